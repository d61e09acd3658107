"""The figures of each move in a record, from plain arrays (numpy; no ROS, no plot): what
`report` prints and draws, and what a test computes on the in-process harness' trace.

A move starts where MOVING rises and lasts until the next move starts (or the record ends). Per
move: move time (MOVING to AT_TARGET), settle time (MOVING to MOTION_DONE), overshoot past the
target in the direction of the move, final error (slide - target at the end of the move's
window), error at MOTION_DONE, peak following error, time at the output limit, and the rises of
AT_TARGET, IN_FINE_POSITION, MOTION_DONE and the fault / stop bits inside the window.

`summarize_moves` takes any record (sample times, commanded and slide positions, status words);
`AxisData` is one axis' record as `motion_ctrl.bags.reader` reads it from a bag, and
`summarize_axis` the same figures of it.
"""
from __future__ import annotations

import math
from dataclasses import asdict, dataclass, field

import numpy as np

from motion_ctrl.core.registers import LOAD_COUNTS_PER_M
from msg_defs.status import Status

OUTPUT_LIMIT = 10.0                      # V, PMAC Ixx69 default here

FAULT_BITS = (Status.FOLLOWING_ERROR_FATAL | Status.FEEDBACK_FAULT | Status.OVERSPEED
              | Status.LIMIT | Status.ABORTED | Status.ESTOPPED | Status.STOPPED)
FAULT_NAMES = [b for b in Status if b & FAULT_BITS]
# Bits whose rises a move lists in its events, besides the fault / stop bits.
EVENT_NAMES = ('AT_TARGET', 'IN_FINE_POSITION', 'MOTION_DONE')


@dataclass
class MoveSummary:
    axis: str
    index: int                       # 1-based move number within the axis
    start: float                     # s: MOVING rose
    start_position: float            # m: commanded position before the move
    target: float                    # m: commanded position at AT_TARGET (else at the end)
    move_time: float | None          # s: MOVING -> AT_TARGET (None: never)
    settle_time: float | None        # s: MOVING -> MOTION_DONE (None: never)
    overshoot_counts: float          # past the target in the direction of the move, >= 0
    final_error_counts: float        # slide - target at the end of the move's window
    done_error_counts: float | None  # slide - target when MOTION_DONE rose
    peak_following_error_counts: float   # max |commanded - measured| in the window
    saturation_time: float           # s with |output| at the output limit
    end: float                       # s: end of the move's window
    events: dict = field(default_factory=dict)   # bit name -> [rise times in the window]
    faults: list = field(default_factory=list)   # fault / stop bit names seen in the window

    def as_dict(self) -> dict:
        return asdict(self)


@dataclass
class AxisData:
    """One axis' series on the joint_states stamp timeline (seconds from the bag's t0)."""
    axis: str
    t: np.ndarray
    command: np.ndarray             # reference_states position [m]
    measured: np.ndarray            # joint_states position [m]
    output: np.ndarray              # joint_states effort [V]
    motor: np.ndarray | None        # motor_states position [m] (load units)
    load_true: np.ndarray | None    # plant_states <axis>_load [m]
    motor_true: np.ndarray | None   # plant_states <axis>_motor [m]
    status_t: np.ndarray
    status: np.ndarray

    @property
    def actual(self) -> np.ndarray:
        return self.load_true if self.load_true is not None else self.measured


@dataclass
class _Record:
    """A record as `summarize_moves` reads it: arrays, the status bits' rises and the units."""
    t: np.ndarray
    command: np.ndarray
    actual: np.ndarray
    measured: np.ndarray
    output: np.ndarray | None
    dt: np.ndarray                  # sample period per sample (the time a saturated one lasts)
    status_t: np.ndarray
    words: np.ndarray
    edges: dict                     # bit name -> rise times
    counts_per_m: float
    output_limit: float


def rising_edges(times, words, bit) -> np.ndarray:
    """Times at which `bit` goes from clear to set in a status sequence. The first word is the
    state the record starts in, not an edge: a move already under way when the recording
    started is not a move of the record."""
    words = np.asarray(words, dtype=np.int64)
    on = (words & int(bit)) != 0
    prev = np.concatenate((on[:1], on[:-1]))
    return np.asarray(times, dtype=float)[on & ~prev]


def summarize_moves(t, command, actual, status, *, status_t=None, measured=None, output=None,
                    counts_per_m: float = LOAD_COUNTS_PER_M,
                    output_limit: float = OUTPUT_LIMIT, axis: str = 'x') -> list[MoveSummary]:
    """Split a record into moves and compute the figures of each.

    t, command, actual: sample times [s], commanded and slide positions [m] (same length);
    measured: the controller's measured slide position for the following error (default:
    actual); output: control output [V] per sample (saturation time); status: status words, per
    sample, or at the times `status_t` (sparse, e.g. only on change). A move starts where MOVING
    rises and its window ends where the next one starts (or at the end of the record).
    """
    t = np.asarray(t, dtype=float)
    actual = np.asarray(actual, dtype=float)
    st_t = t if status_t is None else np.asarray(status_t, dtype=float)
    words = np.asarray(status, dtype=np.int64)
    if not len(t) or not len(words):
        return []
    dt = np.diff(t, append=t[-1] + (np.median(np.diff(t)) if len(t) > 1 else 0.0))
    r = _Record(t, np.asarray(command, dtype=float), actual,
                actual if measured is None else np.asarray(measured, dtype=float),
                None if output is None else np.asarray(output, dtype=float), dt, st_t, words,
                {b.name: rising_edges(st_t, words, b) for b in Status}, counts_per_m,
                output_limit)
    starts = rising_edges(st_t, words, Status.MOVING)
    moves: list[MoveSummary] = []
    for i, start in enumerate(starts):
        end = starts[i + 1] if i + 1 < len(starts) else math.inf
        idx = np.flatnonzero((t >= start) & (t < end))
        if len(idx):
            moves.append(_summarize_move(r, start, end, idx, axis, len(moves) + 1))
    return moves


def _summarize_move(r: _Record, start, end, idx: np.ndarray, axis: str,
                    index: int) -> MoveSummary:
    """The figures of one move: its window [start, end) holds the samples `idx`."""
    first, last = idx[0], idx[-1]
    start_pos = r.command[first - 1 if first > 0 else first]
    rises = {name: e[(e >= start) & (e < end)] for name, e in r.edges.items()}
    at_target = float(rises['AT_TARGET'][0]) if len(rises['AT_TARGET']) else None
    done = float(rises['MOTION_DONE'][0]) if len(rises['MOTION_DONE']) else None
    k_target = np.searchsorted(r.t, at_target) if at_target is not None else last
    target = r.command[min(k_target, last)]
    direction = math.copysign(1.0, target - start_pos) if target != start_pos else 1.0
    err = (r.actual[idx] - target) * r.counts_per_m
    fe = np.abs(r.command[idx] - r.measured[idx]) * r.counts_per_m
    done_error = None
    if done is not None:
        k = min(int(np.searchsorted(r.t, done)), len(r.t) - 1)
        done_error = float((r.actual[k] - target) * r.counts_per_m)
    in_window = (r.status_t >= start) & (r.status_t < end)
    seen = int(np.bitwise_or.reduce(r.words[in_window])) if in_window.any() else 0
    return MoveSummary(
        axis=axis, index=index, start=float(start), start_position=float(start_pos),
        target=float(target),
        move_time=None if at_target is None else at_target - float(start),
        settle_time=None if done is None else done - float(start),
        overshoot_counts=max(0.0, float(np.max(err * direction))),
        final_error_counts=float(err[-1]), done_error_counts=done_error,
        peak_following_error_counts=float(fe.max()),
        saturation_time=_saturation_time(r, idx), end=float(r.t[last]),
        events={name: [float(x) for x in e] for name, e in rises.items()
                if len(e) and (name in EVENT_NAMES or Status[str(name)] & FAULT_BITS)},
        faults=[b.name for b in FAULT_NAMES if seen & b])


def _saturation_time(r: _Record, idx: np.ndarray) -> float:
    """Seconds of the samples `idx` with |output| at the output limit (0 without output)."""
    if r.output is None:
        return 0.0
    out = r.output[idx]
    return float(np.sum(r.dt[idx][np.abs(out) >= r.output_limit * (1 - 1e-9)]))


def summarize_axis(d: AxisData, counts_per_m=LOAD_COUNTS_PER_M,
                   output_limit=OUTPUT_LIMIT) -> list[MoveSummary]:
    """`summarize_moves` of one axis read from a bag."""
    return summarize_moves(d.t, d.command, d.actual, d.status, status_t=d.status_t,
                           measured=d.measured, output=d.output, counts_per_m=counts_per_m,
                           output_limit=output_limit, axis=d.axis)


def format_summary(summary: dict) -> str:
    """The printed table: one line per axis per move."""
    head = (f'{"axis":<5}{"move":>5}{"start [s]":>10}{"target [mm]":>13}{"move [ms]":>11}'
            f'{"settle [ms]":>13}{"overshoot":>11}{"final err":>11}{"err@done":>10}'
            f'{"peak FE":>10}{"saturated":>11}  faults')
    units = (f'{"":<5}{"":>5}{"":>10}{"":>13}{"":>11}{"":>13}{"[counts]":>11}{"[counts]":>11}'
             f'{"[counts]":>10}{"[counts]":>10}{"[s]":>11}')
    lines = [head, units]

    def ms(v):
        return f'{v * 1000:.1f}' if v is not None else '-'
    for axis, moves in summary.items():
        if not moves:
            lines.append(f'{axis:<5}  (no move: MOVING never rose)')
        for m in moves:
            done = f'{m.done_error_counts:+.2f}' if m.done_error_counts is not None else '-'
            lines.append(
                f'{axis:<5}{m.index:>5}{m.start:>10.3f}{m.target * 1000:>13.4f}'
                f'{ms(m.move_time):>11}{ms(m.settle_time):>13}{m.overshoot_counts:>11.2f}'
                f'{m.final_error_counts:>+11.2f}{done:>10}'
                f'{m.peak_following_error_counts:>10.1f}{m.saturation_time:>11.3f}  '
                + (','.join(m.faults) or '-'))
    return '\n'.join(lines)
