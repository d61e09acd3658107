"""`report`: plot and summarise the moves in a motion_ctrl bag.

    python -m motion_ctrl.tools.report BAG -o move.png [--axis x] [--load-counts-per-m N]
                                 [--output-limit V] [--start S] [--end S]
    ros2 run motion_ctrl report BAG -o move.png

Reads a rosbag2 bag (any storage `rosbags` reads: mcap, sqlite3) made by `motion_ctrl.tools.record`
or `ros2 bag record`, and draws one figure per axis (one axis: the -o path; several:
``<stem>_<axis>.png``), stacked panels on a shared time axis:

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

Time axis: header.stamp of the servo messages (the servo tick that produced them), seconds from
the first joint_states. The status word (std_msgs/UInt32) has no header; the controller
publishes it in the same tick right after joint_states, so each word is given the stamp of the
last joint_states recorded before it (bag time = receive order; the recorder's EventsExecutor
handles messages in arrival order). Several words on one tick are the transient-local history
a late subscriber receives at once: the last one is the state at that tick.

A summary is printed per axis per move (a move starts where MOVING rises and lasts until the
next move): move time (MOVING to AT_TARGET), settle time (MOVING to MOTION_DONE), overshoot past
the target in the direction of the move, final error (slide - target at the end of the move's
window), error at MOTION_DONE, peak following error, time at the output limit. All figures come
from `summarize_moves`, a plain function over arrays, so the in-process harness trace gives the
same numbers (test/test_record_report.py compares them).

API for scripts and the demo::

    summary = make_report('bag_dir', 'move.png')      # {axis: [MoveSummary, ...]}
    print(format_summary(summary))

A bag that does not exist, is not a bag or lacks the topics is a one-line error, exit code 2;
the bag of a killed recorder (an MCAP file, no metadata.yaml) names `record --repair DIR`.
"""
from __future__ import annotations

import argparse
import math
import pathlib
import struct
import sys
from typing import Any
from dataclasses import asdict, dataclass, field

import numpy as np

from msg_defs.status import Status

LOAD_COUNTS_PER_M = 10000 / 0.0254      # 2.54 um linear encoder (the Galil slide)
OUTPUT_LIMIT = 10.0                      # V, PMAC Ixx69 default here

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
FAULT_BITS = (Status.FOLLOWING_ERROR_FATAL | Status.FEEDBACK_FAULT | Status.OVERSPEED
              | Status.LIMIT | Status.ABORTED | Status.ESTOPPED | Status.STOPPED)
FAULT_NAMES = [b for b in Status if b & FAULT_BITS]
_unpack = struct.unpack_from
# Legends right of the panels: they never hide data.
LEGEND = dict(loc='upper left', bbox_to_anchor=(1.01, 1.0), fontsize=8, borderaxespad=0.0)


class ReportError(Exception):
    """The bag cannot be reported on: one line for the user, exit code 2."""


# -- the summary: plain arrays in, figures out ------------------------------------------------
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
    command = np.asarray(command, dtype=float)
    actual = np.asarray(actual, dtype=float)
    measured = actual if measured is None else np.asarray(measured, dtype=float)
    st_t = t if status_t is None else np.asarray(status_t, dtype=float)
    words = np.asarray(status, dtype=np.int64)
    if not len(t) or not len(words):
        return []
    starts = rising_edges(st_t, words, Status.MOVING)
    edges = {b.name: rising_edges(st_t, words, b) for b in Status}
    # Sample period per sample (the time a saturated sample lasts).
    dt = np.diff(t, append=t[-1] + (np.median(np.diff(t)) if len(t) > 1 else 0.0))
    moves: list[MoveSummary] = []
    for i, start in enumerate(starts):
        end = starts[i + 1] if i + 1 < len(starts) else math.inf
        win = (t >= start) & (t < end)
        if not win.any():
            continue
        idx = np.flatnonzero(win)
        first, last = idx[0], idx[-1]
        before = first - 1 if first > 0 else first
        start_pos = command[before]

        def first_edge(name):
            e = edges[name]
            e = e[(e >= start) & (e < end)]
            return float(e[0]) if len(e) else None
        at_target = first_edge('AT_TARGET')
        done = first_edge('MOTION_DONE')
        k_target = np.searchsorted(t, at_target) if at_target is not None else last
        target = command[min(k_target, last)]
        direction = math.copysign(1.0, target - start_pos) if target != start_pos else 1.0
        err = (actual[idx] - target) * counts_per_m
        overshoot = max(0.0, float(np.max(err * direction)))
        fe = np.abs(command[idx] - measured[idx]) * counts_per_m
        done_error = None
        if done is not None:
            k = min(np.searchsorted(t, done), len(t) - 1)
            done_error = float((actual[k] - target) * counts_per_m)
        sat = 0.0
        if output is not None:
            out = np.asarray(output, dtype=float)[idx]
            sat = float(np.sum(dt[idx][np.abs(out) >= output_limit * (1 - 1e-9)]))
        wmask = (st_t >= start) & (st_t < end)
        seen = int(np.bitwise_or.reduce(words[wmask])) if wmask.any() else 0
        events = {name: [float(x) for x in e[(e >= start) & (e < end)]]
                  for name, e in edges.items() if name in (
                      'AT_TARGET', 'IN_FINE_POSITION', 'MOTION_DONE') or
                  Status[str(name)] & FAULT_BITS}
        moves.append(MoveSummary(
            axis=axis, index=len(moves) + 1, start=float(start), start_position=float(start_pos),
            target=float(target),
            move_time=None if at_target is None else at_target - float(start),
            settle_time=None if done is None else done - float(start),
            overshoot_counts=overshoot, final_error_counts=float(err[-1]),
            done_error_counts=done_error, peak_following_error_counts=float(fe.max()),
            saturation_time=sat, end=float(t[last]),
            events={k: v for k, v in events.items() if v},
            faults=[b.name for b in FAULT_NAMES if seen & b]))
    return moves


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


# -- reading a bag ------------------------------------------------------------------------------
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


def parse_joint_state(raw) -> tuple:
    """Little-endian CDR sensor_msgs/JointState -> (stamp_ns, names, position, velocity,
    effort), ~10x faster than a generic deserializer on a 1 kHz recording. Raises ValueError
    (or struct.error) on anything else; the caller then uses the typestore."""
    if len(raw) < 12 or raw[0] != 0 or raw[1] != 1:          # CDR_LE encapsulation
        raise ValueError('not little-endian CDR')
    b = memoryview(raw)[4:]                                   # alignment is relative to here
    sec, nsec = _unpack('<iI', b, 0)
    (n,) = _unpack('<I', b, 8)
    o = 12 + n                                                # header.frame_id
    o = (o + 3) & ~3
    (count,) = _unpack('<I', b, o)
    o += 4
    names = []
    for _ in range(count):
        o = (o + 3) & ~3
        (n,) = _unpack('<I', b, o)
        o += 4
        if n < 1 or o + n > len(b):
            raise ValueError('bad string')
        names.append(bytes(b[o:o + n - 1]).decode())
        o += n
    arrays = []
    for _ in range(3):
        o = (o + 3) & ~3
        (n,) = _unpack('<I', b, o)
        o += 4
        if n:
            o = (o + 7) & ~7
        arrays.append(_unpack(f'<{n}d', b, o))
        o += 8 * n
    return (sec * 1_000_000_000 + nsec, names) + tuple(arrays)


def _find_topic(topics: dict, name: str, namespace: str | None):
    """'/ns/joint_states' for name 'joint_states': exact under the namespace, else unique."""
    if namespace is not None:
        full = namespace.rstrip('/') + '/' + name
        return full if full in topics else None
    if '/' + name in topics:
        return '/' + name
    found = [t for t in topics if t.endswith('/' + name)]
    return found[0] if len(found) == 1 else None


def _bag_dir(path: pathlib.Path) -> pathlib.Path:
    from motion_ctrl.tools.bag_repair import needs_repair
    if not path.exists():
        raise ReportError(f'{path}: no such bag (file or directory not found)')
    if path.is_file() and path.suffix == '.mcap' and needs_repair(path.parent):
        path = path.parent
    if path.is_file() and (path.parent / 'metadata.yaml').is_file():
        return path.parent            # the .mcap / .db3 inside a bag directory
    if needs_repair(path):
        raise ReportError(f'{path}: an MCAP file without metadata.yaml: the recorder was '
                          f'killed before it closed the bag; `record --repair {path}` makes a '
                          f'readable bag of it')
    if path.is_dir() and not (path / 'metadata.yaml').is_file():
        raise ReportError(f'{path}: not a rosbag2 bag (no metadata.yaml: was the recorder '
                          f'killed before it closed the bag?)')
    return path


def load_bag(path, axes=None, namespace: str | None = None) -> tuple[dict, dict]:
    """Read a bag into {axis: AxisData}; also returns info (t0_ns, topics, path)."""
    from rosbags.highlevel import AnyReader
    from rosbags.typesys import Stores, get_typestore

    path = _bag_dir(pathlib.Path(path))
    try:
        reader = AnyReader([path], default_typestore=get_typestore(Stores.ROS2_KILTED))
        reader.open()
    except Exception as e:                     # AnyReaderError, yaml errors, corrupt files
        why = str(e).splitlines()[0] if str(e) else type(e).__name__
        raise ReportError(f'{path}: not a readable rosbag2 bag ({why})') from None
    try:
        topics = {c.topic: c.msgtype for c in reader.connections}
        want = {}
        missing = []
        for name in ('joint_states', 'reference_states'):
            topic = _find_topic(topics, name, namespace)
            if topic is None or topics[topic] != 'sensor_msgs/msg/JointState':
                missing.append(name)
            want[name] = topic
        for name in ('motor_states', 'plant_states'):
            topic = _find_topic(topics, name, namespace)
            want[name] = topic if topic and topics[topic] == 'sensor_msgs/msg/JointState' \
                else None
        status_topics = {t: t.rsplit('/', 2)[-2] for t, ty in topics.items()
                         if t.endswith('/status') and ty == 'std_msgs/msg/UInt32'
                         and t.count('/') >= 2}
        if not status_topics:
            missing.append('<axis>/status')
        if missing:
            have = ', '.join(sorted(topics)) or 'no topics'
            raise ReportError(f'{path}: lacks topics {", ".join(missing)} (has: {have})')
        conns = [c for c in reader.connections
                 if c.topic in want.values() or c.topic in status_topics]
        # name -> [(stamp_ns, bag_ns, names, pos, vel, eff)]
        series: dict[str, list] = {k: [] for k in want}
        by_topic = {v: k for k, v in want.items() if v}
        status_raw: dict[str, list] = {a: [] for a in status_topics.values()}
        try:
            for conn, bag_ns, raw in reader.messages(connections=conns):
                if conn.topic in status_topics:
                    msg: Any = reader.deserialize(raw, conn.msgtype)
                    status_raw[status_topics[conn.topic]].append((bag_ns, int(msg.data)))
                    continue
                try:
                    fields = parse_joint_state(raw)
                except (ValueError, struct.error, UnicodeDecodeError):
                    msg = reader.deserialize(raw, conn.msgtype)     # big-endian, odd data
                    fields = (msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec,
                              list(msg.name), msg.position, msg.velocity, msg.effort)
                series[by_topic[conn.topic]].append((fields[0], bag_ns) + fields[1:])
        except ReportError:
            raise
        except Exception as e:
            msg = str(e).splitlines()[0] if str(e) else type(e).__name__
            raise ReportError(f'{path}: unreadable message data ({msg})') from None
    finally:
        reader.close()

    joint = series['joint_states']
    if not joint:
        raise ReportError(f'{path}: lacks topics joint_states (no messages)')
    if not series['reference_states']:
        raise ReportError(f'{path}: lacks topics reference_states (no messages)')
    joint_names = []
    for m in joint:
        for n in m[2]:
            if n not in joint_names:
                joint_names.append(n)
    axes = [a for a in (axes or joint_names) if a in joint_names]
    if not axes:
        raise ReportError(f'{path}: none of the axes {axes} in joint_states {joint_names}')
    t0 = min(m[0] for m in joint)
    info = {'t0_ns': t0, 'topics': topics, 'path': path}
    # joint_states in receive order: bag time -> the servo tick (stamp) last received.
    joint_bag = np.asarray([m[1] for m in joint], dtype=np.int64)
    joint_stamp = (np.asarray([m[0] for m in joint], dtype=np.int64) - t0) * 1e-9
    order = np.argsort(joint_bag, kind='stable')
    joint_bag, joint_stamp = joint_bag[order], joint_stamp[order]

    def column(msgs, joint_name, field_index):
        ts, vs = [], []
        for m in msgs:
            try:
                k = m[2].index(joint_name)
            except ValueError:
                continue
            arr = m[field_index]
            if k < len(arr):
                ts.append(m[0])
                vs.append(arr[k])
        return (np.asarray(ts, dtype=np.int64) - t0) * 1e-9, np.asarray(vs, dtype=float)

    def on(t_grid, ts, vs):
        if not len(ts):
            return None
        order = np.argsort(ts, kind='stable')
        return np.interp(t_grid, ts[order], vs[order])

    data = {}
    for a in axes:
        t, measured = column(joint, a, 3)
        _, output = column(joint, a, 5)
        order = np.argsort(t, kind='stable')
        t, measured = t[order], measured[order]
        output = output[order] if len(output) == len(t) else np.zeros_like(t)
        command = on(t, *column(series['reference_states'], a, 3))
        motor = on(t, *column(series['motor_states'], a, 3)) if series['motor_states'] \
            else None
        load_true = motor_true = None
        if series['plant_states']:
            load_true = on(t, *column(series['plant_states'], f'{a}_load', 3))
            motor_true = on(t, *column(series['plant_states'], f'{a}_motor', 3))
        st_t, st_w = status_timeline(status_raw.get(a, []), joint_bag, joint_stamp)
        data[a] = AxisData(a, t, command, measured, output, motor, load_true, motor_true,
                           st_t, st_w)
    return data, info


def status_timeline(words, joint_bag, joint_stamp):
    """[(bag_ns, word)] -> (tick times [s], words): each word on the stamp of the last
    joint_states received before it (the first tick if none was).

    Several words on one tick are a burst: the transient-local history a late subscriber gets
    at once, possibly followed by a live change. Only the first and the last word of a burst
    are kept: the state before and after it, so a move that starts during the burst still
    shows its MOVING edge, and a whole past move replayed from the history shows none."""
    if not len(words):
        return np.zeros(0), np.zeros(0, dtype=np.int64)
    words = sorted(words, key=lambda w: w[0])
    bag = np.asarray([w[0] for w in words], dtype=np.int64)
    k = np.searchsorted(joint_bag, bag, side='right') - 1
    t = np.where(k >= 0, joint_stamp[np.clip(k, 0, None)], joint_stamp.min())
    w = np.asarray([x[1] for x in words], dtype=np.int64)
    # Keep the last word of each run on one tick; ticks are non-decreasing in receive order
    # except for reordering across topics, which np.maximum.accumulate absorbs.
    t = np.maximum.accumulate(t)
    first = np.insert(t[1:] != t[:-1], 0, True)
    last = np.append(t[1:] != t[:-1], True)
    keep = last.copy()
    starts = np.flatnonzero(first)
    ends = np.flatnonzero(last)
    for a, b in zip(starts, ends):
        if b > a and w[a] != w[b]:
            keep[a] = True
    return t[keep], w[keep]


def summarize_axis(d: AxisData, counts_per_m=LOAD_COUNTS_PER_M,
                   output_limit=OUTPUT_LIMIT) -> list[MoveSummary]:
    return summarize_moves(d.t, d.command, d.actual, d.status, status_t=d.status_t,
                           measured=d.measured, output=d.output, counts_per_m=counts_per_m,
                           output_limit=output_limit, axis=d.axis)


# -- drawing ------------------------------------------------------------------------------------
def _crop(d: AxisData, start, end) -> AxisData:
    lo = -math.inf if start is None else start
    hi = math.inf if end is None else end
    m = (d.t >= lo) & (d.t <= hi)
    s = (d.status_t >= lo) & (d.status_t <= hi)

    def c(a):
        return None if a is None else a[m]
    # Keep the word in force at the crop start.
    before = np.flatnonzero(d.status_t < lo)
    st_t, st_w = d.status_t[s], d.status[s]
    if len(before) and m.any():
        st_t = np.concatenate(([d.t[m][0]], st_t))
        st_w = np.concatenate(([d.status[before[-1]]], st_w))
    return AxisData(d.axis, d.t[m], d.command[m], d.measured[m], d.output[m], c(d.motor),
                    c(d.load_true), c(d.motor_true), st_t, st_w)


def draw_axis(d: AxisData, moves, png, *, counts_per_m=LOAD_COUNTS_PER_M,
              output_limit=OUTPUT_LIMIT, title=None):
    import matplotlib
    matplotlib.use('Agg')
    import matplotlib.pyplot as plt
    from matplotlib.lines import Line2D

    fig, ax = plt.subplots(5, 1, sharex=True, figsize=(15, 13),
                           gridspec_kw={'height_ratios': [3, 2.2, 2, 2, 2.4]})
    fig.suptitle(title or f'axis {d.axis}', fontsize=13)
    t = d.t
    mm = 1000.0

    a = ax[0]
    a.plot(t, d.command * mm, color='tab:blue', lw=1.6, label='commanded (reference_states)')
    if d.load_true is not None:
        a.plot(t, d.load_true * mm, color='tab:orange', lw=1.2, ls='--',
               label='slide, true (plant_states)')
    a.plot(t, d.measured * mm, color='tab:red', lw=0.8, ls=':',
           label='slide, measured (joint_states)')
    a.set_ylabel('position [mm]')

    a = ax[1]
    fe = (d.command - d.measured) * counts_per_m
    a.plot(t, fe, color='tab:red', lw=1.0, label='commanded − measured slide')
    if d.load_true is not None:
        a.plot(t, (d.command - d.load_true) * counts_per_m, color='tab:gray', lw=0.8, ls='--',
               label='commanded − true slide')
    a.set_yscale('symlog', linthresh=2.0, linscale=1.0)
    a.axhspan(-1, 1, color='tab:green', alpha=0.12, lw=0, label='±1 count')
    a.set_ylabel('following error\n[linear counts]')
    a.legend(**LEGEND)

    a = ax[2]
    if d.motor_true is not None and d.load_true is not None:
        a.plot(t, (d.motor_true - d.load_true) * counts_per_m, color='tab:brown', lw=1.2,
               label='motor − slide, true (plant_states)')
    if d.motor is not None:
        a.plot(t, (d.motor - d.measured) * counts_per_m, color='tab:purple', lw=0.8, ls='--',
               label='motor − slide, measured (motor_states − joint_states)')
    a.set_ylabel('motor − slide\n[linear counts]')
    if a.lines:
        a.legend(**LEGEND)
    else:
        a.text(0.5, 0.5, 'no motor_states or plant_states in the bag', ha='center',
               va='center', transform=a.transAxes, color='0.4')

    a = ax[3]
    a.plot(t, d.output, color='tab:green', lw=0.8, label='output (joint_states effort)')
    for s in (1, -1):
        a.axhline(s * output_limit, color='tab:red', ls='--', lw=1.0,
                  label=f'±output_limit ({output_limit:g} V)' if s > 0 else None)
    a.set_ylim(-1.15 * output_limit, 1.15 * output_limit)
    a.set_ylabel('control output [V]')
    a.legend(**LEGEND)

    # Status strip.
    a = ax[4]
    words = d.status
    t_end = t[-1] if len(t) else 0.0
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

    # Event lines across all panels, and labels on top.
    styles = {'MOVING': ('tab:green', '-'), 'AT_TARGET': ('tab:blue', ':'),
              'MOTION_DONE': ('black', '--')}
    for m in moves:
        marks = [('MOVING', m.start)]
        if m.move_time is not None:
            marks.append(('AT_TARGET', m.start + m.move_time))
        if m.settle_time is not None:
            marks.append(('MOTION_DONE', m.start + m.settle_time))
        for name, x in marks:
            colour, ls = styles[name]
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
        if len(moves) <= 4:
            text = (f'move {m.index}: → {m.target * mm:.3f} mm{settle}\n'
                    f'final {m.final_error_counts:+.1f} counts')
        else:                       # many moves: the number only, details in the summary
            text = f'{m.index}'
        ax[0].annotate(text, (m.start, 0.02), xycoords=('data', 'axes fraction'), fontsize=8,
                       xytext=(3, 0), textcoords='offset points', va='bottom',
                       bbox=dict(boxstyle='round,pad=0.2', fc='white', ec='0.7', alpha=0.85))
    handles = [Line2D([], [], color=c, ls=ls, lw=1.2, label=f'{n} rises')
               for n, (c, ls) in styles.items()]
    if any(m.faults for m in moves):
        handles.append(Line2D([], [], color='tab:red', lw=1.2, label='fault / stop'))
    ax[0].legend(handles=ax[0].get_legend_handles_labels()[0] + handles, **LEGEND)
    for a in ax[:4]:
        a.grid(alpha=0.3)
    if len(t) > 1:                  # event lines outside a cropped range do not widen it
        pad = 0.02 * (t[-1] - t[0])
        ax[-1].set_xlim(t[0] - pad, t[-1] + pad)
    fig.align_ylabels(ax)
    fig.tight_layout()
    fig.savefig(png, dpi=110)
    plt.close(fig)
    return png


def png_paths(png, axes) -> dict:
    """-o path per axis: the path itself for one axis, <stem>_<axis><suffix> for several."""
    png = pathlib.Path(png)
    if len(axes) == 1:
        return {axes[0]: png}
    return {a: png.with_name(f'{png.stem}_{a}{png.suffix or ".png"}') for a in axes}


def make_report(bag, png=None, *, axes=None, load_counts_per_m=LOAD_COUNTS_PER_M,
                output_limit=OUTPUT_LIMIT, start=None, end=None, namespace=None) -> dict:
    """Read `bag`, draw the figure(s) (when png is given) and return {axis: [MoveSummary]}.

    The summary covers the whole bag; start/end [s] crop the plot only. Raises ReportError.
    """
    data, info = load_bag(bag, axes, namespace)
    summary = {a: summarize_axis(d, load_counts_per_m, output_limit) for a, d in data.items()}
    if png is not None:
        name = pathlib.Path(info['path']).name
        for a, path in png_paths(png, list(data)).items():
            d = _crop(data[a], start, end) if (start is not None or end is not None) \
                else data[a]
            moves = [m for m in summary[a] if (start is None or m.start >= start)
                     and (end is None or m.start <= end)]
            draw_axis(d, moves, path, counts_per_m=load_counts_per_m,
                      output_limit=output_limit, title=f'{name}: axis {a}')
    return summary


def main(argv=None) -> int:
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
    args = ap.parse_args(argv)
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
