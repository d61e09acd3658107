"""The demo: the Galil manual's 1-inch move on the simulated backlash slide, over ROS.

Starts the plant and the controller as two processes (params/plant.yaml, controller.yaml), or
with `--hardware sim` the controller alone with the slide simulated inside its loop, commands a
1-inch forward move, then the headline move after a reversal (+2 in, back to +1 in),
prints the true slide error (from plant_states) in linear counts, the time to MOTION_DONE and
how long after the end of the profile (AT_TARGET) it came, with the median of the three moves,
and stops both nodes with SIGINT. The moves are recorded into a rosbag2 (MCAP) bag and drawn
by the report tool next to it (out/demo-<time>/).

`--hardware canopen`: the same moves through a CiA 402 drive on a CAN bus, emulated by the
`virtual_drive` node (the slide behind a CiA 402 object dictionary, its linear encoder a CiA 406
node), the controller its CANopen master at the highest servo rate a 1 Mbit/s bus carries. The
bus is python-can's udp_multicast, in a network namespace of its own (processes.private_network:
the demo runs itself again inside it), so no frame leaves the machine.
"""
from __future__ import annotations

import argparse
import datetime
import math
import os
import pathlib
import statistics
import sys

import rclpy

import msg_defs as md
from motion_ctrl.analysis.moves import format_summary
from motion_ctrl.bags.reader import ReportError
from motion_ctrl.bags.report import make_report
from motion_ctrl.bags.writer import SERVO_TOPICS, Recorder
from motion_ctrl.canopen import busload
from motion_ctrl.canopen.objects import cycle_frames
from motion_ctrl.core.registers import INCH, LOAD_COUNTS_PER_M
from motion_ctrl.ros import ros_env
from motion_ctrl.ros.client import SlideClient
from motion_ctrl.ros.processes import (CAN_BUS, PRIVATE_NET, private_network, start_canopen,
                                       start_sim, start_slide)

ENCODER_NODE = 5                                 # the slide's CiA 406 encoder node (canopen)
# The three moves: 1 inch forward, +2 in, then the headline move back to +1 in.
MOVES = (('1 in forward', INCH), ('+2 in', 2 * INCH), ('back to +1 in (reversal)', INCH))


def parser() -> argparse.ArgumentParser:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument('--feedback', default=None, choices=('motor', 'load', 'dual', 'sampled'),
                    help='override x.feedback (default: params/controller.yaml)')
    ap.add_argument('-o', '--out', default=None,
                    help='directory for logs, bag and plot (default out/demo-<time>)')
    ap.add_argument('--hardware', default='topics', choices=('topics', 'sim', 'canopen'),
                    help='topics: plant node + controller (default); sim: the controller alone, '
                         'the slide simulated in its loop; canopen: an emulated CiA 402 drive '
                         'and CiA 406 encoder on a CAN bus')
    ap.add_argument('--realtime-priority', type=int, default=0,
                    help='SCHED_FIFO priority of both nodes (realtime_priority; 0: normal)')
    ap.add_argument('--servo-rate', type=float, default=None,
                    help='canopen: the servo rate [Hz] (default: the most 1 Mbit/s carries)')
    return ap


def main(argv=None) -> int:
    args = parser().parse_args(argv)
    if args.hardware == 'canopen' and not os.environ.get(PRIVATE_NET):
        return rerun_in_private_network(sys.argv[1:] if argv is None else list(argv))
    domain = ros_env.private_domain()
    overrides = {'x.feedback': args.feedback} if args.feedback else {}
    out = pathlib.Path(args.out or datetime.datetime.now().strftime('out/demo-%Y%m%d-%H%M%S'))
    out.mkdir(parents=True, exist_ok=True)
    bag, png = out / 'bag', out / 'move.png'
    nodes = start_nodes(args, overrides, domain, out)
    rclpy.init()
    client = SlideClient()
    recorder = None
    try:
        if not client.wait_ready(20.0):
            print(f'demo: the nodes did not come up ({client.not_ready()}); see the logs',
                  file=sys.stderr)
            return 1
        # What the report draws. Not `command` / `encoders`: over topics each of them read on
        # the user's domain is a 1 kHz stream more that the bridges copy out, on the cores
        # the loop runs on (doc/gains.md, "The demo's own load").
        topics = [t for t in SERVO_TOPICS if t not in (md.COMMAND, md.ENCODERS)]
        recorder = Recorder(bag, topics, discover_status=True).start()
        if not recorder.wait_ready(10.0):
            print('demo: the recorder did not see every topic; recording anyway')
        code = headline_moves(client)
        client.spin_for(0.3)
    finally:
        if recorder is not None:
            recorder.stop()
        client.destroy_node()
        rclpy.try_shutdown()
        # The controller first: a plant that stops first leaves it a FEEDBACK_FAULT to report.
        rcs = [n.stop() for n in reversed(nodes)]
        print('demo: nodes stopped (exit codes ' + ', '.join(map(str, rcs)) + ')')
    if recorder is not None:
        try:
            summary = make_report(bag, png)
            print(f'demo: recorded {recorder.total} messages into {bag}; plot in {png}')
            print(format_summary(summary))
        except ReportError as e:
            print(f'demo: no report: {e}', file=sys.stderr)
    return code


def rerun_in_private_network(argv: list) -> int:
    """Run the demo again inside a network namespace of its own (the CAN bus's multicast stays
    in it); returns only when that cannot be made (exit code 2)."""
    command = private_network([sys.executable, '-m', 'motion_ctrl.tools.demo', *argv])
    try:
        os.execvp(command[0], command)
    except OSError as e:
        print(f'demo: cannot make a private network namespace ({" ".join(command[:3])}): '
              f'{e}', file=sys.stderr)
    return 2


def start_nodes(args: argparse.Namespace, overrides: dict, domain: int, out: pathlib.Path):
    """Start the nodes of `--hardware` (logs in `out`); returns them, controller last."""
    if args.hardware == 'canopen':
        return start_can_bus(args, overrides, domain, out)
    what = ('plant and controller' if args.hardware == 'topics'
            else 'the controller (hardware sim)')
    print(f'demo: starting {what} (ROS_DOMAIN_ID={domain}, logs in {out})')
    return (start_slide if args.hardware == 'topics' else start_sim)(overrides, log_dir=out)


def start_can_bus(args: argparse.Namespace, overrides: dict, domain: int,
                  out: pathlib.Path):
    """virtual_drive (CiA 402 drive node 1, CiA 406 encoder node ENCODER_NODE) and the
    controller as its CANopen master, at the servo rate the bus carries (its load printed)."""
    frames = cycle_frames([ENCODER_NODE])
    rate = args.servo_rate or busload.max_rate(CAN_BUS['can_bitrate'], frames)
    print(f'demo: starting virtual_drive (CiA 402 drive node 1, CiA 406 encoder node '
          f'{ENCODER_NODE}) and the controller on {CAN_BUS["can_interface"]} in a private '
          f'network namespace (ROS_DOMAIN_ID={domain}, logs in {out})')
    share = busload.load(rate, CAN_BUS['can_bitrate'], frames)
    print(f'demo: servo rate {rate:.1f} Hz: {share * 100:.0f} % of '
          f'{CAN_BUS["can_bitrate"] / 1e6:g} Mbit/s (SYNC + PDOs of '
          f'{"/".join(map(str, frames))} bytes, {busload.cycle_bits(frames)} bits a cycle '
          f'with worst-case stuffing)')
    rt = {'realtime_priority': args.realtime_priority}
    return start_canopen(overrides | rt | {'servo_rate': rate,
                                           'x.load_encoder_node_id': ENCODER_NODE},
                         rt | {'x.load_encoder_node_id': ENCODER_NODE}, log_dir=out)


def headline_moves(client: SlideClient) -> int:
    """The three moves (MOVES), a line each: the true slide error [counts], the time to
    MOTION_DONE and how long after the profile's end (AT_TARGET) it came; then their median.
    Returns 1 when a move timed out, else 0."""
    print(f'{"move":<28}{"target [m]":>12}{"slide error [counts]":>22}'
          f'{"MOTION_DONE [ms]":>18}{"after profile end [ms]":>24}')
    code = 0
    settles, errors = [], []
    for label, target in MOVES:
        mark = len(client.status_log['x'])
        t = client.move({'x': target}, timeout=5.0)
        settle = client.settle_after_profile('x', mark) if t is not None else None
        client.spin_for(0.05)      # latest truth after the event
        err = (client.load_position() - target) * LOAD_COUNTS_PER_M
        when = f'{t * 1000:.0f}' if t is not None else 'timeout'
        after = f'{settle * 1000:.0f}' if settle is not None else '-'
        print(f'{label:<28}{target:>12.4f}{err:>+22.2f}{when:>18}{after:>24}')
        if t is None:
            code = 1
        settles.append(math.inf if settle is None else settle)
        errors.append(err)
    median = statistics.median(settles) * 1000
    print(f'demo: MOTION_DONE - profile end, median of the {len(settles)} moves: '
          f'{median:.0f} ms; every move within 1 count of its target: '
          f'{"yes" if all(abs(e) <= 1.0 for e in errors) else "no"}')
    return code


if __name__ == '__main__':
    sys.exit(main())
