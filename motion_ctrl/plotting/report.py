"""The `report` figure: one axis' record and its moves, stacked panels on a shared time axis.

1. commanded (reference_states) vs actual slide position (plant_states ``<axis>_load``, the true
   slide, when recorded; else the measured joint_states position) [mm];
2. following error = commanded - measured slide position (joint_states) [linear counts]
   (symlog scale: the move's hundreds of counts and the final ±1 count on one axis); dashed:
   commanded - true slide;
3. motor - slide [linear counts]: lost motion between the motor and the slide (the backlash
   shows as a step on a reversal), true (plant_states) and measured (motor_states -
   joint_states);
4. control output (joint_states effort) [V] with the ±output_limit lines;
5. the status word as a logic-analyser strip (MOVING, AT_TARGET, IN_FINE_POSITION,
   MOTION_DONE, saturation, following-error and fault bits); the move start (MOVING rises),
   AT_TARGET and MOTION_DONE are vertical lines across every panel, faults red.

The record (`AxisData`) and the moves (`MoveSummary`) come from `motion_ctrl.analysis.moves`.
"""
from __future__ import annotations

import math
import pathlib

import numpy as np
from matplotlib.figure import Figure
from matplotlib.lines import Line2D

from motion_ctrl.analysis.moves import (FAULT_NAMES, LOAD_COUNTS_PER_M, OUTPUT_LIMIT, AxisData,
                                        MoveSummary)
from msg_defs.status import Status

# Bits drawn in the status strip, top to bottom, with their colours.
STRIP_BITS = [
    (Status.MOVING, 'tab:green'),
    (Status.AT_TARGET, 'tab:blue'),
    (Status.IN_COARSE_POSITION, 'tab:cyan'),
    (Status.IN_FINE_POSITION, 'tab:purple'),
    (Status.MOTION_DONE, 'black'),
    (Status.OUTPUT_SATURATED, 'tab:orange'),
    (Status.INTEGRATOR_HELD, 'tab:olive'),
    (Status.BACKLASH_ACTIVE, 'tab:brown'),
    (Status.CORRECTING, 'tab:pink'),
    (Status.FOLLOWING_ERROR_WARNING, 'gold'),
]
# The event lines across all panels: colour and line style of each bit's rise.
EVENT_STYLES = {'MOVING': ('tab:green', '-'), 'AT_TARGET': ('tab:blue', ':'),
                'MOTION_DONE': ('black', '--')}
# Legends right of the panels: they never hide data.
LEGEND = dict(loc='upper left', bbox_to_anchor=(1.01, 1.0), fontsize=8, borderaxespad=0.0)
MM = 1000.0


def png_paths(png, axes) -> dict:
    """-o path per axis: the path itself for one axis, <stem>_<axis><suffix> for several."""
    png = pathlib.Path(png)
    if len(axes) == 1:
        return {axes[0]: png}
    return {a: png.with_name(f'{png.stem}_{a}{png.suffix or ".png"}') for a in axes}


def draw_report(data: dict, summary: dict, png, *, name: str,
                counts_per_m=LOAD_COUNTS_PER_M, output_limit=OUTPUT_LIMIT, start=None,
                end=None) -> None:
    """One figure per axis of {axis: AxisData} with its moves ({axis: [MoveSummary]}), at
    `png_paths`; start/end [s] crop the plot (and the moves marked) only."""
    for a, path in png_paths(png, list(data)).items():
        d = crop(data[a], start, end) if (start is not None or end is not None) else data[a]
        moves = [m for m in summary[a] if (start is None or m.start >= start)
                 and (end is None or m.start <= end)]
        draw_axis(d, moves, path, counts_per_m=counts_per_m, output_limit=output_limit,
                  title=f'{name}: axis {a}')


def crop(d: AxisData, start, end) -> AxisData:
    """The samples of `d` in [start, end] [s], and the status word in force at the start."""
    lo = -math.inf if start is None else start
    hi = math.inf if end is None else end
    m = (d.t >= lo) & (d.t <= hi)
    s = (d.status_t >= lo) & (d.status_t <= hi)

    def c(a):
        return None if a is None else a[m]
    before = np.flatnonzero(d.status_t < lo)
    st_t, st_w = d.status_t[s], d.status[s]
    if len(before) and m.any():
        st_t = np.concatenate(([d.t[m][0]], st_t))
        st_w = np.concatenate(([d.status[before[-1]]], st_w))
    return AxisData(d.axis, d.t[m], d.command[m], d.measured[m], d.output[m], c(d.motor),
                    c(d.load_true), c(d.motor_true), st_t, st_w)


def draw_axis(d: AxisData, moves: list[MoveSummary], png, *, counts_per_m=LOAD_COUNTS_PER_M,
              output_limit=OUTPUT_LIMIT, title=None):
    """Draw one axis' figure (the five panels, the moves' event lines) into `png`."""
    fig = Figure(figsize=(15, 13))
    ax = fig.subplots(5, 1, sharex=True, gridspec_kw={'height_ratios': [3, 2.2, 2, 2, 2.4]})
    fig.suptitle(title or f'axis {d.axis}', fontsize=13)
    _draw_positions(ax[0], d)
    _draw_following_error(ax[1], d, counts_per_m)
    _draw_lost_motion(ax[2], d, counts_per_m)
    _draw_output(ax[3], d, output_limit)
    _draw_status_strip(ax[4], d)
    for m in moves:
        _mark_move(ax, m, many=len(moves) > 4)
    handles = [Line2D([], [], color=c, ls=ls, lw=1.2, label=f'{n} rises')
               for n, (c, ls) in EVENT_STYLES.items()]
    if any(m.faults for m in moves):
        handles.append(Line2D([], [], color='tab:red', lw=1.2, label='fault / stop'))
    ax[0].legend(handles=ax[0].get_legend_handles_labels()[0] + handles, **LEGEND)
    for a in ax[:4]:
        a.grid(alpha=0.3)
    t = d.t
    if len(t) > 1:                  # event lines outside a cropped range do not widen it
        pad = 0.02 * (t[-1] - t[0])
        ax[-1].set_xlim(t[0] - pad, t[-1] + pad)
    fig.align_ylabels(ax)
    fig.tight_layout()
    fig.savefig(png, dpi=110)
    return png


def _draw_positions(a, d: AxisData) -> None:
    """Panel 1: commanded, true and measured slide position [mm]."""
    a.plot(d.t, d.command * MM, color='tab:blue', lw=1.6, label='commanded (reference_states)')
    if d.load_true is not None:
        a.plot(d.t, d.load_true * MM, color='tab:orange', lw=1.2, ls='--',
               label='slide, true (plant_states)')
    a.plot(d.t, d.measured * MM, color='tab:red', lw=0.8, ls=':',
           label='slide, measured (joint_states)')
    a.set_ylabel('position [mm]')


def _draw_following_error(a, d: AxisData, counts_per_m) -> None:
    """Panel 2: commanded - measured (and - true) slide [linear counts], symlog."""
    fe = (d.command - d.measured) * counts_per_m
    a.plot(d.t, fe, color='tab:red', lw=1.0, label='commanded − measured slide')
    if d.load_true is not None:
        a.plot(d.t, (d.command - d.load_true) * counts_per_m, color='tab:gray', lw=0.8,
               ls='--', label='commanded − true slide')
    a.set_yscale('symlog', linthresh=2.0, linscale=1.0)
    a.axhspan(-1, 1, color='tab:green', alpha=0.12, lw=0, label='±1 count')
    a.set_ylabel('following error\n[linear counts]')
    a.legend(**LEGEND)


def _draw_lost_motion(a, d: AxisData, counts_per_m) -> None:
    """Panel 3: motor - slide [linear counts], true (plant_states) and measured."""
    if d.motor_true is not None and d.load_true is not None:
        a.plot(d.t, (d.motor_true - d.load_true) * counts_per_m, color='tab:brown', lw=1.2,
               label='motor − slide, true (plant_states)')
    if d.motor is not None:
        a.plot(d.t, (d.motor - d.measured) * counts_per_m, color='tab:purple', lw=0.8, ls='--',
               label='motor − slide, measured (motor_states − joint_states)')
    a.set_ylabel('motor − slide\n[linear counts]')
    if a.lines:
        a.legend(**LEGEND)
    else:
        a.text(0.5, 0.5, 'no motor_states or plant_states in the bag', ha='center',
               va='center', transform=a.transAxes, color='0.4')


def _draw_output(a, d: AxisData, output_limit) -> None:
    """Panel 4: control output [V] and the ±output_limit lines (PMAC Ixx69)."""
    a.plot(d.t, d.output, color='tab:green', lw=0.8, label='output (joint_states effort)')
    for s in (1, -1):
        a.axhline(s * output_limit, color='tab:red', ls='--', lw=1.0,
                  label=f'±output_limit ({output_limit:g} V)' if s > 0 else None)
    a.set_ylim(-1.15 * output_limit, 1.15 * output_limit)
    a.set_ylabel('control output [V]')
    a.legend(**LEGEND)


def _draw_status_strip(a, d: AxisData) -> None:
    """Panel 5: a row per status bit that was set (STRIP_BITS, then fault bits in red), a bar
    wherever it was set."""
    words = d.status
    t_end = d.t[-1] if len(d.t) else 0.0
    present = [(b, c) for b, c in STRIP_BITS if len(words) and np.any(words & int(b))]
    faults = [b for b in FAULT_NAMES if len(words) and np.any(words & int(b))]
    rows = [(b.name, int(b), c) for b, c in present] + [(b.name, int(b), 'tab:red')
                                                        for b in faults]
    for row, (name, bit, colour) in enumerate(rows):
        on = (words & bit) != 0
        spans = []
        for k in range(len(words)):
            if on[k]:
                t1 = d.status_t[k + 1] if k + 1 < len(words) else t_end
                spans.append((d.status_t[k], max(t1 - d.status_t[k], 1e-4)))
        a.broken_barh(spans, (row - 0.35, 0.7), color=colour)
    a.set_yticks(range(len(rows)), [r[0] for r in rows], fontsize=8)
    a.set_ylim(len(rows) - 0.5, -0.5)
    a.set_xlabel('time [s] (header.stamp from the first joint_states)')
    a.set_ylabel('status')
    a.grid(axis='x', alpha=0.3)


def _mark_move(ax, m: MoveSummary, many: bool) -> None:
    """A move's event lines across all panels (MOVING, AT_TARGET, MOTION_DONE rises; fault
    rises red, named) and its label on the position panel (only its number when `many`)."""
    marks = [('MOVING', m.start)]
    if m.move_time is not None:
        marks.append(('AT_TARGET', m.start + m.move_time))
    if m.settle_time is not None:
        marks.append(('MOTION_DONE', m.start + m.settle_time))
    for name, x in marks:
        colour, ls = EVENT_STYLES[name]
        for a in ax:
            a.axvline(x, color=colour, ls=ls, lw=0.9, alpha=0.8)
    at: dict = {}               # fault edges at one tick share one line and label
    for name in m.faults:
        for x in m.events.get(name, []):
            at.setdefault(x, []).append(name)
    for x, names in sorted(at.items()):
        for a in ax:
            a.axvline(x, color='tab:red', lw=1.2)
        ax[0].annotate(' + '.join(names), (x, 0.98), xycoords=('data', 'axes fraction'),
                       xytext=(-2, 0), textcoords='offset points', color='tab:red',
                       fontsize=7, rotation=90, va='top', ha='right')
    settle = f', done {m.settle_time * 1000:.0f} ms' if m.settle_time is not None else ''
    if not many:
        text = (f'move {m.index}: → {m.target * MM:.3f} mm{settle}\n'
                f'final {m.final_error_counts:+.1f} counts')
    else:                       # many moves: the number only, details in the summary
        text = f'{m.index}'
    ax[0].annotate(text, (m.start, 0.02), xycoords=('data', 'axes fraction'), fontsize=8,
                   xytext=(3, 0), textcoords='offset points', va='bottom',
                   bbox=dict(boxstyle='round,pad=0.2', fc='white', ec='0.7', alpha=0.85))
