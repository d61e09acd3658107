"""`record` and `report` (issue 7): a complete recording at the servo rate, a clean bag after
SIGTERM, the report's figures against the in-process harness, and the error paths.

What "every message published is in the bag" means here, and how it is checked:

* the recorder's own count (printed at exit) = the bag's count (rosbags reader) = the count the
  `mcap` reader finds = metadata.yaml: whatever reached the recorder was written;
* an independent checker subscriber in this process (same reliable QoS, its own executor and
  code) saw exactly the same header stamps, per JointState topic, over the time both were
  listening;
* the publisher's own accounting: the controller counts every servo tick it skipped (rcl timers
  skip missed periods; /diagnostics overruns_total, computed from the tick stamps exactly as
  below). Between two diagnostics messages the gaps in the recorded joint_states stamps add up
  to exactly the ticks the controller says it skipped: every tick it published is in the bag.
  (A stamp gap of more than one period alone is not a loss: on a loaded 2-core VM the timer
  does skip ticks.)
"""
import os
import pathlib
import queue
import signal
import struct
import subprocess
import sys
import threading
import time

import numpy as np
import pytest

import conftest

from kit import running_slide, spin_for
from msg_defs.status import Status
from motion_ctrl.analysis.moves import FAULT_BITS, format_summary, summarize_moves
from motion_ctrl.bags.reader import ReportError, parse_joint_state
from motion_ctrl.bags.report import make_report
from motion_ctrl.tools import report
from motion_ctrl.sim.harness import Harness
from motion_ctrl.core.registers import INCH, LOAD_COUNTS_PER_M

REPO_ROOT = pathlib.Path(conftest.REPO_ROOT)
SERVO_TOPICS = ['/joint_states', '/reference_states', '/motor_states', '/command', '/encoders',
                '/plant_states']
RECORD_SECONDS = 10.5
PERIOD = 1e-3


# -- helpers ------------------------------------------------------------------------------------
def _env():
    env = os.environ.copy()
    env['PYTHONPATH'] = str(REPO_ROOT) + os.pathsep + env.get('PYTHONPATH', '')
    return env


def _default_sigint():
    signal.signal(signal.SIGINT, signal.SIG_DFL)


class RecorderProcess:
    """`python -m motion_ctrl.tools.record` with its stdout read line by line in a thread."""

    def __init__(self, args):
        self.proc = subprocess.Popen(
            [sys.executable, '-m', 'motion_ctrl.tools.record'] + list(args), cwd=str(REPO_ROOT),
            env=_env(), stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
            preexec_fn=_default_sigint)
        self.lines = queue.Queue()
        self.out = []
        self.reader = threading.Thread(target=self._read, daemon=True)
        self.reader.start()

    def _read(self):
        for line in self.proc.stdout:
            self.out.append(line)
            self.lines.put(line)

    def wait_line(self, prefix, timeout):
        end = time.monotonic() + timeout
        while time.monotonic() < end:
            try:
                line = self.lines.get(timeout=0.1)
            except queue.Empty:
                if self.proc.poll() is not None:
                    break
                continue
            if line.startswith(prefix):
                return line
        raise AssertionError(f'recorder did not print {prefix!r}: {"".join(self.out)}'
                             f'{self.proc.stderr.read() if self.proc.poll() is not None else ""}')

    def stop(self, sig, timeout=30.0):
        self.proc.send_signal(sig)
        rc = self.proc.wait(timeout)
        err = self.proc.stderr.read()
        self.reader.join(5.0)           # stdout drained to EOF
        return rc, ''.join(self.out), err

    def kill(self):
        if self.proc.poll() is None:
            self.proc.kill()
            self.proc.wait()


def printed_counts(stdout):
    """{topic: count} from the recorder's exit summary."""
    counts = {}
    for line in stdout.splitlines():
        parts = line.split()
        if len(parts) == 3 and parts[0].startswith('/') and parts[1].isdigit():
            counts[parts[0]] = int(parts[1])
    return counts


def stamp_ns(raw):
    """header.stamp of a CDR JointState (4-byte encapsulation, then int32 sec, uint32 nsec)."""
    sec, nsec = struct.unpack_from('<iI', raw, 4)
    return sec * 1_000_000_000 + nsec


def read_bag(path):
    """rosbags reader: {topic: count}, {topic: header stamps}, [(bag_ns, word)] per status."""
    from rosbags.highlevel import AnyReader
    counts, stamps, status = {}, {}, {}
    with AnyReader([pathlib.Path(path)]) as reader:
        for conn, t, raw in reader.messages():
            counts[conn.topic] = counts.get(conn.topic, 0) + 1
            if conn.msgtype == 'sensor_msgs/msg/JointState':
                stamps.setdefault(conn.topic, []).append(stamp_ns(raw))
            elif conn.topic.endswith('/status'):
                status.setdefault(conn.topic, []).append(
                    (t, reader.deserialize(raw, conn.msgtype).data))
    return counts, stamps, status


def read_mcap(path):
    """The `mcap` package's reader: {topic: count} and the log times per topic."""
    from mcap.reader import make_reader
    files = list(pathlib.Path(path).glob('*.mcap'))
    assert len(files) == 1, files
    counts, times = {}, {}
    with open(files[0], 'rb') as f:
        reader = make_reader(f)
        assert reader.get_header().profile == 'ros2'
        for schema, channel, message in reader.iter_messages():
            assert channel.message_encoding == 'cdr'
            counts[channel.topic] = counts.get(channel.topic, 0) + 1
            times.setdefault(channel.topic, []).append(message.log_time)
    return counts, times


def metadata_counts(path):
    import yaml
    meta = yaml.safe_load((pathlib.Path(path) / 'metadata.yaml').read_text())
    info = meta['rosbag2_bagfile_information']
    assert info['storage_identifier'] == 'mcap'
    return {t['topic_metadata']['name']: t['message_count']
            for t in info['topics_with_message_count']}


class Checker:
    """An independent subscriber: header stamps per servo topic, and the controller's
    /diagnostics overruns_total, on its own node and EventsExecutor in a thread."""

    def __init__(self, context=None):
        import rclpy
        from rclpy.node import Node
        from rclpy.qos import QoSProfile, ReliabilityPolicy
        from sensor_msgs.msg import JointState
        from diagnostic_msgs.msg import DiagnosticArray
        from motion_ctrl.ros import ros_env
        self.executor = ros_env.executor(context)
        self.node = Node('record_checker', context=context)
        qos = QoSProfile(depth=1000, reliability=ReliabilityPolicy.RELIABLE)
        self.stamps = {t: [] for t in SERVO_TOPICS}
        for t in SERVO_TOPICS:
            self.node.create_subscription(
                JointState, t, lambda raw, s=self.stamps[t]: s.append(stamp_ns(raw)), qos,
                raw=True)
        self.diag = []        # (stamp_ns, overruns_total)
        self.node.create_subscription(DiagnosticArray, '/diagnostics', self._on_diag, 10)
        self.executor.add_node(self.node)
        self.stop_flag = threading.Event()
        self.rclpy = rclpy
        self.thread = threading.Thread(target=self._spin, daemon=True)
        self.thread.start()

    def _on_diag(self, msg):
        for st in msg.status:
            values = {kv.key: kv.value for kv in st.values}
            if 'overruns_total' in values:
                s = msg.header.stamp
                self.diag.append((s.sec * 1_000_000_000 + s.nanosec,
                                  int(float(values['overruns_total']))))

    def _spin(self):
        while not self.stop_flag.is_set() and self.node.context.ok():
            self.executor.spin_once(timeout_sec=0.05)

    def wait_matched(self, timeout):
        end = time.monotonic() + timeout
        while time.monotonic() < end:
            if all(self.node.count_publishers(t) > 0 for t in SERVO_TOPICS) and all(
                    self.stamps[t] for t in SERVO_TOPICS):
                return True
            time.sleep(0.02)
        return False

    def stop(self):
        self.stop_flag.set()
        self.thread.join()
        self.executor.shutdown()
        self.node.destroy_node()


def skipped_ticks(stamps_ns, period=PERIOD):
    """Ticks skipped between consecutive stamps, computed as the controller's LoopStats does
    (dt in float seconds from nanoseconds, int(round(dt / period)) - 1)."""
    secs = [s * 1e-9 for s in stamps_ns]
    out = []
    for a, b in zip(secs, secs[1:]):
        out.append(max(0, int(round((b - a) / period)) - 1))
    return out


# -- the slide, shared by the ROS tests ----------------------------------------------------------
def _slide(logs, context=None):
    from motion_ctrl.ros.client import SlideClient
    with running_slide(logs, lambda: SlideClient(name='record_test_client', context=context,
                                                 services=True)) as s:
        yield s.client


@pytest.fixture(scope='module')
def slide(rclpy_session, tmp_path_factory):
    yield from _slide(tmp_path_factory.mktemp('slide_logs'))


@pytest.fixture
def own_slide(own_domain, tmp_path):
    """A slide of its own on a domain of its own, for a test that kills a participant."""
    yield from _slide(tmp_path, own_domain)


@pytest.fixture(scope='module')
def recording(slide, tmp_path_factory):
    """A >= 10 s recording at 1 kHz of moves, by the CLI recorder, stopped with SIGINT; plus
    what the checker saw and the recorder printed."""
    bag = tmp_path_factory.mktemp('rec') / 'moves'
    checker = Checker()
    rec = None
    try:
        assert checker.wait_matched(15.0), 'checker saw no servo messages'
        rec = RecorderProcess(['-o', str(bag)])
        ready = rec.wait_line('record: recording', 30.0)
        t0 = time.monotonic()
        targets = [INCH, 2 * INCH, INCH, 0.0]
        moves = []
        while time.monotonic() - t0 < RECORD_SECONDS:
            target = targets[len(moves) % len(targets)]
            moves.append((target, slide.move({'x': target}, timeout=5.0)))
            spin_for(slide, 0.15)                   # a pause between moves
            if (slide.status['x'] or 0) & FAULT_BITS:
                # a move that faulted (an OVERSPEED over DDS on the shared 2-core VM, seen once
                # in 4 full runs of 2026-11-27) is in the record as such: the recording goes on
                slide.call('reset')
                slide.call('enable', True)
        seconds = time.monotonic() - t0
        rc, out, err = rec.stop(signal.SIGINT)
        rec = None
        time.sleep(0.2)
    finally:
        if rec is not None:
            rec.kill()
        checker.stop()
    return dict(bag=bag, rc=rc, stdout=out, stderr=err, ready=ready, moves=moves,
                seconds=seconds, checker=checker)


# -- 1. every message published is in the bag ---------------------------------------------------
def test_recording_at_servo_rate_is_complete(recording):
    r = recording
    bag = r['bag']
    assert r['rc'] == 0, r['stderr']
    printed = printed_counts(r['stdout'])
    counts, stamps, status = read_bag(bag)
    mcap_counts, mcap_times = read_mcap(bag)

    # Topics: the six servo streams and the discovered status topic.
    assert set(SERVO_TOPICS) | {'/x/status'} <= set(counts), sorted(counts)
    # Written = received (recorder), and both readers and the metadata agree.
    assert printed == counts == mcap_counts == metadata_counts(bag)
    for topic in counts:
        assert mcap_times[topic] == sorted(mcap_times[topic])

    js = stamps['/joint_states']
    span = (js[-1] - js[0]) * 1e-9
    assert span >= 10.0, f'only {span:.2f} s recorded'
    for topic in SERVO_TOPICS:
        s = stamps[topic]
        assert len(set(s)) == len(s), f'{topic}: duplicated stamps'
        assert s == sorted(s), f'{topic}: stamps out of order'

    # An independent subscriber: everything it received while both listened is in the bag.
    # (It is itself a DDS subscriber on the same machine: what it missed is reported.)
    seen = r['checker'].stamps
    checker_missed, lost = {}, {}
    for topic in SERVO_TOPICS:
        # From half a second after both first received: until discovery has completed in both
        # directions the writer does not yet serve a new reader reliably (seen here: a burst
        # in the first ~0.3 s missing from one of two readers and never afterwards).
        lo = max(stamps[topic][0], seen[topic][0]) + 500_000_000
        hi = min(stamps[topic][-1], seen[topic][-1])
        in_bag = {s for s in stamps[topic] if lo <= s <= hi}
        in_checker = {s for s in seen[topic] if lo <= s <= hi}
        checker_missed[topic] = len(in_bag - in_checker)
        if in_checker - in_bag:
            lost[topic] = (sorted(in_checker - in_bag), lo, hi, len(in_checker))
    if lost:
        detail = '; '.join(
            f'{t}: {len(x)} of {n} the checker received, at '
            f'{[round((s - lo) * 1e-6) for s in x[:8]]} ms of {(hi - lo) * 1e-6:.0f} ms'
            for t, (x, lo, hi, n) in lost.items())
        load = os.getloadavg()[0]
        if load > 1.5 * os.cpu_count() or any(checker_missed.values()):
            # A subscriber starved for longer than the publisher's history (1000 messages =
            # 1 s at 1 kHz, msg_defs.SERVO_QOS) loses messages in DDS, before any code of
            # the recorder runs; the checker losing messages too shows that the whole machine
            # was starved (e.g. by other jobs), which the recorder cannot make up for.
            pytest.xfail(f'machine overloaded (load {load:.1f} on {os.cpu_count()} cores, the '
                         f'checker missed {sum(checker_missed.values())}): the recorder lost '
                         f'messages: {detail}')
        pytest.fail(f'the recorder lost messages: {detail}')

    # The publisher's own accounting: the stamp gaps are exactly the ticks it skipped.
    # From when every stream is in the bag (and discovery has settled, as above).
    begin = max(stamps[t][0] for t in SERVO_TOPICS) + 500_000_000
    diag = [(s, n) for s, n in r['checker'].diag if begin < s < js[-1]]
    assert len(diag) >= 5, 'no /diagnostics overruns_total from the controller'
    (d0, n0), (d1, n1) = diag[0], diag[-1]
    window = [s for s in js if s < d1]
    k0 = max(i for i, s in enumerate(window) if s < d0)
    gaps = skipped_ticks(window[k0:])
    published = len(window) - 1 - k0
    # The two diagnostics samples are taken at 1 Hz between ticks: a skipped tick next to
    # either boundary can fall on the other side of it, hence the one tick at each end.
    assert abs(sum(gaps) - (n1 - n0)) <= 2, (
        f'bag gaps {sum(gaps)} vs controller skipped {n1 - n0}: a tick is missing')
    # The same per-tick comparison for the other controller streams.
    for topic in ('/reference_states', '/motor_states', '/command'):
        assert [s for s in stamps[topic] if window[k0] < s < d1] == window[k0 + 1:], topic

    # Measured figures (pytest -s shows them).
    total = sum(counts.values())
    ctl_rate = published / ((d1 - window[k0]) * 1e-9)
    print(f'\nrecorded {total} messages over {span:.2f} s = {total / span:.0f} msg/s; '
          f'controller {ctl_rate:.1f} Hz, ticks skipped by the controller in '
          f'{(d1 - d0) * 1e-9:.1f} s: {n1 - n0} (bag gaps: {sum(gaps)}), recorder losses: 0, '
          f'checker missed: {sum(checker_missed.values())}')
    for topic in sorted(counts):
        print(f'  {topic:<20}{counts[topic]:>8}')
    print('  moves:', ', '.join(f'{t * 1000:.1f} mm in {d * 1000:.0f} ms' if d else
                                f'{t * 1000:.1f} mm: timeout' for t, d in r['moves']))

    # The moves are in the bag (how many complete depends on the machine's load: a starved
    # controller faults; that is the controller's business, the recording shows it).
    words = [w for _, w in status['/x/status']]
    rises = sum(1 for a, b in zip(words, words[1:])
                if b & Status.MOVING and not a & Status.MOVING)
    assert rises >= 1, f'no move recorded; status words {sorted(set(words))}'


# -- 4. the PNG of a real recording ---------------------------------------------------------------
def test_report_png_of_a_recording(recording, tmp_path):
    png = tmp_path / 'move.png'
    summary = make_report(recording['bag'], png)
    print('\n' + format_summary(summary) + f'\nPNG: {png}')
    assert png.read_bytes()[:8] == b'\x89PNG\r\n\x1a\n' and png.stat().st_size > 50_000
    assert summary['x'], 'no move found in the recording'
    # Every move the report found is one of those commanded. Not those of the first half
    # second: the bag may begin during a move, while the status subscription is still being
    # matched and the transient-local history of past words arrives (on a starved machine
    # spread over several ticks, which the report cannot tell from live changes). Nor a
    # faulted move: it ends where the loop opened.
    later = [m for m in summary['x'] if m.start > 0.5 and not m.faults]
    assert later, format_summary(summary)
    for m in later:
        assert any(m.target == pytest.approx(t, abs=1e-9) for t, _ in recording['moves']), m
    for m in summary['x']:
        if m.settle_time is not None and not m.faults:
            assert m.move_time is not None and 0 < m.move_time <= m.settle_time < 5.0


# -- 2. SIGTERM leaves a readable bag --------------------------------------------------------------
def test_sigterm_leaves_a_readable_bag(slide, tmp_path):
    bag = tmp_path / 'term'
    rec = RecorderProcess(['-o', str(bag)])
    try:
        rec.wait_line('record: recording', 30.0)
        spin_for(slide, 1.0)                        # a second of recording
        rc, out, err = rec.stop(signal.SIGTERM)
    finally:
        rec.kill()
    assert rc == 0, err
    assert 'Traceback' not in err
    printed = printed_counts(out)
    counts, stamps, _ = read_bag(bag)
    assert counts == printed == metadata_counts(bag)
    assert read_mcap(bag)[0] == counts
    # (how many depends on the machine's load: on a starved VM the loop runs slower)
    assert all(counts[t] > 50 for t in SERVO_TOPICS), counts
    assert counts['/x/status'] >= 1


def test_a_recorder_held_up_3_s_loses_nothing(slide, tmp_path):
    """The recorder stopped 3 s (SIGSTOP, SIGCONT: a laptop that is busy, a link that pauses)
    while it records the servo streams through the bridge: the bag has no hole, only the
    single ticks the loop itself skipped (its longest gap a few periods). A reliable stream is
    kept 10 s deep on the way (the bridge's copy, the recorder's reader: STREAM_DEPTH,
    --depth); 1 s deep, 3 s held up left a hole of about 2 s in each stream."""
    bag = tmp_path / 'held'
    rec = RecorderProcess(['-o', str(bag), 'joint_states', 'encoders'])
    try:
        rec.wait_line('record: recording', 30.0)
        spin_for(slide, 1.0)
        rec.proc.send_signal(signal.SIGSTOP)
        spin_for(slide, 3.0)
        rec.proc.send_signal(signal.SIGCONT)
        spin_for(slide, 4.0)                        # (what was held up, sent again)
        rc, out, err = rec.stop(signal.SIGINT)
    finally:
        rec.kill()
    assert rc == 0, err
    _, stamps, _ = read_bag(bag)
    for topic in ('/joint_states', '/encoders'):
        s = sorted(stamps[topic])
        span, longest = (s[-1] - s[0]) * 1e-9, max(b - a for a, b in zip(s, s[1:])) * 1e-9
        print(f'{topic}: {len(s)} messages over {span:.2f} s, the longest gap '
              f'{longest * 1e3:.0f} ms, {sum(skipped_ticks(s))} periods without one')
        assert span > 7.0 and longest < 0.05, (topic, len(s), span, longest)


def test_recorder_api_in_process(slide, tmp_path):
    """The library API the demo uses: Recorder in the caller's rclpy context."""
    from motion_ctrl.bags.writer import Recorder
    bag = tmp_path / 'api'
    with Recorder(bag) as rec:
        assert rec.wait_ready(10.0)
        # ready: every topic's first message in (through the bridges, a stream is copied only
        # once a reader is seen: a move started at a matched publisher was not recorded)
        assert all(rec.counts.get(t, 0) > 0 for t in SERVO_TOPICS), rec.counts
        # Until every servo stream has brought 20 messages: a stream can pause for 0.33 s while
        # a participant joins (doc/design_notes.md); the bag's contents are under test here.
        slide.spin_until(lambda: all(rec.counts.get(t, 0) > 20 for t in SERVO_TOPICS), 10.0)
    counts, stamps, status = read_bag(bag)
    assert counts == rec.counts
    assert set(SERVO_TOPICS) | {'/x/status'} <= set(counts)
    assert all(counts[t] > 20 for t in SERVO_TOPICS), counts


# -- 6. SIGKILL: all but the last second is in the bag, after `record --repair` (issue 11) --------
def test_sigkill_then_repair_keeps_all_but_the_last_second(own_slide, tmp_path):
    """The recorder SIGKILLed in the middle of a move leaves an MCAP file and no metadata.yaml:
    `report` names the repair, `record --repair` makes a bag `rosbags` opens, and it holds every
    servo message the independent checker received up to one second before the kill. While
    recording, the file grew at least every second (the periodic flush; rosbags alone writes a
    chunk per MiB, ~1.5 s of these streams)."""
    import msg_defs as md
    from rosbags.rosbag2 import Reader
    bag = tmp_path / 'killed'
    mcap_file = bag / 'killed.mcap'
    growth = []                       # (monotonic, size) of the MCAP file while recording
    sampling = threading.Event()

    def sample():
        while not sampling.is_set():
            try:
                size = mcap_file.stat().st_size
            except FileNotFoundError:
                size = 0
            if not growth or size != growth[-1][1]:
                growth.append((time.monotonic(), size))
            time.sleep(0.01)

    slide = own_slide
    checker = Checker(slide.context)
    rec = sampler = None
    try:
        assert checker.wait_matched(15.0), 'checker saw no servo messages'
        rec = RecorderProcess(['-o', str(bag)])
        rec.wait_line('record: recording', 30.0)
        sampler = threading.Thread(target=sample, daemon=True)
        sampler.start()
        moves, t0 = [], time.monotonic()
        while time.monotonic() - t0 < 3.0:                 # (a starved slide times out)
            moves.append(slide.move({'x': INCH if len(moves) % 2 == 0 else 0.0}, timeout=2.0))
        # Kill in the middle of a move.
        slide.pub_target.publish(md.joint_state(slide.get_clock().now().to_msg(), ['x'],
                                                [2 * INCH]))
        spin_for(slide, 0.3)                        # into the move
        kill_ns, kill_mono = time.time_ns(), time.monotonic()
        rec.proc.send_signal(signal.SIGKILL)
        # (the kernel's time to end it: once in CI it took over 10 s, the VM's disk under load;
        # what is under test is the file it left)
        rec.proc.wait(60.0)
        sampling.set()
        sampler.join()
        spin_for(slide, 0.3)                       # the checker goes on past the kill
    finally:
        sampling.set()
        if rec is not None:
            rec.kill()
        checker.stop()
    assert rec.proc.returncode == -signal.SIGKILL

    # What the kill left: unreadable, and report says what to do.
    assert mcap_file.is_file() and not (bag / 'metadata.yaml').exists()
    with pytest.raises(ReportError, match='record --repair'):
        make_report(bag)

    # The file grew every half second (from its first chunk to the kill): the recorder's
    # flush. (rosbags alone: once per MiB, ~1.5 s at the slide's full rate.) What a starved
    # machine does to the longest interval is checked below.
    times = []
    for t, size in growth:
        if size > growth[0][1] and (not times or t - times[-1] > 0.05):
            times.append(t)               # (a chunk and its index may land 10 ms apart)
    times.append(kill_mono)
    intervals = sorted(b - a for a, b in zip(times, times[1:]))
    assert len(intervals) >= 4, growth
    longest, median = intervals[-1], intervals[len(intervals) // 2]
    assert median <= 0.75, f'the recording reached the file every {median:.2f} s: {growth}'

    # The one command.
    p = subprocess.run([sys.executable, '-m', 'motion_ctrl.tools.record', '--repair', str(bag)],
                       cwd=str(REPO_ROOT), env=_env(), capture_output=True, text=True,
                       timeout=120)
    assert p.returncode == 0 and p.stdout.startswith('record: repaired'), p.stdout + p.stderr
    with Reader(bag) as reader:                       # rosbags opens it
        meta = {c.topic: c.msgcount for c in reader.connections}
        assert reader.message_count == sum(meta.values())
    counts, stamps, status = read_bag(bag)
    assert counts == meta == read_mcap(bag)[0]
    assert set(SERVO_TOPICS) | {'/x/status'} <= set(counts), sorted(counts)

    last_second = kill_ns - 1_000_000_000
    lost_window = {t: (kill_ns - stamps[t][-1]) * 1e-9 for t in SERVO_TOPICS}
    for topic in SERVO_TOPICS:
        s = stamps[topic]
        assert len(set(s)) == len(s) and s == sorted(s), topic
    # The controller's streams hold the same ticks up to the last second (one tick publishes
    # all four) from when all four were coming (through the servo bus's bridge each stream's
    # copy starts when the bridge sees the recorder's reader of it: 0.5 s apart on a loaded
    # machine); how many ticks the controller published is what the checker received (below).
    js = stamps['/joint_states']
    lo = max(stamps[t][0] for t in ('/joint_states', '/reference_states', '/motor_states',
                                    '/command'))
    window = [x for x in js if lo <= x <= last_second]
    for topic in ('/reference_states', '/motor_states', '/command'):
        assert [x for x in stamps[topic] if lo <= x <= last_second] == window, topic
    span = (window[-1] - window[0]) * 1e-9
    assert len(status['/x/status']) >= 1

    # report reads the repaired bag.
    assert 'x' in make_report(bag)

    total = sum(counts.values())
    detail = (f'SIGKILL after {(kill_ns - js[0]) * 1e-9:.2f} s of recording: each servo stream '
              f'ends {min(lost_window.values()) * 1000:.0f}-'
              f'{max(lost_window.values()) * 1000:.0f} ms before the kill; the file grew every '
              f'{median * 1000:.0f} ms (median), longest {longest * 1000:.0f} ms')
    # All but the last second: every stream reaches to within a second of the kill, the file
    # never went a second without growing, and the bag holds everything the checker received
    # up to then (from half a second after both listened, as in
    # test_recording_at_servo_rate_is_complete).
    problems = [f'{t} ends {lost_window[t]:.2f} s before the kill' for t in SERVO_TOPICS
                if stamps[t][-1] < last_second]
    if longest > 1.0:
        problems.append(f'the file went {longest:.2f} s without growing')
    seen = checker.stamps
    checker_missed = 0
    for topic in SERVO_TOPICS:
        lo = max(stamps[topic][0], seen[topic][0]) + 500_000_000
        in_bag = {x for x in stamps[topic] if lo <= x <= last_second}
        in_checker = {x for x in seen[topic] if lo <= x <= last_second}
        checker_missed += len(in_bag - in_checker)
        if in_checker - in_bag:
            problems.append(f'{topic}: {len(in_checker - in_bag)} messages the checker '
                            f'received are not in the bag')
    if problems:
        load = os.getloadavg()[0]
        if load > 1.5 * os.cpu_count() or checker_missed:
            # The recorder (a process like any other) receives and writes late on a machine
            # starved by other jobs; messages DDS still held at the kill are in no bag.
            pytest.xfail(f'machine overloaded (load {load:.1f} on {os.cpu_count()} cores, the '
                         f'checker missed {checker_missed}): {"; ".join(problems)}; {detail}')
        pytest.fail(f'{"; ".join(problems)}; {detail}')
    print(f'\n{detail}; repaired bag holds {total} messages, {len(window)} ticks in the '
          f'{span:.2f} s checked (controller at {len(window) / span:.0f} Hz); '
          f'moves {[round(m, 2) if m else m for m in moves]} s\n'
          + p.stdout)


# -- 3. the report agrees with the harness -------------------------------------------------------
def write_harness_bag(trace, path, status_period=0.1):
    """The harness trace as the controller and plant would publish it: JointState on
    joint_states / reference_states / plant_states with header.stamp = harness
    time, and x/status on change or every status_period; bag time = stamp."""
    from rosbags.rosbag2 import StoragePlugin, Writer
    from rosbags.typesys import Stores, get_typestore
    ts = get_typestore(Stores.ROS2_KILTED)
    JointState = ts.types['sensor_msgs/msg/JointState']
    Header = ts.types['std_msgs/msg/Header']
    Time = ts.types['builtin_interfaces/msg/Time']
    UInt32 = ts.types['std_msgs/msg/UInt32']

    def js(ns, names, pos, eff=()):
        return ts.serialize_cdr(JointState(
            header=Header(stamp=Time(sec=ns // 10**9, nanosec=ns % 10**9), frame_id=''),
            name=list(names), position=np.array(pos, dtype=float),
            velocity=np.zeros(len(pos)), effort=np.array(eff, dtype=float)),
            'sensor_msgs/msg/JointState')

    with Writer(path, version=Writer.VERSION_LATEST, storage_plugin=StoragePlugin.MCAP) as w:
        # No motor_states: the trace has the true motor position only (after the plant step),
        # not the controller's measured one.
        c = {t: w.add_connection(t, 'sensor_msgs/msg/JointState', typestore=ts)
             for t in ('/joint_states', '/reference_states', '/plant_states')}
        cs = w.add_connection('/x/status', 'std_msgs/msg/UInt32', typestore=ts)
        last_word, last_time = None, -1.0
        for k, t in enumerate(trace.t):
            ns = round(t * 1e9)
            w.write(c['/joint_states'], ns, js(ns, ['x'], [trace.actual[k]], [trace.output[k]]))
            w.write(c['/reference_states'], ns, js(ns, ['x'], [trace.command[k]]))
            w.write(c['/plant_states'], ns,
                    js(ns, ['x_motor', 'x_load'], [trace.motor[k], trace.load[k]]))
            word = trace.status[k]
            if word != last_word or t - last_time >= status_period:
                w.write(cs, ns, ts.serialize_cdr(UInt32(data=word), 'std_msgs/msg/UInt32'))
                last_word, last_time = word, t


@pytest.mark.parametrize('registers', [
    None,                                                   # the default slide
    {'max_acceleration': 20.0, 'max_velocity': 0.3},        # hard enough to saturate
], ids=['default', 'saturating'])
def test_report_agrees_with_harness(registers, tmp_path, capsys):
    h = Harness(registers=registers)
    h.run(0.1)
    figures = []
    for target, idle in ((2 * INCH, 0.2), (INCH, 0.3)):      # +2 in, back to +1 in
        start = h.time
        settle = h.move(target)
        assert settle is not None
        done_error = h.load_error_counts(target)
        h.run(idle)
        figures.append(dict(start=start, settle=settle, done_error=done_error,
                            final_error=(h.plant.x_l - target) * LOAD_COUNTS_PER_M,
                            end=h.time))
    tr = h.trace
    bag = tmp_path / 'harness'
    write_harness_bag(tr, bag)
    summary = make_report(bag, tmp_path / 'harness.png')
    moves = summary['x']
    assert len(moves) == 2
    # The same function on the harness' own arrays (no bag in between) gives the same numbers.
    direct = summarize_moves(tr.t, tr.command, tr.load, tr.status, measured=tr.actual,
                             output=tr.output)
    t0 = tr.t[0]                       # the report's time axis starts at the first stamp
    t = np.array(tr.t) - t0
    for m, d, f in zip(moves, direct, figures):
        for key in ('move_time', 'settle_time', 'overshoot_counts', 'final_error_counts',
                    'done_error_counts', 'peak_following_error_counts', 'saturation_time'):
            assert getattr(m, key) == pytest.approx(getattr(d, key), abs=1e-6), key
        # Against the harness' own figures: final error within one count ...
        assert abs(m.final_error_counts - f['final_error']) <= 1.0
        assert abs(m.done_error_counts - f['done_error']) <= 1.0
        # ... settle time within one servo period: Harness.move counts from the command (the
        # tick before MOVING shows), the report from the first tick showing MOVING.
        assert abs(m.settle_time - f['settle']) <= PERIOD + 1e-9
        assert m.start + t0 == pytest.approx(f['start'] + PERIOD)
        assert d.start == pytest.approx(f['start'] + PERIOD)
        # Peak following error and saturation time straight from the trace.
        win = (t >= m.start) & (t <= f['end'] - t0)
        fe = np.abs(np.array(tr.command) - np.array(tr.actual))[win] * LOAD_COUNTS_PER_M
        assert m.peak_following_error_counts == pytest.approx(fe.max(), abs=1e-6)
        sat = np.sum(np.abs(np.array(tr.output)[win]) >= 10.0 - 1e-9) * PERIOD
        assert m.saturation_time == pytest.approx(sat, abs=1e-9)
    if registers:
        assert sum(m.saturation_time for m in moves) > 0.02
    assert moves[0].target == pytest.approx(2 * INCH) and moves[1].target == pytest.approx(INCH)

    # The CLI prints the same figures.
    assert report.main([str(bag), '-o', str(tmp_path / 'cli.png')]) == 0
    out = capsys.readouterr().out
    rows = [line.split() for line in out.splitlines() if line.startswith('x ')]
    assert len(rows) == 2
    for row, m in zip(rows, moves):
        assert float(row[5]) == pytest.approx(m.settle_time * 1000, abs=0.05)
        assert float(row[7]) == pytest.approx(m.final_error_counts, abs=0.005)
    assert (tmp_path / 'cli.png').stat().st_size > 50_000


def test_parse_joint_state_matches_the_typestore():
    from rosbags.typesys import Stores, get_typestore
    ts = get_typestore(Stores.ROS2_KILTED)
    JointState = ts.types['sensor_msgs/msg/JointState']
    Header = ts.types['std_msgs/msg/Header']
    Time = ts.types['builtin_interfaces/msg/Time']
    cases = [('', ['x'], [1.5], [2.5], [-3.0]),
             ('base', ['x_motor', 'x_load'], [1.0, 2.0], [], [0.1, 0.2]),
             ('ab', ['a', 'bb', 'ccc'], [], [], []),
             ('abc', [], [], [], [])]
    for frame, names, pos, vel, eff in cases:
        msg = JointState(header=Header(stamp=Time(sec=1795309000, nanosec=123456789),
                                       frame_id=frame), name=names,
                         position=np.array(pos, float), velocity=np.array(vel, float),
                         effort=np.array(eff, float))
        raw = ts.serialize_cdr(msg, 'sensor_msgs/msg/JointState')
        assert parse_joint_state(raw) == (
            1795309000123456789, names, tuple(pos), tuple(vel), tuple(eff))
        with pytest.raises(ValueError):
            parse_joint_state(ts.serialize_cdr(msg, 'sensor_msgs/msg/JointState',
                                               little_endian=False))


# -- 5. one-line errors, exit code 2 ---------------------------------------------------------------
def _lacking_bag(path):
    from rosbags.rosbag2 import StoragePlugin, Writer
    from rosbags.typesys import Stores, get_typestore
    ts = get_typestore(Stores.ROS2_KILTED)
    with Writer(path, version=Writer.VERSION_LATEST, storage_plugin=StoragePlugin.MCAP) as w:
        c = w.add_connection('/chatter', 'std_msgs/msg/UInt32', typestore=ts)
        UInt32 = ts.types['std_msgs/msg/UInt32']
        w.write(c, 1, ts.serialize_cdr(UInt32(data=1), 'std_msgs/msg/UInt32'))


@pytest.mark.parametrize('case', ['missing', 'not_a_bag_dir', 'not_a_bag_file', 'lacks_topics'])
def test_report_errors_are_one_line(case, tmp_path, capsys):
    path = tmp_path / case
    if case == 'not_a_bag_dir':
        path.mkdir()
        (path / 'notes.txt').write_text('hello\n')
    elif case == 'not_a_bag_file':
        path.write_text('not a bag\n')
    elif case == 'lacks_topics':
        _lacking_bag(path)
    assert report.main([str(path), '-o', str(tmp_path / 'x.png')]) == 2
    captured = capsys.readouterr()
    err = captured.err.strip()
    assert err.startswith('report: error:') and '\n' not in err, err
    assert 'Traceback' not in captured.err and captured.out == ''
    assert not (tmp_path / 'x.png').exists()
    if case == 'lacks_topics':
        assert 'joint_states' in err and '/chatter' in err


def test_record_refuses_an_existing_output(tmp_path):
    p = subprocess.run([sys.executable, '-m', 'motion_ctrl.tools.record', '-o', str(tmp_path)],
                       cwd=str(REPO_ROOT), env=_env(), capture_output=True, text=True,
                       timeout=60)
    assert p.returncode == 2
    assert p.stderr.startswith('record: error:') and p.stderr.count('\n') == 1, p.stderr


def test_report_cli_error_exit_code(tmp_path):
    """The real entry point: no traceback, exit code 2."""
    p = subprocess.run([sys.executable, '-m', 'motion_ctrl.tools.report', str(tmp_path / 'nope')],
                       cwd=str(REPO_ROOT), env=_env(), capture_output=True, text=True,
                       timeout=60)
    assert p.returncode == 2
    assert p.stderr.count('\n') == 1 and p.stderr.startswith('report: error:'), p.stderr
