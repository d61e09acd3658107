"""`record`: record motion_ctrl's topics into a rosbag2 bag (MCAP storage), `ros2 bag record`
without a ROS install.

    python -m motion_ctrl.tools.record -o DIR [TOPIC ...] [--ros-args ...]
    ros2 run motion_ctrl record -o DIR
    ros2 run motion_ctrl record --repair DIR      # the bag of a killed recorder

Default topics: joint_states, reference_states, motor_states, command, encoders, plant_states and
every ``<axis>/status`` (std_msgs/UInt32 topics ending in ``/status``, found in the ROS graph at
start and, every 0.5 s, while recording). Topic names are relative: ``--ros-args -r __ns:=/ns``
records a namespaced slide. The recording itself (bag format, timestamps, QoS, the periodic
flush, throughput) is `motion_ctrl.bags.writer.Recorder`.

SIGINT and SIGTERM only raise a flag; the bag is closed in `finally`. "record: recording N
topics" is printed once the topics are matched (or after --ready-timeout, naming those without
a publisher yet); at exit the messages written per topic are printed.

A recorder that is killed (SIGKILL, OOM killer, power to the PC cut by an e-stop chain) cannot
close the bag: it leaves the MCAP file without its footer and summary and no metadata.yaml,
which no `rosbags` reader opens (it needs both).

    record --repair DIR

(as `ros2 bag reindex`, `motion_ctrl.bags.repair`) rebuilds a complete bag from what the file
holds: every complete message, a complete MCAP with summary, and the metadata.yaml. `report` on a
killed recorder's bag says to run the repair.
"""
from __future__ import annotations

import argparse
import os
import signal
import sys
import time

import rclpy
from rclpy.signals import SignalHandlerOptions

from motion_ctrl.bags import repair
from motion_ctrl.bags.writer import (DEFAULT_DEPTH, SERVO_TOPICS, SPIN_TIMEOUT, Recorder,
                                     RecordError, default_output)
from motion_ctrl.ros import ros_env


def parser() -> argparse.ArgumentParser:
    ap = argparse.ArgumentParser(
        prog='record', description='Record motion_ctrl topics into a rosbag2 bag (MCAP).')
    ap.add_argument('topics', nargs='*', help='topics to record (default: '
                    + ', '.join(SERVO_TOPICS) + ' and every <axis>/status)')
    ap.add_argument('-o', '--output', default=None,
                    help='bag directory to create (default: rosbag2_<date>-<time>)')
    ap.add_argument('--all-status', action='store_true',
                    help='with explicit topics: also record every <axis>/status')
    ap.add_argument('--depth', type=int, default=DEFAULT_DEPTH,
                    help=f'reader queue depth of the servo streams (default {DEFAULT_DEPTH})')
    ap.add_argument('--ready-timeout', type=float, default=5.0,
                    help='seconds to wait at start for the topics to be published (default 5)')
    ap.add_argument('--repair', metavar='DIR', default=None,
                    help='do not record: make a complete bag (MCAP summary, metadata.yaml) of '
                         'what a killed recorder left in DIR')
    return ap


def main(argv=None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    ros_args = []
    if '--ros-args' in argv:
        i = argv.index('--ros-args')
        argv, ros_args = argv[:i], argv[i:]
    ap = parser()
    args = ap.parse_args(argv)
    if args.repair is None:
        return record(args, ros_args)
    if args.topics or args.output or ros_args:
        ap.error('--repair takes no topics, -o or --ros-args')
    try:
        result = repair.repair(args.repair)
    except (repair.RepairError, OSError) as e:
        print(f'record: error: {e}', file=sys.stderr)
        return 2
    print(result.summary(), flush=True)
    return 0


def record(args: argparse.Namespace, ros_args: list) -> int:
    """Record until SIGINT / SIGTERM (or the context ends), then print the counts."""
    ros_env.local_discovery()
    stop = []
    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, lambda *_: stop.append(True))
    out = args.output or default_output()
    if os.path.lexists(out):
        print(f'record: error: {out} exists already, not overwriting', file=sys.stderr)
        return 2
    rclpy.init(args=['record'] + ros_args, signal_handler_options=SignalHandlerOptions.NO)
    rec = Recorder(out, args.topics or None, depth=args.depth,
                   discover_status=True if args.all_status else None)
    try:
        try:
            rec.open()
        except RecordError as e:
            print(f'record: error: {e}', file=sys.stderr)
            return 2
        end = time.monotonic() + args.ready_timeout
        while not stop and not rec.ready() and time.monotonic() < end:
            rec.spin_once(0.01)
        missing = rec.unmatched()
        print(f'record: recording {len(rec._subs)} topics into {out}'
              + (f' (no publisher yet: {", ".join(missing)})' if missing else ''), flush=True)
        while not stop and rclpy.ok():
            rec.spin_once(SPIN_TIMEOUT)
    finally:
        rec.close()
        rclpy.try_shutdown()
    print(rec.summary(), flush=True)
    return 0


if __name__ == '__main__':
    sys.exit(main())
