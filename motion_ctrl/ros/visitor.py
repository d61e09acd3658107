"""A short-lived ROS participant, as a `ros2 param get` or `ros2 topic echo` is: for the churn
test and `scripts/soak`, which check that tools joining and leaving the graph do not disturb the
servo loop.

`python -m motion_ctrl.ros.visitor [--axis x] [--linger 1.0]` creates a node (a new DDS
participant), reads a register of the controller through its parameter services, subscribes to
`joint_states` and `<axis>/status` for `--linger` seconds, and exits. It prints one line: what it
received.
"""
from __future__ import annotations

import argparse
import faulthandler
import os
import time

import rclpy
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node
from rclpy.parameter_client import AsyncParameterClient
from sensor_msgs.msg import JointState
from std_msgs.msg import UInt32

import msg_defs as md
from motion_ctrl.ros import ros_env


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument('--axis', default='x')
    ap.add_argument('--controller', default='controller', help='node whose parameters to read')
    ap.add_argument('--linger', type=float, default=1.0, help='seconds subscribed')
    a = ap.parse_args(argv)

    faulthandler.enable()            # (a crash says where: soak prints the visitor's last line)
    ros_env.local_discovery()        # (read by rclpy.init(), not at import)
    rclpy.init()
    node = Node(f"visitor_{os.getpid()}")
    got = {'joint_states': 0, 'status': 0}

    def count(key):
        def cb(_msg):
            got[key] += 1
        return cb
    node.create_subscription(JointState, md.JOINT_STATES, count('joint_states'), 10)
    node.create_subscription(UInt32, md.status_topic(a.axis), count('status'), md.STATUS_QOS)
    # The executor ros2cli uses (rclpy's default), not the nodes' experimental EventsExecutor,
    # which now and then crashes a participant this short-lived (doc/design_notes.md, "The
    # executor").
    executor = SingleThreadedExecutor()
    executor.add_node(node)
    params = AsyncParameterClient(node, a.controller)
    value = None
    end = time.monotonic() + a.linger
    future = None
    while time.monotonic() < end:
        if future is None and params.services_are_ready():
            future = params.get_parameters([f'{a.axis}.kp'])
        if future is not None and future.done() and value is None:
            result = future.result()
            value = result.values[0].double_value if result is not None else None
        executor.spin_once(timeout_sec=0.01)
    print(f'visitor: {a.axis}.kp={value} joint_states={got["joint_states"]} '
          f'status={got["status"]}', flush=True)
    executor.shutdown()
    node.destroy_node()
    rclpy.try_shutdown()
    return 0


if __name__ == '__main__':
    raise SystemExit(main())
