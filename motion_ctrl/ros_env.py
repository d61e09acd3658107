"""Network hygiene, and the executor, for every motion_ctrl process that uses ROS.

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


def executor(context=None):
    """The executor that holds a 1 kHz loop best here (REFERENCE.md: EventsExecutor, about half
    the CPU of SingleThreaded), SingleThreaded where rclpy has no EventsExecutor (before Jazzy
    7.1.4). Drive it with spin_once: in rclpy 9.1 EventsExecutor.spin() busy-waits without
    running timers or seeing signals."""
    try:
        from rclpy.experimental import EventsExecutor as Executor
    except ImportError:
        from rclpy.executors import SingleThreadedExecutor as Executor
    return Executor(context=context)
