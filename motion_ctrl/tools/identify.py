"""`identify`: measure an axis over ROS, fit the two-mass model, write a Bode plot (Kollmorgen
WorkBench's Bode measurement, Beckhoff TwinCAT's base motion, PMAC's gather): the command line
of motion_ctrl/procedures/identify.py, which holds the measurement and what it writes
(identify.yaml, response.csv, report.md, bode.png), with the maths in
motion_ctrl/analysis/identify.py.

`--spawn` starts the simulated slide itself (as `calibrate`), `--lockstep` as the lockstep
simulation, `--plant NAME:=VALUE` changes it.
"""
from __future__ import annotations

import argparse
import sys

from motion_ctrl.procedures.identify import (IdentifyError, identify, identify_arguments,
                                             servo_rate)
from motion_ctrl.procedures.session import SessionError, axis_session, session_arguments


def parser() -> argparse.ArgumentParser:
    ap = argparse.ArgumentParser(
        prog='identify', description='Measure an axis through the running controller (loop '
        'closed, stepped sine on a slow base motion, every servo tick gathered), fit the '
        'two-mass model, print it and write a Bode plot.')
    identify_arguments(ap)
    session_arguments(ap, 'identify', 'x.slide_mass:=10.0')
    return ap


def main(argv=None) -> int:
    args = parser().parse_args(argv)
    if args.lockstep and not args.spawn:
        print('identify: --lockstep needs --spawn', file=sys.stderr)
        return 2
    bad = [n for n in ('amplitude', 'fine_amplitude', 'dwell', 'fine_dwell', 'velocity',
                       'ratio_dwell', 'soft_loop', 'creep_time') if not getattr(args, n) > 0]
    if not args.creep >= 0:
        bad.append('creep')
    if args.ratio_amplitude is not None and not args.ratio_amplitude > 0:
        bad.append('ratio_amplitude')
    bad += [n for n in ('points', 'fine_points', 'friction_samples') if getattr(args, n) < 2]
    if args.ratio_points and args.ratio_points < 3:
        bad.append('ratio_points')
    if bad:
        print(f'identify: --{bad[0].replace("_", "-")} must be > 0 (points, samples: >= 2)',
              file=sys.stderr)
        return 2
    try:
        with axis_session(args, 'identify', services=True) as (_, axis, out):
            args.servo_rate = servo_rate(axis)
            identify(axis, args, out)
    except (IdentifyError, SessionError) as e:
        print(f'identify: {e}', file=sys.stderr)
        return 1
    return 0


if __name__ == '__main__':
    sys.exit(main())
