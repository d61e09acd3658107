"""The bag of a killed recorder (issue 11), without ROS: `bags.repair.flush` puts everything
written so far into the file, and `record --repair` makes a complete bag, readable by `rosbags`
and the `mcap` package, of an MCAP file cut off anywhere.

Oracle: every message record is unique (channel id, log time and data), so where it ends in the
complete file is found by searching the file for it; a copy of the file cut at byte k
must repair to exactly the messages whose records end at or before k, in order.
"""
import pathlib
import random
import shutil
import struct
import subprocess
import sys

import numpy as np
import pytest

import conftest

from motion_ctrl.bags import reader
from motion_ctrl.bags import repair as bag_repair
from motion_ctrl.tools import report

REPO_ROOT = pathlib.Path(conftest.REPO_ROOT)
JS = 'sensor_msgs/msg/JointState'
U32 = 'std_msgs/msg/UInt32'


def _typestore():
    from rosbags.typesys import Stores, get_typestore
    return get_typestore(Stores.ROS2_KILTED)


def write_bag(path, n=1200, flush_every=100, close=False):
    """A recorder's bag as bags.writer.Recorder writes it: joint_states at 1 kHz (log time = stamp),
    x/status (transient local) every 50th tick, a flush every `flush_every` messages (the
    recorder's FLUSH_PERIOD). Returns ([(topic, log_time, raw)], writer or None)."""
    from rosbags.rosbag2 import StoragePlugin, Writer
    import msg_defs as md
    from motion_ctrl.bags.writer import _rosbags_qos
    ts = _typestore()
    JointState, Header, Time = (ts.types[t] for t in (
        JS, 'std_msgs/msg/Header', 'builtin_interfaces/msg/Time'))
    UInt32 = ts.types[U32]
    w = Writer(path, version=Writer.VERSION_LATEST, storage_plugin=StoragePlugin.MCAP)
    w.open()
    bag_repair.check_flushable(w)
    cj = w.add_connection('/joint_states', JS, typestore=ts,
                          offered_qos_profiles=[_rosbags_qos(md.SERVO_QOS)])
    cs = w.add_connection('/x/status', U32, typestore=ts,
                          offered_qos_profiles=[_rosbags_qos(md.STATUS_QOS)])
    written = []
    t0 = 1_795_309_000_000_000_000
    for k in range(n):
        ns = t0 + k * 1_000_000
        raw = bytes(ts.serialize_cdr(JointState(
            header=Header(stamp=Time(sec=ns // 10**9, nanosec=ns % 10**9), frame_id=''),
            name=['x'], position=np.array([k * 1e-6]), velocity=np.zeros(1),
            effort=np.zeros(1)), JS))
        w.write(cj, ns, raw)
        written.append(('/joint_states', ns, raw))
        if k % 50 == 0:
            raw = bytes(ts.serialize_cdr(UInt32(data=k), U32))
            w.write(cs, ns, raw)
            written.append(('/x/status', ns, raw))
        if len(written) % flush_every == 0:
            bag_repair.flush(w)
    if close:
        w.close()
        return written, None
    return written, w


def read_all(path):
    """rosbags' Reader: [(topic, log_time, raw)], metadata counts, connections by topic."""
    from rosbags.rosbag2 import Reader
    with Reader(path) as r:
        msgs = [(c.topic, t, bytes(raw)) for c, t, raw in r.messages()]
        conns = {c.topic: c for c in r.connections}
        meta = {c.topic: c.msgcount for c in r.connections}
        total = r.message_count
    assert total == len(msgs)
    return msgs, meta, conns


def mcap_count(path):
    from mcap.reader import make_reader
    (f,) = pathlib.Path(path).glob('*.mcap')
    with open(f, 'rb') as fh:
        reader = make_reader(fh)
        assert reader.get_summary() is not None      # indexed: a complete file
        return sum(1 for _ in reader.iter_messages())


@pytest.fixture(scope='module')
def killed(tmp_path_factory):
    """The file a killed recorder leaves (flushed, never closed), the messages written, and
    where each one's record ends in that file."""
    path = tmp_path_factory.mktemp('killed') / 'bag'
    written, w = write_bag(path)
    bag_repair.flush(w)           # the last periodic flush before the kill
    data = (path / 'bag.mcap').read_bytes()
    ends = []
    channel_ids = {'/joint_states': 1, '/x/status': 2}
    for topic, ns, raw in written:
        # The message record's body: channel id, sequence 0, log and publish time, data.
        body = struct.pack('<HIQQ', channel_ids[topic], 0, ns, ns) + raw
        pos = data.find(body)
        assert pos > 0 and data.find(body, pos + 1) == -1
        ends.append(pos + len(body))
    assert ends == sorted(ends)
    w.abort()                     # close the file object without writing anything more
    assert (path / 'bag.mcap').read_bytes() == data
    return dict(path=path, data=data, written=written, ends=ends)


def _cut(killed, k, tmp_path):
    bag = tmp_path / f'cut{k}'
    bag.mkdir()
    (bag / 'cut.mcap').write_bytes(killed['data'][:k])     # the file name need not match
    return bag


def test_a_killed_recorders_bag_does_not_open_and_report_says_repair(killed, tmp_path, capsys):
    from rosbags.rosbag2 import Reader
    bag = _cut(killed, len(killed['data']), tmp_path)
    assert not (bag / 'metadata.yaml').exists()
    with pytest.raises(FileNotFoundError):
        Reader(bag).open()
    (bag / 'metadata.yaml').write_text('')      # even with one, rosbags wants the footer
    bag2 = tmp_path / 'fake_meta'
    shutil.copytree(bag, bag2)
    (bag2 / 'metadata.yaml').unlink()
    assert bag_repair.needs_repair(bag2) and not bag_repair.needs_repair(bag)
    for arg in (bag2, bag2 / 'cut.mcap'):
        assert report.main([str(arg)]) == 2
        err = capsys.readouterr().err.strip()
        assert err.startswith('report: error:') and '\n' not in err
        assert f'record --repair {bag2}' in err, err


def test_repair_of_the_flushed_file_keeps_every_message(killed, tmp_path):
    """What `flush` wrote is all there: the file as it was at the kill repairs to every message
    written before the last flush."""
    bag = _cut(killed, len(killed['data']), tmp_path)
    result = bag_repair.repair(bag)
    msgs, meta, conns = read_all(bag)
    assert msgs == killed['written']
    assert meta == result.counts == {'/joint_states': 1200, '/x/status': 24}
    assert mcap_count(bag) == len(msgs)
    assert not result.complete and 'cut off' not in result.stopped
    # Types, QoS and type hashes as the recorder wrote them.
    import msg_defs as md
    from rosbags.interfaces import QosDurability
    assert conns['/x/status'].ext.offered_qos_profiles[0].durability == \
        QosDurability.TRANSIENT_LOCAL
    assert conns['/joint_states'].ext.offered_qos_profiles[0].depth == md.SERVO_QOS.depth
    assert conns['/joint_states'].digest == _typestore().hash_rihs01(JS)
    assert not (bag / '.repair').exists()
    assert sorted(p.name for p in bag.iterdir()) == ['cut.mcap', 'metadata.yaml']


def _expected(killed, k):
    return [m for m, e in zip(killed['written'], killed['ends']) if e <= k]


def test_repair_of_a_file_cut_anywhere(killed, tmp_path):
    """Cut in the middle of chunks, of message records inside them, of message index records,
    right at chunk boundaries: every complete message before the cut, nothing else."""
    data, ends = killed['data'], killed['ends']
    rng = random.Random(11)
    cuts = {len(data) - 1, len(data) - 500}
    cuts |= {rng.randrange(200, len(data)) for _ in range(40)}
    # At and around message ends (a message record complete or one byte short).
    for i in rng.sample(range(len(ends)), 15):
        cuts |= {ends[i] - 1, ends[i], ends[i] + 1}
    partial_seen = 0
    for k in sorted(cuts):
        bag = _cut(killed, k, tmp_path)
        result = bag_repair.repair(bag)
        msgs, meta, _ = read_all(bag)
        want = _expected(killed, k)
        assert msgs == want, (k, len(msgs), len(want))
        assert sum(meta.values()) == result.total == len(want)
        if want:
            assert mcap_count(bag) == len(want)
        partial_seen += result.partial_chunk > 0
        shutil.rmtree(bag)
    assert partial_seen >= 10        # most cuts land inside a chunk, whose head is kept


def test_repair_edge_cases(killed, tmp_path, capsys):
    data = killed['data']
    # Cut before any complete message: an empty but valid bag.
    bag = _cut(killed, 40, tmp_path)
    result = bag_repair.repair(bag)
    assert result.total == 0 and read_all(bag)[0] == []
    # Nothing to repair from: one line each, exit 2.
    cases = {'missing': tmp_path / 'nope', 'no_mcap': tmp_path / 'empty_dir',
             'empty_file': tmp_path / 'empty', 'not_mcap': tmp_path / 'text',
             'closed': tmp_path / 'closed'}
    cases['no_mcap'].mkdir()
    for name in ('empty', 'text'):
        (tmp_path / name).mkdir()
    (tmp_path / 'empty' / 'empty.mcap').write_bytes(b'')
    (tmp_path / 'text' / 'text.mcap').write_bytes(b'hello, not a bag\n' * 4)
    write_bag(cases['closed'], n=10, close=True)
    for name, path in cases.items():
        with pytest.raises(bag_repair.RepairError):
            bag_repair.repair(path)
        from motion_ctrl.tools import record
        assert record.main(['--repair', str(path)]) == 2, name
        err = capsys.readouterr().err
        assert err.startswith('record: error:') and err.count('\n') == 1, (name, err)
    # A file a live recorder holds (its flock) is refused.
    live = tmp_path / 'live'
    _, w = write_bag(live, n=10)
    bag_repair.lock(w)
    with pytest.raises(bag_repair.RepairError, match='still writing'):
        bag_repair.repair(live)
    w.abort()
    assert bag_repair.repair(live).total == 0     # (10 messages never flushed)
    # The closed bag is untouched.
    assert len(read_all(cases['closed'])[0]) == 11
    # A complete MCAP whose metadata.yaml is lost (e.g. killed inside close()): all of it.
    complete = tmp_path / 'complete'
    written, _ = write_bag(complete, n=300, close=True)
    (complete / 'metadata.yaml').unlink()
    result = bag_repair.repair(complete)
    assert result.complete and read_all(complete)[0] == written
    assert data[:8] == bag_repair.MAGIC


def test_record_repair_cli(killed, tmp_path):
    """The user's one command after a crash, then `report` reads the bag."""
    bag = _cut(killed, len(killed['data']) - 700, tmp_path)
    p = subprocess.run([sys.executable, '-m', 'motion_ctrl.tools.record', '--repair', str(bag)],
                       cwd=str(REPO_ROOT), capture_output=True, text=True, timeout=60,
                       env={**__import__('os').environ, 'PYTHONPATH': str(REPO_ROOT)})
    assert p.returncode == 0, p.stderr
    assert p.stdout.startswith(f'record: repaired {bag}: ')
    assert '/joint_states' in p.stdout and p.stderr == ''
    want = _expected(killed, len(killed['data']) - 700)
    assert read_all(bag)[0] == want
    # report gets past the bag (it lacks reference_states, which this synthetic bag never had).
    with pytest.raises(reader.ReportError, match='reference_states'):
        reader.load_bag(bag)
