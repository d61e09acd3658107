"""The demo: the Galil manual's 1-inch move on the simulated backlash slide, over ROS.

Starts the plant and the controller as two processes (params/plant.yaml, controller.yaml), or
with `--hardware sim` the controller alone with the slide simulated inside its loop, commands a
1-inch forward move, then the headline move after a reversal (+2 in, back to +1 in),
prints the true slide error (from plant_states) in linear counts and the time to MOTION_DONE,
and stops both nodes with SIGINT. The moves are recorded into a rosbag2 (MCAP) bag and drawn
by the report tool next to it (out/demo-<time>/).
"""
from __future__ import annotations

import argparse
import datetime
import pathlib
import sys

import msg_defs as md
from motion_ctrl.ros import ros_env
from motion_ctrl.core.registers import INCH, LOAD_COUNTS_PER_M


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument('--feedback', default=None, choices=('motor', 'load', 'dual', 'sampled'),
                    help='override x.feedback (default: params/controller.yaml)')
    ap.add_argument('--hardware', default='topics', choices=('topics', 'sim'),
                    help='topics: plant node + controller (default); sim: the controller alone, '
                         'the slide simulated in its loop')
    ap.add_argument('-o', '--out', default=None,
                    help='directory for logs, bag and plot (default out/demo-<time>)')
    args = ap.parse_args(argv)
    domain = ros_env.private_domain()
    import rclpy
    from motion_ctrl.ros.client import SlideClient
    from motion_ctrl.ros.processes import start_sim, start_slide
    from motion_ctrl.tools.record import SERVO_TOPICS, Recorder
    from motion_ctrl.tools.report import ReportError, format_summary, make_report

    overrides = {'x.feedback': args.feedback} if args.feedback else {}
    out = pathlib.Path(args.out or datetime.datetime.now().strftime('out/demo-%Y%m%d-%H%M%S'))
    out.mkdir(parents=True, exist_ok=True)
    bag, png = out / 'bag', out / 'move.png'
    what = 'plant and controller' if args.hardware == 'topics' else 'the controller (hardware sim)'
    print(f'demo: starting {what} (ROS_DOMAIN_ID={domain}, logs in {out})')
    nodes = (start_slide if args.hardware == 'topics' else start_sim)(overrides, log_dir=out)
    rclpy.init()
    client = SlideClient()
    recorder = None
    code = 0
    try:
        if not client.wait_ready(20.0):
            print(f'demo: the nodes did not come up ({client.not_ready()}); see the logs',
                  file=sys.stderr)
            return 1
        # (sim: no `command` / `encoders` on DDS, the slide is in the controller's loop)
        topics = None if args.hardware == 'topics' else [
            t for t in SERVO_TOPICS if t not in (md.COMMAND, md.ENCODERS)]
        recorder = Recorder(bag, topics, discover_status=True).start()
        if not recorder.wait_ready(10.0):
            print('demo: the recorder did not see every topic; recording anyway')
        print(f'{"move":<28}{"target [m]":>12}{"slide error [counts]":>22}{"MOTION_DONE [ms]":>18}')
        for label, target in (('1 in forward', INCH), ('+2 in', 2 * INCH),
                              ('back to +1 in (reversal)', INCH)):
            t = client.move({'x': target}, timeout=5.0)
            client.spin_for(0.05)      # latest truth after the event
            err = (client.load_position() - target) * LOAD_COUNTS_PER_M
            when = f'{t * 1000:.0f}' if t is not None else 'timeout'
            print(f'{label:<28}{target:>12.4f}{err:>+22.2f}{when:>18}')
            if t is None:
                code = 1
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


if __name__ == '__main__':
    sys.exit(main())
