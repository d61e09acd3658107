"""One commander per amplifier: the servo streams a node reads (`command` into a plant,
`encoders` into a controller, `/clock` in sim time) come from the one source it is bound to, as
a drive takes its setpoints from one master (an EtherCAT master, a CANopen SYNC producer) and
treats a second as an error, not as a mix.

The node's source is its peer on the servo bus (the controller of a plant, the plant of a
controller). Its bridge watches the user's domain for publishers of those streams that are not
bridges (a `ros2 topic pub`, a stray node, a laptop): while the node has a peer on the bus each
of them is refused. Without a peer on the bus the node can be bound on purpose to a node of
another make on the user's domain, named by PEER_ENV (its full name, e.g. `/plant`): that
node's samples are copied onto the bus and every other source's refused. A relay to other
hosts (servo_bus.relay) copies none in: the node's source is on its own host.

A refused sample never reaches the bus. The bridge logs each refused source once a second with
a count (ros.refusals), naming the node, and publishes on /diagnostics a status
`<node>: <topic> source`: WARN while samples are refused, naming each source and its count, OK
once they stop. Samples are told apart by their publisher's GID (rclpy's MessageInfo), matched
to nodes through the graph; a bridge's copy of the bus's own stream (the peer's bridge copies
it out for this reader) is dropped without a word.
"""
from __future__ import annotations

import os
import time

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from rclpy.callback_groups import MutuallyExclusiveCallbackGroup
from rclpy.exceptions import InvalidHandle
from rclpy.publisher import Publisher
from rclpy.qos import QoSProfile

import msg_defs as md

PEER_ENV = 'MOTION_CTRL_SERVO_PEER'
BRIDGE_PREFIX = '_bridge_'
UNKNOWN_NODE = '_NODE_NAME_UNKNOWN_'   # rmw's name for an endpoint whose node is not known yet
STATUS_PERIOD = 1.0                    # s between /diagnostics of the streams' sources


def named_peer(environ=os.environ) -> str | None:
    """The node of another make named by PEER_ENV, as a full name (`plant` -> `/plant`)."""
    value = environ.get(PEER_ENV, '').strip()
    return '/' + value.strip('/') if value.strip('/') else None


def fqn(info) -> str:
    """The full name of the node of an endpoint (rclpy TopicEndpointInfo)."""
    return info.node_namespace.rstrip('/') + '/' + info.node_name


class Commander:
    """The servo streams into the node of `bridge` (servo_bus.bridge.Bridge), bound to its one
    source: `look` from the bridge's look at the graph, `report` from its poll."""

    def __init__(self, bridge, peer: str | None, relay: bool = False):
        self.bridge, self.peer, self.relay = bridge, peer, relay
        self.streams: dict[str, StreamIn] = {}    # read while a foreign node publishes them
        self.finished: list[StreamIn] = []        # ... no longer read, an OK status still due
        self.diagnostics: Publisher | None = None  # the publisher of the streams' statuses
        self.next_status = 0.0

    def look(self, subscribed: list) -> None:
        """`subscribed`: (topic, types) of the servo streams the node reads. Each is read on
        the user's domain while nodes that are not bridges publish it there, and no longer
        once only bridges do."""
        b = self.bridge
        bridges = bridged(b.public.get_node_names_and_namespaces())
        for topic, types in subscribed:
            public = b.public.get_publishers_info_by_topic(topic)
            foreign = [i for i in public if (i.node_name, i.node_namespace) not in bridges]
            stream = self.streams.get(topic)
            if stream is None:
                # (a publisher whose node's names are not in yet: judged at the next look)
                kind = None if all(i.node_name == UNKNOWN_NODE for i in foreign) else \
                    self._kind(topic, types)
                if kind is None:
                    continue
                msg_type, qos = kind
                stream = self.streams[topic] = StreamIn(b.fqn, topic, msg_type, qos, b.servo_in,
                                                        b.servo, b.refusals, b.log)
            elif not foreign:
                self.streams.pop(topic).close()
                self.finished.append(stream)
                continue
            bus_peers = sorted(fqn(i) for i in b.servo.get_publishers_info_by_topic(topic)
                               if not i.node_name.startswith(BRIDGE_PREFIX)
                               and i.node_name != UNKNOWN_NODE)
            stream.bind([i for i in foreign if i.node_name != UNKNOWN_NODE], bridges,
                        bus_peers, self.peer, self.relay)

    def _kind(self, topic: str, types: list[str]) -> tuple | None:
        """(type, QoS) of the stream's reader: the node's own; a relay's node reads none
        (a relay only refuses)."""
        if not self.relay:
            return self.bridge.inward_kind(topic, types)
        msg_type = self.bridge.type_of(topic, types)
        return None if msg_type is None else (msg_type, QoSProfile(depth=10))

    def report(self) -> None:
        """/diagnostics of the streams' sources, once a second when there is something to say
        (StreamIn.status)."""
        now = time.monotonic()
        if now < self.next_status:
            return
        self.next_status = now + STATUS_PERIOD
        statuses = [st for st in (s.status() for s in [*self.streams.values(),
                                                        *self.finished]) if st is not None]
        self.finished = [s for s in self.finished if s.warned]     # (its OK still to come)
        if not statuses:
            return
        if self.diagnostics is None:
            self.diagnostics = self.bridge.public.create_publisher(
                DiagnosticArray, md.DIAGNOSTICS, 10)
        arr = DiagnosticArray(status=statuses)
        arr.header.stamp = self.bridge.public.get_clock().now().to_msg()
        self.diagnostics.publish(arr)


def bridged(nodes: list[tuple[str, str]]) -> set[tuple[str, str]]:
    """The bridged nodes among the user's domain's `nodes`: a bridge's participant there holds
    `_bridge_<name>_in` beside `<name>`, and a participant's node names arrive together, so
    this does not depend on what the bus's discovery has seen yet, and a restarted peer's
    bridge is not taken for a plant of another make."""
    return {(n[len(BRIDGE_PREFIX):-len('_in')], ns) for n, ns in nodes
            if n.startswith(BRIDGE_PREFIX) and n.endswith('_in')}


class StreamIn:
    """Servo stream `topic` into node `node` (its full name) while nodes that are not bridges
    publish it on the user's domain: read on `reader` (a node on the user's domain whose
    executor passes MessageInfo), a sample of an accepted source copied onto the bus through
    `bus_node`'s publisher, made when the first source is accepted."""

    def __init__(self, node: str, topic: str, msg_type, qos, reader, bus_node, refusals, log):
        self.node, self.topic, self.msg_type, self.qos = node, topic, msg_type, qos
        self.what = topic.rsplit('/', 1)[-1]
        self.reader, self.bus_node, self.refusals, self.log = reader, bus_node, refusals, log
        self.accepted: frozenset[bytes] = frozenset()   # publisher GIDs copied onto the bus
        self.names: dict[bytes, str] = {}               # GID -> node, of the refused sources
        self.reason = ''
        self.refused: dict[str, int] = {}               # node -> samples since the last status
        self.out: Publisher | None = None               # the publisher on the bus
        self.warned = False                             # the last status was a WARN
        self.sub = reader.create_subscription(msg_type, topic, self._sample, qos, raw=True,
                                              callback_group=MutuallyExclusiveCallbackGroup())

    def bind(self, public: list, bridges: set, bus_peers: list[str], peer: str | None,
             relay: bool = False) -> None:
        """From one look at the graph: `public`, the endpoints publishing the stream on the
        user's domain; `bridges`, the (name, namespace) of the bridges there; `bus_peers`, the
        nodes that publish it on the servo bus and are not bridges; `peer`, PEER_ENV's node;
        `relay`: a relay's, which copies no servo stream in."""
        foreign = [i for i in public if (i.node_name, i.node_namespace) not in bridges]
        accepted: list = []
        if relay:
            self.reason = (f'{self.node} takes {self.what} from its peer on its own host only '
                           f'(this is a relay to other hosts)')
        elif bus_peers:
            self.reason = (f'{self.node} takes {self.what} from {", ".join(bus_peers)} on the '
                           f'servo bus only')
        elif peer is not None:
            accepted = [i for i in foreign if fqn(i) == peer]
            self.reason = f'{self.node} takes {self.what} from {peer} only ({PEER_ENV})'
        else:
            self.reason = (f'{self.node} takes {self.what} from its peer on the servo bus only '
                           f'(none is there; name a source of another make with {PEER_ENV})')
        gids = frozenset(bytes(i.endpoint_gid) for i in accepted)
        self.names = {bytes(i.endpoint_gid): fqn(i) for i in foreign
                      if bytes(i.endpoint_gid) not in gids}
        if gids and self.out is None:
            self.out = self.bus_node.create_publisher(self.msg_type, self.topic, self.qos)
            self.log(f'bridge: {self.topic} from {peer} copied in ({PEER_ENV}; a hop more of '
                     f'latency, and what joins the user\'s domain can hold it up)')
        self.accepted = gids

    def _sample(self, data: bytes, info) -> None:
        gid = bytes(info['publisher_gid']['data'])
        if gid in self.accepted and self.out is not None:
            try:
                self.out.publish(data)
            except InvalidHandle:        # (closed meanwhile)
                pass
            return
        name = self.names.get(gid)
        if name is None:          # a bridge's copy of the bus's own stream (or not looked at yet)
            return
        self.refused[name] = self.refused.get(name, 0) + 1
        self.refusals.refused(f'{self.topic} from {name}',
                              f'bridge: {self.topic} from {name} refused: {self.reason}')

    def status(self) -> DiagnosticStatus | None:
        """The status since the last call: WARN naming the refused sources and their counts;
        OK once, after a WARN, when no sample was refused since; else None."""
        counts, self.refused = self.refused, {}
        if not counts and not self.warned:
            return None
        self.warned = bool(counts)
        st = DiagnosticStatus(name=f'{self.node.lstrip("/")}: {self.what} source',
                              hardware_id=self.node.lstrip('/'))
        if counts:
            st.level = DiagnosticStatus.WARN
            st.message = ('refused ' + ', '.join(f'{n} ({c} samples)' for n, c in counts.items())
                          + f': {self.reason}')
            st.values = [KeyValue(key=f'refused from {n}', value=str(c))
                         for n, c in counts.items()]
        else:
            st.level, st.message = DiagnosticStatus.OK, f'no other source: {self.reason}'
        return st

    def close(self) -> None:
        self.reader.destroy_subscription(self.sub)
        if self.out is not None:
            self.bus_node.destroy_publisher(self.out)
