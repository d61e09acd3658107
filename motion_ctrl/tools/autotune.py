"""`autotune`: gains and a notch for an axis from its measured response, with the margins they
give on the measured open loop; on request applied and verified with real moves (Kollmorgen
WorkBench's Performance Servo Tuner): the command line of motion_ctrl/procedures/autotune.py,
which runs it on the axis, with the maths in motion_ctrl/analysis/autotune.py and
analysis/rest.py and the figures in motion_ctrl/plotting/.

1. The response: an `identify` output folder (`--from DIR`: identify.yaml, the fitted two-mass
   model and friction, and response.csv, the measured points), or, without --from, `identify`
   is run on the axis first (into OUT/identify).
2. The proposal for `--preset` stiff / medium / soft and the axis's `feedback` (dual or motor):
   kp, ki, kd, kvff, kaff, friction_ff and, where the resonance limits the loop, the Ixx36–39
   notch; printed with its margins and bandwidth beside the controller's current registers;
   written as `ros2 param load` YAML (autotune.yaml), with a Bode plot of both open loops,
   margins marked (open_loop.png) and report.md. With them the rest settings
   (analysis.rest): the anti-hunting window, the fine window, the breakaway aid and the
   settling time, from the slip identify's friction predicts, and the accuracy they promise.
3. `--apply`: the demo's moves (1 in, +2 in, back to +1 in: the headline move after a reversal)
   with the current registers; the gains loaded with each rest candidate in turn and short
   test moves, until one brings every test move to rest (rest.search); the proposal loaded
   (load_parameter_file_atomically, as `ros2 param load`), the demo's moves again. Each move
   is watched `--rest` s after MOTION_DONE: settled only if neither the slide's reading nor the
   output turns back (a move that never settles: its limit cycle, period and amplitude). A
   before/after table of settle time (end of the profile to MOTION_DONE), overshoot, final
   error, the output's peak-to-peak at rest and the rest, from the controller's own
   joint_states and status (never plant_states), steps.png and verification.yaml.

With --from and neither --apply nor --spawn it needs no ROS: the registers it compares with are
the register table's defaults (or `--current FILE`, a `ros2 param load` YAML).
"""
from __future__ import annotations

import argparse
import datetime
import math
import pathlib
import sys

import yaml

from motion_ctrl.analysis import autotune as at
from motion_ctrl.core.registers import axis_defaults
from motion_ctrl.procedures.autotune import (AutotuneError, autotune_ros, propose_and_write,
                                             read_axis)
from motion_ctrl.procedures.session import SessionError, axis_session, session_arguments


def read_current(path, axis: str) -> dict:
    """The axis's registers from a `ros2 param load` YAML file (`<axis>.<register>` keys) over
    the register table's defaults: {register: value}."""
    try:
        doc = yaml.safe_load(pathlib.Path(path).read_text())
        params = next(iter(doc.values()))['ros__parameters']
        mine = {k.split('.', 1)[1]: v for k, v in params.items()
                if k.startswith(f'{axis}.')}
    except (OSError, yaml.YAMLError, AttributeError, KeyError, StopIteration, TypeError) as e:
        raise AutotuneError(f'--current {path}: not a ros2 param load file ({e})') from None
    if not mine:
        raise AutotuneError(f'--current {path}: no registers of axis {axis} ({axis}.kp, ...)')
    return axis_defaults() | mine


def parser() -> argparse.ArgumentParser:
    ap = argparse.ArgumentParser(
        prog='autotune', description='Propose gains (kp, ki, kd, kvff, kaff, friction_ff) and '
        'a notch for a preset from the measured response, with the margins on the measured '
        'open loop; write ros2 param load YAML and a Bode plot; --apply loads and verifies it '
        'with real moves.')
    ap.add_argument('--axis', default='x')
    ap.add_argument('--from', dest='source', default=None, metavar='DIR',
                    help='identify output folder (identify.yaml, response.csv); without it '
                    'identify is run on the axis first')
    ap.add_argument('--preset', choices=sorted(at.PRESETS), default='stiff',
                    help='stiff, medium: 8 dB / 45° (crossover up to 0.5 / 0.3 of the '
                    'anti-resonance); soft: 10 dB / 55° (0.2). Default stiff')
    ap.add_argument('--feedback', choices=('dual', 'motor', 'sampled'), default=None,
                    help='loop to tune (default: the controller\'s feedback register, dual '
                    'offline)')
    ap.add_argument('--notch', choices=('auto', 'on', 'off'), default='auto',
                    help='auto (default): only where the resonance limits the loop and a '
                    'notch buys 10 %% more ki (doc/autotune.md: the rule)')
    ap.add_argument('--current', default=None, metavar='FILE',
                    help='offline: the registers to compare with, as ros2 param load YAML '
                    '(default: the register table\'s defaults)')
    ap.add_argument('--apply', action='store_true',
                    help='load the proposal into the controller and verify it with the demo\'s '
                    'moves before and after')
    ap.add_argument('--restore', action='store_true',
                    help='with --apply: put the previous registers back after the verification')
    ap.add_argument('--move-timeout', type=float, default=10.0,
                    help='s of the controller\'s clock a verification move may take to '
                    'MOTION_DONE (default 10)')
    ap.add_argument('--rest', type=float, default=2.0,
                    help='s each verification move is watched at rest after MOTION_DONE: '
                    'settled only if neither the slide\'s reading nor the output turns back '
                    '(default 2)')
    session_arguments(ap, 'autotune', 'x.screw_stiffness:=1.0e6')
    return ap


def main(argv=None) -> int:
    args = parser().parse_args(argv)
    if args.lockstep and not args.spawn:
        print('autotune: --lockstep needs --spawn', file=sys.stderr)
        return 2
    if args.restore and not args.apply:
        print('autotune: --restore needs --apply', file=sys.stderr)
        return 2
    for name in ('move_timeout', 'rest'):
        if not (math.isfinite(getattr(args, name)) and getattr(args, name) > 0):
            print(f'autotune: --{name.replace("_", "-")} must be > 0 s', file=sys.stderr)
            return 2
    offline = args.source is not None and not (args.apply or args.spawn)
    try:
        if offline:
            out = pathlib.Path(args.out or datetime.datetime.now().strftime(
                'out/autotune-%Y%m%d-%H%M%S'))
            out.mkdir(parents=True, exist_ok=True)
            current = read_current(args.current, args.axis) if args.current else axis_defaults()
            tuning = propose_and_write(read_axis(args.source), current, args, out)
            return 0 if tuning.prop.ok else 1
        if args.current:
            print('autotune: --current is for offline use (the controller\'s registers are '
                  'read when it is there)', file=sys.stderr)
            return 2
        with axis_session(args, 'autotune', services=args.source is None,
                          truth=args.spawn) as (client, axis, out):
            result = autotune_ros(client, axis, args, out)
    except (AutotuneError, SessionError) as e:
        print(f'autotune: {e}', file=sys.stderr)
        return 1
    return 0 if result['proposal'].ok and result.get('at_rest', True) else 1


if __name__ == '__main__':
    sys.exit(main())
