"""`calibrate`: ISO 230-2 test of an axis over ROS with its own linear encoder as the reference,
PMAC compensation tables (DEFINE COMP, DEFINE BLCOMP, Ixx86) and a LinuxCNC COMP_FILE from it,
optionally applied and checked by a second test (the ROS shell of motion_ctrl/analysis/iso230.py).

It talks to the controller like any ROS user: targets on `target_position`, MOTION_DONE from
`<axis>/status`, the load (linear) encoder from `joint_states` (the controller's load position,
read from the `encoders` the plant or the drive sends), registers through the parameter services
`ros2 param` uses. `plant_states` (the simulation's ground truth) is never read. During the test
the axis runs on `feedback: motor` — the loop the tables are for — with its compensation off
and its integrator on through the moves (`integration_mode: always`); afterwards they are put
back as they were, or, with `--apply`, the new
tables are loaded (from the YAML file written) and the test is run again.

`--spawn` starts the simulated slide itself (plant and controller as two processes, as the demo
does, or `--hardware sim`: the controller alone with the slide in its loop), `--lockstep` as the
deterministic lockstep simulation (by default the controller alone, its own clock, as fast as the
machine allows), `--plant NAME:=VALUE` changes the simulated slide.
"""
from __future__ import annotations

import argparse
import math
import pathlib
import sys
import time

import numpy as np

from motion_ctrl.analysis import iso230
from motion_ctrl.core.registers import INCH
from motion_ctrl.plotting.iso230 import plot_report
from motion_ctrl.procedures.session import (AxisUnderTest, SessionError, axis_session, pair,
                                       session_arguments, spawned_hardware)

COMP_REGISTERS = ('backlash_distance', 'backlash_table', 'backlash_table_spacing',
                  'leadscrew_table', 'leadscrew_table_spacing')
DEFAULT_LENGTH = 4 * INCH         # the headline's travel (1 and 2 in) and as much again
DEFAULT_TARGETS = 11              # ~10 mm apart: a quarter of the default screw's error period
DEFAULT_OVERTRAVEL = 1e-3         # far beyond any backlash + Ixx87 this slide may have


def default_travel(soft_min: float, soft_max: float, overtravel: float) -> tuple[float, float]:
    """From position 0 (the tables start there) or the soft limit's overtravel above it, 4 in
    long, ending at the latest an overtravel below the upper soft limit."""
    lo = max(0.0, soft_min + overtravel)
    hi = min(lo + DEFAULT_LENGTH, soft_max - overtravel)
    return lo, hi


def calibrate(axis: AxisUnderTest, args, out: pathlib.Path, log=print) -> dict:
    """The whole procedure on an axis of a ready controller; returns {'before': Iso230,
    'after': Iso230 or None, 'tables': Tables, 'seconds': {...}}."""
    problem = axis.not_ready()
    if problem:
        raise SessionError(problem)
    regs, lo, hi, targets = _plan(axis, args, log)
    cpm = regs['load_counts_per_m']
    saved = {k: regs[k] for k in ('feedback', 'integration_mode', *COMP_REGISTERS)}
    seconds = {}
    t0 = time.monotonic()
    _uncompensated_motor_loop(axis, targets[0] - args.overtravel, args.move_timeout)
    applied = False
    try:
        approach = (args.approach, args.approach_time)
        before = iso230.run_cycle(axis, targets, args.cycles, args.overtravel, args.dwell,
                                  args.average, args.move_timeout, _progress(log, 'before'),
                                  approach)
        seconds['before'] = time.monotonic() - t0
        tables, yaml_path = _write_tables(before, args, out, lo, hi, targets, cpm, log)
        after = None
        if args.apply:
            axis.move(targets[0] - args.overtravel, args.move_timeout)
            axis.load_file(yaml_path)
            applied = True
            t1 = time.monotonic()
            after = iso230.run_cycle(axis, targets, args.cycles, args.overtravel, args.dwell,
                                     args.average, args.move_timeout, _progress(log, 'after'),
                                     approach)
            seconds['after'] = time.monotonic() - t1
    finally:
        _put_back(axis, args, saved, applied, targets[0] - args.overtravel, log)
    seconds['total'] = time.monotonic() - t0
    runs = {'before': before} | ({'after (tables applied)': after} if after is not None else {})
    report = iso230.format_report(runs, cpm)
    png = out / 'calibration.png'
    plot_report(runs, png, cpm, title=f'ISO 230-2, axis {args.axis}, feedback motor, '
                       f'{len(targets)} targets x {args.cycles} cycles')
    log(report)
    log(f'calibrate: plot in {png}; ' + ', '.join(f'{k} {v:.1f} s' for k, v in seconds.items()))
    (out / 'report.md').write_text(report + '\n')
    return dict(before=before, after=after, tables=tables, seconds=seconds, targets=targets)


def _plan(axis: AxisUnderTest, args, log) -> tuple[dict, float, float, np.ndarray]:
    """The axis's registers, the travel (--range or default_travel) checked against the soft
    limits and the reversal hysteresis, and the targets; logs the plan. (registers, lo, hi,
    targets)"""
    regs = axis.get('feedback', 'integration_mode', 'soft_limit_min', 'soft_limit_max',
                    'load_counts_per_m', 'backlash_hysteresis', *COMP_REGISTERS)
    lo, hi = (args.range if args.range else
              default_travel(regs['soft_limit_min'], regs['soft_limit_max'], args.overtravel))
    if args.overtravel <= 2 * regs['backlash_hysteresis']:
        raise SessionError(f'--overtravel {args.overtravel:g} m must exceed twice the '
                               f'reversal hysteresis ({regs["backlash_hysteresis"]:g} m)')
    if lo - args.overtravel < regs['soft_limit_min'] or hi + args.overtravel > \
            regs['soft_limit_max']:
        raise SessionError(f'travel {lo:g} .. {hi:g} m with {args.overtravel:g} m overtravel '
                               f'leaves the soft limits {regs["soft_limit_min"]:g} .. '
                               f'{regs["soft_limit_max"]:g} m')
    if lo < 0.0:
        raise SessionError('the compensation tables start at position 0: calibrate a travel '
                               'at or above 0')
    targets = iso230.plan_targets(lo, hi, args.targets)
    log(f'calibrate: axis {args.axis}, {len(targets)} targets {lo * 1e3:.3f} .. {hi * 1e3:.3f} mm '
        f'(intervals {np.diff(targets).min() * 1e3:.2f} .. {np.diff(targets).max() * 1e3:.2f} mm), '
        f'{args.cycles} bidirectional cycles, overtravel {args.overtravel * 1e3:g} mm')
    if args.cycles < iso230.MIN_CYCLES or args.targets < iso230.MIN_TARGETS:
        log(f'calibrate: note: ISO 230-2 asks for >= {iso230.MIN_TARGETS} targets and '
            f'>= {iso230.MIN_CYCLES} cycles; this run is shorter')
    return regs, lo, hi, targets


def _progress(log, label: str):
    """progress(k, n) for iso230.run_cycle: logs the move count every 10 s and at the end."""
    last = [time.monotonic()]

    def show(k, n):
        if time.monotonic() - last[0] > 10.0 or k == n:
            last[0] = time.monotonic()
            log(f'calibrate: {label}: move {k}/{n}')
    return show


def _uncompensated_motor_loop(axis: AxisUnderTest, below: float, move_timeout: float) -> None:
    """The axis moved to `below` (at rest before the switch), then on the motor loop with its
    compensation off and its integrator on through the moves."""
    axis.move(below, move_timeout)
    # Motor loop, compensation off: what the tables are to correct. The integrator on through
    # each approach (PMAC Ixx34 = 0): it presses the nut onto the flank it came from; held
    # during moves, it left the slide where friction stopped it, and the reversal error read
    # 8 counts of the default slide's 21-count gap.
    axis.set({'feedback': 'motor', 'integration_mode': 'always', 'backlash_distance': 0.0,
              'leadscrew_table': [], 'backlash_table': []})


def _write_tables(before: iso230.Iso230, args, out: pathlib.Path, lo: float, hi: float,
                  targets, cpm: float, log) -> tuple[iso230.Tables, pathlib.Path]:
    """The compensation tables from the test before (PMAC COMP / BLCOMP and Ixx86 as `ros2
    param load` YAML, a LinuxCNC COMP_FILE) written into `out`; (the tables, the YAML's path)."""
    tables = iso230.build_tables(before, args.table_tolerance / cpm, args.spacing)
    header = (f'motion_ctrl calibrate: ISO 230-2 test of axis {args.axis} on feedback: motor, '
              f'{len(targets)} targets {lo:g} .. {hi:g} m, {args.cycles} cycles\n'
              f'B {before.B * cpm:.2f} counts, E {before.E * cpm:.2f} counts before; '
              f'table spacing {tables.spacing:g} m (fit within '
              f'{tables.residual * cpm:.2f} counts)\n'
              f'load with: ros2 param load /controller <this file>')
    yaml_path, comp_path = out / 'compensation.yaml', out / 'linuxcnc_comp.txt'
    yaml_path.write_text(iso230.params_yaml(tables, args.axis, comment=header))
    comp_path.write_text(iso230.linuxcnc_comp_file(before, args.comp_units))
    log(f'calibrate: Ixx86 backlash_distance {tables.backlash_distance * 1e6:.2f} um '
        f'({tables.backlash_distance * cpm:.2f} counts); COMP/BLCOMP '
        f'{len(tables.leadscrew_table)} entries at {tables.spacing * 1e3:.3f} mm (reproduce '
        f'the measured means within {tables.residual * cpm:.2f} counts)')
    log(f'calibrate: wrote {yaml_path} and {comp_path} (LinuxCNC COMP_FILE_TYPE = 1, '
        f'{args.comp_units})')
    return tables, yaml_path


def _put_back(axis: AxisUnderTest, args, saved: dict, applied: bool, below: float,
              log) -> None:
    """The axis moved to `below` and its registers put back as they were, but the new tables
    when applied and the motor loop with --keep-motor."""
    restore = {k: v for k, v in saved.items() if not (applied and k in COMP_REGISTERS)}
    if args.keep_motor and 'feedback' in restore:
        del restore['feedback']
    try:
        axis.move(below, args.move_timeout)
    except SessionError as e:
        log(f'calibrate: {e}')
    axis.set(restore)


def parser() -> argparse.ArgumentParser:
    ap = argparse.ArgumentParser(
        prog='calibrate', description='ISO 230-2 test of an axis against its linear encoder; '
        'PMAC COMP/BLCOMP tables and Ixx86 as ros2 param load YAML, a LinuxCNC comp file, and '
        'a before/after report.')
    ap.add_argument('--axis', default='x')
    ap.add_argument('--range', type=pair, metavar='LO,HI',
                    help='travel to calibrate [m] (default: 0 .. 4 in, inside the soft limits '
                    'less the overtravel)')
    ap.add_argument('--targets', type=int, default=DEFAULT_TARGETS,
                    help=f'target positions (default {DEFAULT_TARGETS}; ISO 230-2: >= 5)')
    ap.add_argument('--cycles', type=int, default=iso230.MIN_CYCLES,
                    help='bidirectional cycles (default and ISO 230-2 minimum: 5)')
    ap.add_argument('--overtravel', type=float, default=DEFAULT_OVERTRAVEL,
                    help='approach margin beyond the first target of each direction [m] '
                    '(default 0.001)')
    ap.add_argument('--approach', type=float, default=0.0002,
                    help='each target\'s final approach: this distance [m] as a slow PVT '
                    'segment on joint_trajectory (default 0.0002; 0: plain moves)')
    ap.add_argument('--approach-time', type=float, default=0.2,
                    help='duration of that final segment [s] (default 0.2)')
    ap.add_argument('--dwell', type=int, default=50,
                    help='joint_states samples skipped after MOTION_DONE (default 50)')
    ap.add_argument('--average', type=int, default=50,
                    help='joint_states samples averaged per reading (default 50)')
    ap.add_argument('--spacing', type=float, default=None,
                    help='table spacing [m] (default: the largest that reproduces the measured '
                    'means within --table-tolerance)')
    ap.add_argument('--table-tolerance', type=float, default=0.25,
                    help='largest table interpolation error at a target [linear counts] '
                    '(default 0.25)')
    ap.add_argument('--comp-units', choices=sorted(iso230.UNITS), default='mm',
                    help='units of the LinuxCNC comp file (the machine\'s; default mm)')
    ap.add_argument('--apply', action='store_true',
                    help='load the tables into the controller and run the test again')
    ap.add_argument('--keep-motor', action='store_true',
                    help='leave the axis on feedback: motor afterwards (default: put it back)')
    ap.add_argument('--move-timeout', type=float, default=10.0)
    session_arguments(ap, 'calibrate', 'x.backlash:=1.524e-4')
    return ap


def main(argv=None) -> int:
    args = parser().parse_args(argv)
    if args.lockstep and not args.spawn:
        print('calibrate: --lockstep needs --spawn', file=sys.stderr)
        return 2
    if args.targets < 2 or args.cycles < 2:
        print('calibrate: at least 2 targets and 2 cycles', file=sys.stderr)
        return 2
    start = time.monotonic()
    try:
        with axis_session(args, 'calibrate') as (_client, axis, out):
            result = calibrate(axis, args, out)
    except SessionError as e:
        print(f'calibrate: {e}', file=sys.stderr)
        return 1
    mode = (f'{"lockstep simulation" if args.lockstep else "real time"}, hardware '
            f'{spawned_hardware(args)}') if args.spawn else 'DDS'
    print(f'calibrate: done in {time.monotonic() - start:.1f} s ({mode}; tests '
          + ', '.join(f'{k} {v:.1f} s' for k, v in result['seconds'].items()) + ')')
    return 0 if math.isfinite(result['before'].B) else 1


if __name__ == '__main__':
    sys.exit(main())
