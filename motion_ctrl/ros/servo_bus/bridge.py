"""A node's ROS interface mirrored from the servo bus onto the user's domain (ros.servo_bus).

The node itself runs in a process of its own on the servo bus's domain, which no ROS tool joins.
The bridge, in the process the user started, gives the user's domain a node of the same name
with the same interface, by reading the node's endpoints from the servo bus's graph:

* every topic the node publishes is published under the same name and reliability, its
  samples copied as bytes (no deserialisation). A latched (transient local) topic of the node's
  own keeps its last sample for late joiners; the others (`/rosout` among them) are copied only
  while somebody on the user's domain subscribes (checked every `POLL` s), so a servo stream
  nobody watches costs nothing;
* every topic the node subscribes to is copied the other way, in order. A target message
  larger than the controller takes (msg_defs.MAX_TARGET_BYTES), or malformed whatever the axes
  (NaN, lengths), is refused here, before the bus, and logged as the controller logs its
  refusals (ros.refusals). The servo streams (`SERVO_TOPICS`: `encoders`, `command`, `/clock`),
  which plant and controller exchange on the servo bus, are not: one commander per amplifier
  (servo_bus.commander). Published on the user's domain by a node that is not a bridge, they
  are refused while the node has its peer on the bus, and copied in only from a node of another
  make named on purpose (commander.PEER_ENV);
* every service (the parameter services included: `ros2 param get/set/dump/load` work
  unchanged) is answered by calling the node's service and returning its response. An action is
  three services and two topics under `<name>/_action/`, mirrored as such (its goal ids
  unchanged); its get_result, which answers only when the goal ends, is forwarded without a
  timeout and without holding a thread.

Of `/rosout` and `/parameter_events`, which the other node on the bus publishes too, only the
node's own messages are copied out.

A tool that joins the user's domain can hold up this process (Fast DDS shared-memory port
waits, rclpy holding the GIL while it sends: doc/design_notes.md), but not the node, which only ever
talks to the bridges and its peer.
"""
from __future__ import annotations

import importlib
import time

from rclpy.callback_groups import MutuallyExclusiveCallbackGroup, ReentrantCallbackGroup
from rclpy.exceptions import InvalidHandle
from rclpy.client import Client
from rclpy.node import Node
from rclpy.parameter import Parameter
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
from rclpy.subscription import Subscription

import msg_defs as md
from motion_ctrl.ros import ros_env
from motion_ctrl.ros.refusals import RefusalLog, malformed_target, too_large
from motion_ctrl.ros.servo_bus.commander import Commander

SERVO_TOPICS = frozenset({'/' + md.ENCODERS, '/' + md.COMMAND, md.CLOCK})
READS = {'/' + md.ENCODERS: '/' + md.COMMAND, '/' + md.COMMAND: '/' + md.ENCODERS}
POLL = 0.1                   # s between looks for readers on the user's side
GRAPH_POLL = 1.0             # s between looks at the node's endpoints, after STARTUP s
STARTUP, STARTUP_POLL = 5.0, 0.25   # s: the node's endpoints appear over its first seconds
SERVICE_TIMEOUT = 10.0       # s a forwarded request waits for the node's answer
STREAM_DEPTH = 10000         # a reliable reader on the user's side held up 10 s loses nothing


# An action's parts on the graph ('<pkg>/action/<Action>_<part>') are classes of the action's
# Impl in Python; its cancel service and status topic are action_msgs' own types.
ACTION_PARTS = {'SendGoal': 'SendGoalService', 'GetResult': 'GetResultService',
                'FeedbackMessage': 'FeedbackMessage'}


def interface_type(name: str):
    """'sensor_msgs/msg/JointState' (or an action's part, 'control_msgs/action/
    FollowJointTrajectory_SendGoal') -> the class; None when not installed here."""
    pkg, kind, cls = name.split('/')
    try:
        module = importlib.import_module(f'{pkg}.{kind}')
    except ImportError:
        return None
    found = getattr(module, cls, None)
    if found is None and kind == 'action' and '_' in cls:
        action, part = cls.rsplit('_', 1)
        found = getattr(getattr(getattr(module, action, None), 'Impl', None),
                        ACTION_PARTS.get(part, ''), None)
    return found


STATUS_WORDS_DEPTH = 10      # the last status words on the user's side (a second at rest)


def outward_qos(info, topic: str = '') -> QoSProfile:
    """The node's publisher QoS for the user's side: same reliability and durability; a
    status word keeps its last STATUS_WORDS_DEPTH words (a reader that falls behind still gets
    MOTION_DONE cleared and raised; the word is republished at 10 Hz, so a second after a
    change a late joiner's words are all the current one), every other latched topic its
    current value only (a late joiner gets that, not a history), a stream a second of
    samples."""
    latched = info.qos_profile.durability == DurabilityPolicy.TRANSIENT_LOCAL
    reliable = info.qos_profile.reliability == ReliabilityPolicy.RELIABLE
    depth = (STATUS_WORDS_DEPTH if topic.endswith('/status') else 1) if latched else \
        (STREAM_DEPTH if reliable else 10)
    return QoSProfile(
        depth=depth,
        reliability=ReliabilityPolicy.RELIABLE if reliable else ReliabilityPolicy.BEST_EFFORT,
        durability=DurabilityPolicy.TRANSIENT_LOCAL if latched else DurabilityPolicy.VOLATILE)


def inward_qos(info) -> QoSProfile:
    """The node's subscription QoS, for the bridge's subscription on the user's side and its
    publisher on the servo bus."""
    return QoSProfile(
        depth=10,
        reliability=info.qos_profile.reliability
        if info.qos_profile.reliability != ReliabilityPolicy.UNKNOWN
        else ReliabilityPolicy.RELIABLE,
        durability=DurabilityPolicy.TRANSIENT_LOCAL
        if info.qos_profile.durability == DurabilityPolicy.TRANSIENT_LOCAL
        else DurabilityPolicy.VOLATILE)


def _own_log(bridge: Bridge, msg) -> bool:
    return msg.name == bridge.logger or msg.name.startswith(bridge.logger + '.')


def _own_parameter_event(bridge: Bridge, msg) -> bool:
    return msg.node == bridge.fqn


# Topics every node on the bus publishes: only the bridged node's messages are copied out.
# (By content: rclpy's EventsExecutor passes no publisher GID.)
SHARED = {'rcl_interfaces/msg/Log': _own_log,
          'rcl_interfaces/msg/ParameterEvent': _own_parameter_event}


class _Outward:
    """One topic the node publishes: the user-side publisher, and the servo-side subscription
    that feeds it while it is wanted (raw bytes; a shared topic's messages filtered)."""

    def __init__(self, bridge: Bridge, topic: str, type_name: str, msg_type, info):
        self.bridge, self.topic, self.msg_type = bridge, topic, msg_type
        # (a servo stream read on a node and thread of its own: nothing queues in front of it)
        self.reader = bridge.servo_out if topic in SERVO_TOPICS else bridge.servo
        self.qos = outward_qos(info, topic)
        self.latched = self.qos.durability == DurabilityPolicy.TRANSIENT_LOCAL
        self.pub = bridge.public.create_publisher(msg_type, topic, self.qos)
        self.own = SHARED.get(type_name)
        self.sub: Subscription | None = None

    def _copy(self, msg) -> None:
        if self.own is not None and not self.own(self.bridge, msg):
            return                   # the other node's
        try:
            self.pub.publish(msg)
        except Exception as e:       # (a reader the middleware gave up on: count, go on)
            self.bridge.dropped(self.topic, e)

    def refresh(self) -> None:
        """A latched topic is copied always (a late joiner wants it at once), a stream while
        it has readers on the user's side; read as the node publishes it (a recording through
        the bridge loses nothing the node's history of a second still holds) and all on one
        thread, so that a recording has the status words in order with the streams.

        A topic both nodes publish (`/rosout`, latched) is read only while wanted too: a reader
        of it here makes the other node's every log line a send to this process, and once this
        process is SIGKILLed such a send waits on its dead shared-memory port, holding the other
        node up for a second or more (doc/design_notes.md, "The servo bus as the default")."""
        wanted = ((self.latched and self.own is None)
                  or self.pub.get_subscription_count() > 0)
        if wanted and self.sub is None:
            # (a status word's every change: MOTION_DONE cleared and raised)
            qos = QoSProfile(depth=STATUS_WORDS_DEPTH if self.latched else self.qos.depth,
                             reliability=self.qos.reliability, durability=self.qos.durability)
            self.sub = self.reader.create_subscription(
                self.msg_type, self.topic, self._copy, qos, raw=self.own is None)
        elif not wanted and self.sub is not None:
            self.reader.destroy_subscription(self.sub)
            self.sub = None


class Bridge:
    """Mirror node `name` in `namespace` of the servo bus (context `servo_ctx`) onto the user's
    domain (context `public_ctx`). Call `poll()` every POLL s on `servo`'s executor; spin
    `public`, `servo`, `calls`, `servo_in` and `servo_out` on executors of their own (a service
    waits for `calls` on `public`'s, so not on one thread; a servo stream waits for nothing)."""

    def __init__(self, name: str, namespace: str, public_ctx, servo_ctx, log=print,
                 peer: str | None = None, servo_env: dict | None = None, relay: bool = False):
        self.name, self.namespace = name, namespace
        self.fqn = namespace.rstrip('/') + '/' + name
        self.logger = '.'.join([*namespace.strip('/').split('/'), name]).lstrip('.')
        self.log = log
        def node(node_name, context):     # none of its own parameters, services or log
            return Node(node_name, namespace=namespace, context=context,
                        use_global_arguments=False, start_parameter_services=False,
                        enable_rosout=False, parameter_overrides=[
                            Parameter('start_type_description_service', value=False)])
        # (the servo side's participant first, made with this node in `servo_env`: made after
        # one that is a discovery server's client, it was one too)
        with ros_env.environ(servo_env or {}):
            self.servo = node(f'_bridge_{name}', servo_ctx)
        self.public = node(name, public_ctx)
        # The service clients on a node (and executor) of their own: a response must not wait
        # behind a queue of stream samples to copy.
        self.calls = node(f'_bridge_{name}_calls', servo_ctx)
        # The servo streams of a plant or controller of another make (`look`): read on nodes of
        # their own, each on one thread (in order, behind nothing else).
        self.servo_in = node(f'_bridge_{name}_in', public_ctx)
        self.servo_out = node(f'_bridge_{name}_out', servo_ctx)
        self.group = ReentrantCallbackGroup()
        self.outward: dict[str, _Outward] = {}
        self.inward: set[str] = set()            # topics copied in
        self.services: set[str] = set()          # services answered
        self.skipped: set[str] = set()           # names whose type is not installed here
        self.dropping: set[str] = set()          # topics that lost a sample (logged once)
        self.strangers: set[str] = set()         # foreign nodes seen on the bus (logged once)
        self.suspects: set[str] = set()          # ... and seen unbridged in the last look
        self.started = time.monotonic()
        self.next_look = 0.0
        self.refusals = RefusalLog(log)
        self.relay = relay                       # a relay's (servo_bus.relay)
        self.commander = Commander(self, peer, relay)   # the servo streams' one source

    # -- the graph ----------------------------------------------------------------------------
    def poll(self) -> None:
        """Start or stop the copies of the streams as readers come and go; look at the graph
        for what the node has that is not mirrored yet every GRAPH_POLL s (every POLL s for the
        first STARTUP s: reading the graph costs more than a copy)."""
        for out in self.outward.values():
            out.refresh()
        self.commander.report()
        now = time.monotonic()
        if now < self.next_look:
            return
        self.next_look = now + (STARTUP_POLL if now < self.started + STARTUP else GRAPH_POLL)
        try:
            self.look()
        except Exception as e:       # (the node went between two graph queries: look again)
            if 'nonexistent node' not in str(e):
                self.log(f'bridge: reading the graph failed: {e!r}')

    def look(self) -> None:
        """Mirror what the node has that is not mirrored yet."""
        ns = self.namespace
        nodes = self.servo.get_node_names_and_namespaces()
        self._strangers(nodes)
        if (self.name, ns) not in nodes:
            return
        published = self.servo.get_publisher_names_and_types_by_node(self.name, ns)
        for topic, types in published:
            if topic in self.outward:
                continue
            mine = [i for i in self.servo.get_publishers_info_by_topic(topic)
                    if i.node_name == self.name and i.node_namespace == ns]
            msg_type = self.type_of(topic, types)
            if msg_type is not None and mine:
                self.outward[topic] = _Outward(self, topic, types[0], msg_type, mine[0])
        subscribed = self.servo.get_subscriber_names_and_types_by_node(self.name, ns)
        # (a relay's node is another bridge, which reads no servo stream on its side: those
        # the loop reads are the ones opposite those it publishes)
        self.commander.look([(READS[t], ts) for t, ts in published if t in READS] if self.relay
                            else [(t, ts) for t, ts in subscribed if t in SERVO_TOPICS])
        for topic, types in subscribed:
            if topic in self.inward or topic in SERVO_TOPICS:
                continue
            kind = self.inward_kind(topic, types)
            if kind is None:
                continue
            msg_type, qos = kind
            out = self.servo.create_publisher(msg_type, topic, qos)
            # (a group per topic: its samples copied one at a time, in the order they came)
            self.public.create_subscription(msg_type, topic, self._copy_in(topic, out), qos,
                                            raw=True,
                                            callback_group=MutuallyExclusiveCallbackGroup())
            self.inward.add(topic)
        for service, types in self.servo.get_service_names_and_types_by_node(self.name, ns):
            if service in self.services:
                continue
            srv_type = self.type_of(service, types)
            if srv_type is None:
                continue
            client: Client = self.calls.create_client(srv_type, service)
            self.public.create_service(
                srv_type, service, self._forward(client, service), callback_group=self.group)
            self.services.add(service)

    def _copy_in(self, topic: str, out):
        """The copy of `topic` onto the bus through `out`. A target message larger than the
        controller takes (msg_defs.MAX_TARGET_BYTES), or one it refuses whichever its axes
        (refusals.malformed_target: NaN, lengths), is refused here, before the servo bus, as
        the controller would refuse it (once a second, with a count): a flood of them copied on
        would take the loop's thread a message at a time (a NaN target at 1 kHz: 792-922 Hz
        before, 405-662 Hz during, doc/performance.md)."""
        what = topic.rsplit('/', 1)[-1]
        gate = what in (md.TARGET_POSITION, md.TARGET_VELOCITY)

        def copy(data: bytes) -> None:
            if gate:
                if len(data) > md.MAX_TARGET_BYTES:
                    self.refusals.refused(topic, 'bridge: ' + too_large(what, len(data)))
                    return
                reason = malformed_target(what, data)
                if reason:
                    self.refusals.refused(topic + ':malformed', 'bridge: ' + reason)
                    return
            try:
                out.publish(data)
            except InvalidHandle:       # (the copy stopped meanwhile)
                pass
        return copy

    def inward_kind(self, topic: str, types: list[str]) -> tuple | None:
        """(type, QoS) of a copy of `topic` in, from the node's own subscription on the bus;
        None when its type is not installed here or the subscription is not seen yet."""
        mine = [i for i in self.servo.get_subscriptions_info_by_topic(topic)
                if i.node_name == self.name and i.node_namespace == self.namespace]
        msg_type = self.type_of(topic, types)
        return None if msg_type is None or not mine else (msg_type, inward_qos(mine[0]))

    def _strangers(self, nodes: list[tuple[str, str]]) -> None:
        """Say so (once per node) when the servo bus holds a node that is neither a bridge nor
        bridged: another system on the bus's domain, whose participants the loop's streams now
        meet (servo_bus: choose domains 50 apart)."""
        if time.monotonic() < self.started + STARTUP:
            return               # (a node and its bridge are discovered in either order)
        names = {n for n, _ in nodes}
        unbridged = {ns.rstrip('/') + '/' + n for n, ns in nodes
                     if not n.startswith('_bridge_') and f'_bridge_{n}' not in names}
        # (in two looks running: a restarted peer and its bridge are discovered in either order)
        for fqn in sorted(unbridged & self.suspects - self.strangers):
            self.strangers.add(fqn)
            self.log(f'bridge: {fqn} is on the servo bus (domain '
                     f'{self.servo.context.get_domain_id()}) and not bridged: another system '
                     f'on this domain? Its participants can hold up the loop')
        self.suspects = unbridged

    def type_of(self, name: str, types: list[str]):
        """The class of `name`'s first type; None (said once) when not installed here."""
        t = interface_type(types[0]) if types else None
        if t is None and name not in self.skipped:
            self.skipped.add(name)
            self.log(f'bridge: {name} ({types}) not mirrored: its type is not installed here')
        return t

    def _forward(self, client, service: str):
        if service.endswith('/_action/get_result'):
            return self._forward_result(client)

        def answer(request, response):
            try:
                return client.call(request, timeout_sec=SERVICE_TIMEOUT)
            except TimeoutError:
                self.log(f'bridge: {self.fqn} did not answer {service} within '
                         f'{SERVICE_TIMEOUT:g} s')
                return response
        return answer

    def _forward_result(self, client):
        """An action's get_result is answered when its goal ends, however long that takes: it
        is forwarded without a timeout and awaited as a coroutine, so that no thread of the
        bridge waits on it (the client's answer wakes the executor that awaits)."""
        async def answer(request, response):
            future = client.call_async(request)
            executor = self.public.executor
            if executor is not None:
                future.add_done_callback(lambda _: executor.wake())
            return await future
        return answer

    def dropped(self, topic: str, e: Exception) -> None:
        if topic not in self.dropping:   # (one thread copies out: no lock)
            self.dropping.add(topic)
            self.log(f'bridge: {topic}: a sample not passed on ({e}); later ones not logged')

    def destroy(self) -> None:
        for node in (self.public, self.servo, self.calls, self.servo_in, self.servo_out):
            node.destroy_node()
