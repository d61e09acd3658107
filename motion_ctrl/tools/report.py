"""`report`: plot and summarise the moves in a motion_ctrl bag.

    python -m motion_ctrl.tools.report BAG -o move.png [--axis x] [--load-counts-per-m N]
                                 [--output-limit V] [--start S] [--end S]
    ros2 run motion_ctrl report BAG -o move.png

Reads a rosbag2 bag (any storage `rosbags` reads: mcap, sqlite3) made by `record` or
`ros2 bag record` (`motion_ctrl.bags.reader`: the time axis is the servo messages'
header.stamp), prints per axis per move the move time, settle time, overshoot, final error,
error at MOTION_DONE, peak following error and time at the output limit
(`motion_ctrl.analysis.moves`), and draws one figure per axis (one axis: the -o path; several:
``<stem>_<axis>.png``; the panels: `motion_ctrl.plotting.report`). Scripts and the demo call
`motion_ctrl.bags.report.make_report`.

A bag that does not exist, is not a bag or lacks the topics is a one-line error, exit code 2;
the bag of a killed recorder (an MCAP file, no metadata.yaml) names `record --repair DIR`.
"""
from __future__ import annotations

import argparse
import sys

from motion_ctrl.analysis.moves import LOAD_COUNTS_PER_M, OUTPUT_LIMIT, format_summary
from motion_ctrl.bags.reader import ReportError
from motion_ctrl.bags.report import make_report
from motion_ctrl.plotting.report import png_paths


def parser() -> argparse.ArgumentParser:
    ap = argparse.ArgumentParser(prog='report', description='Plot and summarise the moves '
                                 'in a motion_ctrl bag.')
    ap.add_argument('bag', help='rosbag2 bag directory (or the .mcap in it)')
    ap.add_argument('-o', '--output', default=None,
                    help='PNG to write (several axes: <stem>_<axis>.png); none: summary only')
    ap.add_argument('--axis', action='append', default=None,
                    help='axis to report (repeatable; default: every joint in joint_states)')
    ap.add_argument('--namespace', default=None, help='namespace of the topics (default: '
                    'the root, else the only one in the bag)')
    ap.add_argument('--load-counts-per-m', type=float, default=LOAD_COUNTS_PER_M,
                    help='linear encoder counts per metre for the errors '
                         f'(default {LOAD_COUNTS_PER_M:.6g} = 10000 counts/inch)')
    ap.add_argument('--output-limit', type=float, default=OUTPUT_LIMIT,
                    help=f'output limit [V] drawn and used for saturation (default '
                         f'{OUTPUT_LIMIT:g})')
    ap.add_argument('--start', type=float, default=None, help='plot from this time [s]')
    ap.add_argument('--end', type=float, default=None, help='plot up to this time [s]')
    return ap


def main(argv=None) -> int:
    args = parser().parse_args(argv)
    try:
        summary = make_report(args.bag, args.output, axes=args.axis,
                              load_counts_per_m=args.load_counts_per_m,
                              output_limit=args.output_limit, start=args.start, end=args.end,
                              namespace=args.namespace)
    except ReportError as e:
        print(f'report: error: {e}', file=sys.stderr)
        return 2
    print(format_summary(summary))
    if args.output:
        for path in png_paths(args.output, list(summary)).values():
            print(f'report: wrote {path}')
    return 0


if __name__ == '__main__':
    sys.exit(main())
