"""Network hygiene for every motion_ctrl process that uses ROS.

DDS discovery stays on this host unless the user chose otherwise
(ROS_AUTOMATIC_DISCOVERY_RANGE; Kilted ignores ROS_LOCALHOST_ONLY). Tools that start their own
nodes (demo, tests, benchmark) also get a ROS_DOMAIN_ID of their own when none (or 0) is set, so
parallel runs on one machine don't see each other. Call before rclpy.init().
"""
import os


def local_discovery() -> None:
    os.environ.setdefault('ROS_AUTOMATIC_DISCOVERY_RANGE', 'LOCALHOST')


def private_domain() -> int:
    """Pick a domain from the pid (1..101: higher domains reach the ephemeral port range)."""
    local_discovery()
    if os.environ.get('ROS_DOMAIN_ID', '0') in ('', '0'):
        os.environ['ROS_DOMAIN_ID'] = str(os.getpid() % 101 + 1)
    return int(os.environ['ROS_DOMAIN_ID'])
