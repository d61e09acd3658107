"""Recording motion_ctrl's topics into a rosbag2 bag (MCAP storage) from inside a process:
`Recorder` (the `record` tool, the demo, tests) and `record_for`.

The bag is written with the `rosbags` library (rosbag2 format version 9, the one Kilted's
`ros2 bag` writes, storage `mcap`, with the metadata.yaml that `ros2 bag info` / `play` read).
Messages are stored exactly as received: raw CDR bytes from rclpy subscriptions (`raw=True`),
never deserialized.

Topics: by default SERVO_TOPICS and every ``<axis>/status`` (std_msgs/UInt32 topics ending in
``/status``, found in the ROS graph at start and, every 0.5 s, while recording); names are
relative to the node's namespace.

Bag timestamp = receive time: the recorder's clock (system time; the ROS clock when the node runs
with use_sim_time) read in the subscription callback, as `ros2 bag record` does. Every servo
message also carries its header.stamp (the servo tick that produced it); `motion_ctrl.bags.reader`
reads against header stamps and uses the bag time only for the header-less status words.

QoS: the servo streams are subscribed reliable, keep-last 1000 (the publishers are reliable with
the same one second of history: a recorder that falls behind for up to a second loses nothing);
status words reliable + transient local (msg_defs.STATUS_QOS: the current word is recorded at
start).
Other topics get reliable/volatile unless every publisher offers best effort / transient local.
The publishers' offered QoS go into the metadata, as ros2 bag does.

A killed recorder (SIGKILL, OOM killer, power to the PC cut by an e-stop chain) cannot close the
bag: the recorder writes its pending chunk and flushes the file every 0.5 s
(`motion_ctrl.bags.repair`, where the reasons are given at length), so a kill loses at most the
last half second or so, and `record --repair DIR` makes a complete bag of what the file holds.

Throughput (measured on the 2-core VM, slide at 1 kHz = 6 streams + status, ~6000 msg/s): one
rclpy EventsExecutor, messages written straight from the callbacks (rosbags' MCAP writer costs
~5-8 us per message; a writer thread would only add GIL traffic): 20-25 % of one core, no
message lost while the machine was not starved. A subscriber descheduled for longer than the
publishers' history (1000 samples = 1 s at 1 kHz) loses messages inside DDS, before any recorder
code runs: on a machine overloaded by other jobs, check the printed counts (test/
test_record_report.py compares them with the controller's own tick accounting).

``Recorder`` records in-process next to other nodes of an rclpy context, on its own node and
executor in a background thread::

    with Recorder('/tmp/move_bag', context=ctx) as rec:    # start() ... stop()
        rec.wait_ready(5.0)
        ... command moves ...
    print(rec.counts)                                      # {topic: messages written}
"""
from __future__ import annotations

import datetime
import importlib
import os
import sys
import threading
import time
from typing import Any

import rclpy
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
from rclpy.task import Future
from rosbags.interfaces import (Qos, QosDurability, QosHistory, QosLiveliness, QosReliability,
                                QosTime)
from rosbags.rosbag2 import StoragePlugin, Writer, WriterError
from rosbags.typesys import Stores, get_typestore

import msg_defs as md
from motion_ctrl.bags import repair
from motion_ctrl.bags.reader import JOINT_STATE, UINT32
from motion_ctrl.ros import ros_env

# Topics recorded by default (relative names); plus every <axis>/status.
SERVO_TOPICS = ('joint_states', 'reference_states', 'motor_states', 'command', 'encoders',
                'plant_states')
DEFAULT_DEPTH = 10000
RESCAN_PERIOD = 0.5        # s between graph scans for new topics
SPIN_TIMEOUT = 0.05        # s: how quickly a stop request is seen


class RecordError(Exception):
    """A problem the user can fix (output exists, bad topic name): one line, exit 2."""


def _message_class(type_name: str):
    """'sensor_msgs/msg/JointState' -> the rclpy message class."""
    pkg, kind, name = type_name.split('/')
    return getattr(importlib.import_module(f'{pkg}.{kind}'), name)


def _rosbags_qos(profile):
    """rclpy QoSProfile -> rosbags Qos (for the metadata's offered_qos_profiles)."""
    def dur(d):
        ns = d.nanoseconds
        return QosTime(ns // 1_000_000_000, ns % 1_000_000_000)

    def enum(cls, value):
        try:
            return cls(int(value))
        except ValueError:
            return cls.UNKNOWN
    return Qos(enum(QosHistory, profile.history), int(profile.depth),
               enum(QosReliability, profile.reliability),
               enum(QosDurability, profile.durability), dur(profile.deadline),
               dur(profile.lifespan), enum(QosLiveliness, profile.liveliness),
               dur(profile.liveliness_lease_duration),
               bool(profile.avoid_ros_namespace_conventions))


def default_output() -> str:
    """The bag directory `ros2 bag record` names by default: rosbag2_<date>-<time>."""
    return datetime.datetime.now().strftime('rosbag2_%Y_%m_%d-%H_%M_%S')


class Recorder:
    """Record topics into a rosbag2/MCAP bag from inside a process.

    out_dir: the bag directory to create (must not exist).
    topics: names (relative or absolute); None = the defaults + every <axis>/status.
    context: rclpy context to record in (default: the global one; rclpy.init() first).
    node: record on this node instead of an own one; the caller then spins it (start() starts
        no thread) and the graph rescan runs as a timer on it.
    discover_status: also record every UInt32 topic ending in /status (default: when topics
        is None).
    depth: reader queue depth of the volatile streams.

    start() opens the bag and spins an own executor in a background thread; stop() (or leaving
    the `with` block) stops it, closes the bag and returns {topic: messages written}.
    """

    def __init__(self, out_dir, topics=None, *, context=None, node=None,
                 discover_status=None, depth: int = DEFAULT_DEPTH, name: str | None = None):
        self.out_dir = os.fspath(out_dir)
        self.requested = list(SERVO_TOPICS if topics is None else topics)
        self.discover_status = topics is None if discover_status is None else discover_status
        self.context = context
        self.node = node
        self._own_node = node is None
        self.depth = depth
        self.name = name or f'motion_ctrl_recorder_{os.getpid()}'
        self.counts: dict[str, int] = {}      # fully-qualified topic -> messages written
        self.types: dict[str, str] = {}
        self.pending: list[str] = []          # requested topics whose type is not known yet
        self.writer: Any = None               # rosbags Writer while recording
        self.executor: Any = None
        self._events = False
        self._subs: dict[str, Any] = {}
        self._conns: dict[str, Any] = {}
        self._timer: Any = None
        self._flush_timer = None
        self.flushes = 0                      # chunks written by the periodic flush
        self._flush_due = 0.0                 # time.monotonic() of the next flush
        self._thread: Any = None
        self._stop = threading.Event()
        self.started: float | None = None     # time.monotonic() at open
        self.stopped: float | None = None
        self.errors: list[str] = []

    # -- setup ------------------------------------------------------------------------------
    def open(self) -> 'Recorder':
        self.typestore = get_typestore(Stores.ROS2_KILTED)
        try:
            self.writer = Writer(self.out_dir, version=Writer.VERSION_LATEST,
                                 storage_plugin=StoragePlugin.MCAP)
            self.writer.open()
            repair.check_flushable(self.writer)
            repair.lock(self.writer)
        except (WriterError, OSError) as e:
            self.writer = None
            raise RecordError(f'cannot create bag {self.out_dir}: {e}') from None
        try:
            if self.node is None:
                self.node = Node(self.name, context=self.context,
                                 start_parameter_services=False)
            node = self.node
            self._now = time.time_ns
            if node.get_parameter('use_sim_time').value:
                clock = node.get_clock()
                self._now = lambda: clock.now().nanoseconds
            self.namespace = node.get_namespace()
            for topic in self.requested:
                try:
                    full = node.resolve_topic_name(topic)
                except Exception as e:          # invalid name
                    raise RecordError(f'bad topic name {topic!r}: {e}') from None
                base = full.rsplit('/', 1)[-1]
                known = (JOINT_STATE if base in SERVO_TOPICS
                         else UINT32 if base == 'status' else None)
                if known:
                    self._subscribe(full, known)
                elif full not in self.pending:
                    self.pending.append(full)
            self._scan()
            self._timer = node.create_timer(RESCAN_PERIOD, self._scan)
            # The flush runs from the message callbacks when due (also while the executor
            # works off a backlog, when a timer event would wait behind the messages) and from
            # a timer (when messages stop). Same (default, mutually exclusive) callback group
            # as the subscriptions: it never runs inside a write, whatever the executor.
            self._flush_due = time.monotonic() + repair.FLUSH_PERIOD
            self._flush_timer = node.create_timer(repair.FLUSH_PERIOD / 5,
                                                  self._flush_if_due)
            self.started = time.monotonic()
        except BaseException:
            self.close()
            raise
        return self

    def flush(self) -> None:
        """Write the pending chunk and flush the file (a SIGKILL loses only what came after)."""
        self._flush_due = time.monotonic() + repair.FLUSH_PERIOD
        if self.writer is not None and repair.flush(self.writer):
            self.flushes += 1

    def _flush_if_due(self) -> None:
        if time.monotonic() >= self._flush_due:
            self.flush()

    def _is_status(self, name: str, types) -> bool:
        prefix = self.namespace.rstrip('/') + '/'
        return (name.endswith('/status') and name.startswith(prefix) and UINT32 in types)

    def _scan(self) -> None:
        """Subscribe to new <axis>/status topics and to requested topics now in the graph."""
        if not (self.pending or self.discover_status):
            return
        graph = dict(self.node.get_topic_names_and_types())
        for name, types in graph.items():
            if name in self._subs:
                continue
            if name in self.pending:
                self.pending.remove(name)
                self._subscribe(name, types[0])
            elif self.discover_status and self._is_status(name, types):
                self._subscribe(name, UINT32)

    def _qos(self, topic: str, type_name: str):
        """(subscription QoS, offered QoS for the metadata)."""
        base = topic.rsplit('/', 1)[-1]
        # The contract's topics: the contract's QoS (the graph reports no history depth).
        if type_name == JOINT_STATE and base in SERVO_TOPICS:
            qos = QoSProfile(depth=self.depth, reliability=ReliabilityPolicy.RELIABLE,
                             history=HistoryPolicy.KEEP_LAST,
                             durability=DurabilityPolicy.VOLATILE)
            return qos, [md.SERVO_QOS]
        if type_name == UINT32 and base == 'status':
            return md.STATUS_QOS, [md.STATUS_QOS]
        offered = [i.qos_profile for i in self.node.get_publishers_info_by_topic(topic)]
        reliable = not offered or any(
            p.reliability != ReliabilityPolicy.BEST_EFFORT for p in offered)
        latched = bool(offered) and all(
            p.durability == DurabilityPolicy.TRANSIENT_LOCAL for p in offered)
        qos = QoSProfile(
            depth=self.depth, history=HistoryPolicy.KEEP_LAST,
            reliability=ReliabilityPolicy.RELIABLE if reliable else ReliabilityPolicy.BEST_EFFORT,
            durability=DurabilityPolicy.TRANSIENT_LOCAL if latched else
            DurabilityPolicy.VOLATILE)
        return qos, offered

    def _subscribe(self, topic: str, type_name: str) -> None:
        if topic in self._subs:
            return                              # named twice
        try:
            cls = _message_class(type_name)
            self.typestore.hash_rihs01(type_name)
        except Exception:
            msg = f'{topic}: type {type_name} not available, not recorded'
            self.errors.append(msg)
            print(f'record: {msg}', file=sys.stderr)
            return
        qos, offered = self._qos(topic, type_name)
        conn = self.writer.add_connection(topic, type_name, typestore=self.typestore,
                                          offered_qos_profiles=[_rosbags_qos(p) for p in offered])
        self._conns[topic] = conn
        self.counts[topic] = 0
        self.types[topic] = type_name
        counts, write, now = self.counts, self.writer.write, self._now
        monotonic, flush_if_due = time.monotonic, self._flush_if_due

        def on_message(data, topic=topic, conn=conn):
            write(conn, now(), data)
            counts[topic] += 1
            if monotonic() >= self._flush_due:
                flush_if_due()
        self._subs[topic] = self.node.create_subscription(cls, topic, on_message, qos, raw=True)

    # -- running ----------------------------------------------------------------------------
    def _make_executor(self):
        executor = ros_env.executor(self.context)
        self._events = type(executor).__name__ == 'EventsExecutor'
        executor.add_node(self.node)
        return executor

    def spin_once(self, timeout_sec: float = SPIN_TIMEOUT) -> None:
        """Process messages on the recorder's own executor for up to timeout_sec.

        On the EventsExecutor this is spin_until_future_complete on a future that never
        completes: the executor dispatches every event of the period in C++ without returning
        to Python between messages (measured ~20 % less CPU per message than spin_once, which
        handles one event per call). Its spin() is not used: in rclpy 9.1 it busy-waits and
        does not return to see a stop request.
        """
        if self.executor is None:
            self.executor = self._make_executor()
        if self._events:
            self.executor.spin_until_future_complete(Future(), timeout_sec=timeout_sec)
        else:
            self.executor.spin_once(timeout_sec=timeout_sec)

    def start(self) -> 'Recorder':
        """Open the bag and record in a background thread (own node only)."""
        if self.writer is None:
            self.open()
        if self._own_node and self._thread is None:
            if self.executor is None:
                self.executor = self._make_executor()
            self._thread = threading.Thread(target=self._spin, name='recorder', daemon=True)
            self._thread.start()
        return self

    def _spin(self) -> None:
        def ok():
            return rclpy.ok(context=self.context)
        while not self._stop.is_set() and ok():
            self.spin_once(SPIN_TIMEOUT)

    def ready(self) -> bool:
        """Every requested topic subscribed and its first message in; with discovery, at least
        one status topic found. A matched publisher is not enough: a bridge of the servo bus
        publishes every topic from the start but copies a stream only once it has seen a
        reader (the demo's bag missed its first move)."""
        subs = dict(self._subs)          # the graph scan may add one meanwhile
        if self.pending or not subs:
            return False
        if self.discover_status and not any(t.endswith('/status') for t in subs):
            return False
        return all(self.counts.get(t, 0) > 0 for t in subs)

    def unmatched(self) -> list:
        """Topics subscribed without a publisher yet, and requested topics not in the graph."""
        return sorted(t for t, s in dict(self._subs).items()
                      if s.get_publisher_count() == 0) + list(self.pending)

    def wait_ready(self, timeout: float = 5.0) -> bool:
        end = time.monotonic() + timeout
        while time.monotonic() < end:
            if self.ready():
                return True
            if self._thread is None and self._own_node:
                self.spin_once(0.01)
            else:
                time.sleep(0.01)
        return self.ready()

    def stop(self) -> dict:
        """Stop recording, close the bag; returns {topic: messages written}."""
        self._stop.set()
        if self._thread is not None:
            self._thread.join()
            self._thread = None
        self.close()
        return dict(self.counts)

    def close(self) -> None:
        """Destroy the subscriptions (no callback runs after this), then close the bag.

        The bag is closed even when the ROS side cannot be torn down cleanly (e.g. the caller
        shut its context down first)."""
        try:
            if self.stopped is None and self.started is not None:
                self.stopped = time.monotonic()
            if self.executor is not None:
                executor, self.executor = self.executor, None
                executor.shutdown()
            if self.node is not None:
                node, self.node = self.node, None
                try:
                    for sub in self._subs.values():
                        node.destroy_subscription(sub)
                    for timer in (self._timer, self._flush_timer):
                        if timer is not None:
                            node.destroy_timer(timer)
                    if self._own_node:
                        node.destroy_node()
                except Exception as e:          # context already shut down
                    print(f'record: warning: node teardown: {e}', file=sys.stderr)
        finally:
            if self.writer is not None:
                writer, self.writer = self.writer, None
                writer.close()

    def __enter__(self):
        return self.start()

    def __exit__(self, *exc):
        self.stop()
        return False

    # -- results ----------------------------------------------------------------------------
    @property
    def total(self) -> int:
        return sum(self.counts.values())

    def summary(self) -> str:
        end = self.stopped if self.stopped is not None else time.monotonic()
        seconds = end - self.started if self.started is not None else 0.0
        rate = self.total / seconds if seconds > 0 else 0.0
        width = max([len(t) for t in self.counts] + [5])
        lines = [f'record: {self.total} messages in {seconds:.1f} s ({rate:.0f} msg/s) '
                 f'written to {self.out_dir}']
        for topic in sorted(self.counts):
            lines.append(f'  {topic:<{width}}  {self.counts[topic]:>8}  {self.types[topic]}')
        for topic in self.pending:
            lines.append(f'  {topic:<{width}}  {"-":>8}  (never published: type unknown)')
        return '\n'.join(lines)


def record_for(seconds: float, out_dir, topics=None, *, context=None, ready_timeout=5.0,
               **kwargs) -> dict:
    """Record for `seconds` (after the topics are matched, up to ready_timeout); returns
    {topic: messages written}."""
    rec = Recorder(out_dir, topics, context=context, **kwargs).start()
    try:
        rec.wait_ready(ready_timeout)
        time.sleep(seconds)
    finally:
        counts = rec.stop()
    return counts
