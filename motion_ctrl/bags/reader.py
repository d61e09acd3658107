"""Reading a motion_ctrl bag into one record per axis (`AxisData`): a rosbag2 bag in any storage
`rosbags` reads (mcap, sqlite3), made by `record` or `ros2 bag record`.

Time axis: header.stamp of the servo messages (the servo tick that produced them), seconds from
the first joint_states. The status word (std_msgs/UInt32) has no header; the controller
publishes it in the same tick right after joint_states, so each word is given the stamp of the
last joint_states recorded before it (bag time = receive order; the recorder's EventsExecutor
handles messages in arrival order). Several words on one tick are the transient-local history
a late subscriber receives at once: the last one is the state at that tick.

A bag that does not exist, is not a bag or lacks the topics raises `ReportError` (one line);
the bag of a killed recorder (an MCAP file, no metadata.yaml) names `record --repair DIR`.
"""
from __future__ import annotations

import pathlib
import struct
from typing import Any

import numpy as np
from rosbags.highlevel import AnyReader
from rosbags.typesys import Stores, get_typestore

from motion_ctrl.analysis.moves import AxisData
from motion_ctrl.bags.repair import needs_repair

JOINT_STATE = 'sensor_msgs/msg/JointState'
UINT32 = 'std_msgs/msg/UInt32'
_unpack = struct.unpack_from


class ReportError(Exception):
    """The bag cannot be reported on: one line for the user, exit code 2."""


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


def find_topic(topics: dict, name: str, namespace: str | None):
    """'/ns/joint_states' for name 'joint_states': exact under the namespace, else unique."""
    if namespace is not None:
        full = namespace.rstrip('/') + '/' + name
        return full if full in topics else None
    if '/' + name in topics:
        return '/' + name
    found = [t for t in topics if t.endswith('/' + name)]
    return found[0] if len(found) == 1 else None


def bag_dir(path: pathlib.Path) -> pathlib.Path:
    """The bag directory of `path` (a bag directory or the .mcap / .db3 in one); ReportError
    for a path that is none, naming `record --repair` for a killed recorder's bag."""
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
    path = bag_dir(pathlib.Path(path))
    try:
        reader = AnyReader([path], default_typestore=get_typestore(Stores.ROS2_KILTED))
        reader.open()
    except Exception as e:                     # AnyReaderError, yaml errors, corrupt files
        raise ReportError(f'{path}: not a readable rosbag2 bag ({_first_line(e)})') from None
    try:
        topics = {c.topic: c.msgtype for c in reader.connections}
        want, status_topics = _servo_topics(topics, namespace, path)
        series, status_raw = _read_messages(reader, want, status_topics, path)
    finally:
        reader.close()
    joint = series['joint_states']
    if not joint:
        raise ReportError(f'{path}: lacks topics joint_states (no messages)')
    if not series['reference_states']:
        raise ReportError(f'{path}: lacks topics reference_states (no messages)')
    axes = _axes_of(joint, axes, path)
    t0 = min(m[0] for m in joint)
    info = {'t0_ns': t0, 'topics': topics, 'path': path}
    joint_bag, joint_stamp = _receive_clock(joint, t0)
    data = {a: _axis_data(a, series, t0, status_timeline(status_raw.get(a, []), joint_bag,
                                                         joint_stamp))
            for a in axes}
    return data, info


def _first_line(e: Exception) -> str:
    return str(e).splitlines()[0] if str(e) else type(e).__name__


def _servo_topics(topics: dict, namespace: str | None, path) -> tuple[dict, dict]:
    """The bag's topics to read: ({'joint_states': topic, 'reference_states', 'motor_states',
    'plant_states': topic or None}, {status topic: axis}); ReportError naming those that lack
    (joint_states, reference_states and one <axis>/status are needed)."""
    want = {}
    missing = []
    for name in ('joint_states', 'reference_states'):
        topic = find_topic(topics, name, namespace)
        if topic is None or topics[topic] != JOINT_STATE:
            missing.append(name)
        want[name] = topic
    for name in ('motor_states', 'plant_states'):
        topic = find_topic(topics, name, namespace)
        want[name] = topic if topic and topics[topic] == JOINT_STATE else None
    status_topics = {t: t.rsplit('/', 2)[-2] for t, ty in topics.items()
                     if t.endswith('/status') and ty == UINT32 and t.count('/') >= 2}
    if not status_topics:
        missing.append('<axis>/status')
    if missing:
        have = ', '.join(sorted(topics)) or 'no topics'
        raise ReportError(f'{path}: lacks topics {", ".join(missing)} (has: {have})')
    return want, status_topics


def _read_messages(reader, want: dict, status_topics: dict, path) -> tuple[dict, dict]:
    """Every message of the wanted topics: ({name: [(stamp_ns, bag_ns, names, pos, vel, eff)]},
    {axis: [(bag_ns, status word)]}); ReportError on data that does not deserialize."""
    conns = [c for c in reader.connections
             if c.topic in want.values() or c.topic in status_topics]
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
    except Exception as e:
        raise ReportError(f'{path}: unreadable message data ({_first_line(e)})') from None
    return series, status_raw


def _axes_of(joint: list, axes, path) -> list:
    """The axes asked for (default: every joint) that joint_states names, in that order."""
    joint_names = []
    for m in joint:
        for n in m[2]:
            if n not in joint_names:
                joint_names.append(n)
    axes = [a for a in (axes or joint_names) if a in joint_names]
    if not axes:
        raise ReportError(f'{path}: none of the axes {axes} in joint_states {joint_names}')
    return axes


def _receive_clock(joint: list, t0: int) -> tuple[np.ndarray, np.ndarray]:
    """joint_states in receive order: (bag time [ns], its servo tick's stamp [s from t0]), to
    put each header-less status word on the tick last received before it."""
    joint_bag = np.asarray([m[1] for m in joint], dtype=np.int64)
    joint_stamp = (np.asarray([m[0] for m in joint], dtype=np.int64) - t0) * 1e-9
    order = np.argsort(joint_bag, kind='stable')
    return joint_bag[order], joint_stamp[order]


def _column(msgs: list, joint_name: str, field_index: int, t0: int):
    """(stamps [s from t0], values) of one joint's field (3 position, 5 effort) in `msgs`."""
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


def _on(t_grid, ts, vs):
    """The series (ts, vs) interpolated onto t_grid (None when it has no sample)."""
    if not len(ts):
        return None
    order = np.argsort(ts, kind='stable')
    return np.interp(t_grid, ts[order], vs[order])


def _axis_data(a: str, series: dict, t0: int, status: tuple) -> AxisData:
    """Axis `a`'s record on its joint_states stamps, the other topics interpolated onto them;
    `status` = (tick times, words) from `status_timeline`."""
    t, measured = _column(series['joint_states'], a, 3, t0)
    _, output = _column(series['joint_states'], a, 5, t0)
    order = np.argsort(t, kind='stable')
    t, measured = t[order], measured[order]
    output = output[order] if len(output) == len(t) else np.zeros_like(t)
    command = _on(t, *_column(series['reference_states'], a, 3, t0))
    motor = _on(t, *_column(series['motor_states'], a, 3, t0)) if series['motor_states'] \
        else None
    load_true = motor_true = None
    if series['plant_states']:
        load_true = _on(t, *_column(series['plant_states'], f'{a}_load', 3, t0))
        motor_true = _on(t, *_column(series['plant_states'], f'{a}_motor', 3, t0))
    return AxisData(a, t, command, measured, output, motor, load_true, motor_true, *status)


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
