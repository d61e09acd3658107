"""The servo bus's rules that need no running node (motion_ctrl.ros.servo_bus, bridge)."""
import types

import pytest

pytest.importorskip('rclpy')

from diagnostic_msgs.msg import DiagnosticStatus  # noqa: E402
from rclpy.serialization import serialize_message  # noqa: E402
from sensor_msgs.msg import JointState  # noqa: E402

from motion_ctrl.ros import servo_bus  # noqa: E402
from motion_ctrl.ros.refusals import RefusalLog, malformed_target  # noqa: E402
from motion_ctrl.ros.servo_bus import commander, relay  # noqa: E402
from motion_ctrl.ros.servo_bus.commander import StreamIn  # noqa: E402
from motion_ctrl.ros.servo_bus.bridge import STARTUP, Bridge  # noqa: E402


@pytest.mark.parametrize('value, user, bus', [
    ('auto', '7', 58), ('auto', '0', 51), ('auto', '60', 10), ('', '7', 58), ('off', '7', None),
    ('12', '7', 12)])
def test_servo_domain_from_the_environment(value, user, bus):
    env = {servo_bus.ENV: value, 'ROS_DOMAIN_ID': user}
    assert servo_bus.servo_domain(env) == bus


@pytest.mark.parametrize('value, why', [('7', 'a domain of its own'), ('300', 'a ROS domain id'),
                                        ('bus', 'a ROS domain id')])
def test_servo_domain_refused_with_the_reason(value, why):
    with pytest.raises(ValueError, match=why):
        servo_bus.servo_domain({servo_bus.ENV: value, 'ROS_DOMAIN_ID': '7'})


def _bridge(started: float) -> types.SimpleNamespace:
    lines: list[str] = []
    context = types.SimpleNamespace(get_domain_id=lambda: 58)
    return types.SimpleNamespace(started=started, strangers=set(), suspects=set(),
                                 log=lines.append,
                                 lines=lines, servo=types.SimpleNamespace(context=context))


BUS = [('_bridge_controller', '/'), ('_bridge_controller_calls', '/'), ('controller', '/'),
       ('_bridge_plant', '/'), ('_bridge_plant_calls', '/'), ('plant', '/')]


def test_a_node_of_another_system_on_the_bus_is_named_once():
    """A node on the servo bus that is neither a bridge nor bridged (a test's publisher, another
    system on that domain) is named in the log, once; the bridged pair is not."""
    b = _bridge(started=-2 * STARTUP)
    Bridge._strangers(b, BUS)
    assert b.lines == []
    Bridge._strangers(b, BUS + [('bad_encoders', '/test')])
    assert b.lines == []                 # (a node may be seen a look before its bridge)
    Bridge._strangers(b, BUS + [('bad_encoders', '/test')])
    Bridge._strangers(b, BUS + [('bad_encoders', '/test')])
    assert len(b.lines) == 1 and '/test/bad_encoders' in b.lines[0] and 'domain 58' in b.lines[0]


def test_nothing_is_judged_while_the_nodes_come_up():
    """In the first STARTUP s a node may be seen before its bridge: no word then."""
    import time
    b = _bridge(started=time.monotonic())
    Bridge._strangers(b, [('plant', '/')])
    assert b.lines == []


USER_SIDE = [('controller', '/'), ('_bridge_controller_in', '/'), ('plant', '/'),
             ('_bridge_plant_in', '/')]


def test_a_bridge_on_the_users_domain_is_known_by_its_in_node():
    """A bridge's copy out is not a source of another make: its participant holds
    `_bridge_<name>_in` beside `<name>`."""
    assert commander.bridged(USER_SIDE) == {('controller', '/'), ('plant', '/')}
    assert commander.bridged(USER_SIDE[:2] + [('plant', '/')]) == {('controller', '/')}


def _endpoint(node: str, gid: int):
    ns, _, name = node.rpartition('/')
    return types.SimpleNamespace(node_name=name, node_namespace=ns or '/', endpoint_gid=[gid] * 16)


def _sample(gid: int) -> dict:
    return {'publisher_gid': {'implementation_identifier': 'rmw_fastrtps_cpp',
                              'data': bytes([gid] * 16)}}


def _stream(lines: list):
    made: list = []
    bus = types.SimpleNamespace(create_publisher=lambda *a: types.SimpleNamespace(
        publish=made.append), destroy_publisher=lambda p: None)
    reader = types.SimpleNamespace(create_subscription=lambda *a, **k: None)
    stream = StreamIn('/plant', '/command', JointState, 10, reader, bus, RefusalLog(lines.append),
                      lines.append)
    return stream, made


@pytest.mark.parametrize('bus_peers, peer, copied', [
    (['/controller'], None, []),                       # the controller on the bus: its own only
    (['/controller'], '/mine', []),                    # ... even a named one gives way to it
    ([], None, []),                                    # no peer: nothing taken unnamed
    ([], '/mine', [1])])                               # a controller of another make, named
def test_one_commander_the_plant_takes_command_from_its_peer_only(bus_peers, peer, copied):
    """`command` published on the user's domain by `/mine` (1), `/stray` (2) and the
    controller's bridge (3, its copy of the bus's own stream): with its controller on the bus
    the plant's bridge copies none in; without, the named one only. Each refused source is
    logged by name with the reason, a bridge's copy is dropped without a word, and the status
    says WARN with the counts, then OK once they stop."""
    lines: list[str] = []
    stream, made = _stream(lines)
    stream.bind([_endpoint('/mine', 1), _endpoint('/stray', 2), _endpoint('/controller', 3)],
                {('controller', '/')}, bus_peers, peer)
    for gid in (1, 2, 3, 1, 2, 3):
        stream._sample(b'cdr%d' % gid, _sample(gid))
    assert made == [b'cdr%d' % g for g in copied * 2]
    refused = [n for n in ('/mine', '/stray') if n != peer or bus_peers]
    said = [ln for ln in lines if 'refused' in ln]
    assert [ln.split(' from ')[1].split(' ')[0] for ln in said] == refused
    why = ('takes command from /controller on the servo bus only' if bus_peers else
           f'takes command from {peer} only (MOTION_CTRL_SERVO_PEER)' if peer else
           'none is there; name a source of another make with MOTION_CTRL_SERVO_PEER')
    assert all(why in ln and ln.startswith('bridge: /command from /') for ln in said), said
    st = stream.status()
    assert st.level == DiagnosticStatus.WARN and st.name == 'plant: command source'
    assert {kv.key: kv.value for kv in st.values} == {f'refused from {n}': '2' for n in refused}
    assert stream.status().level == DiagnosticStatus.OK
    assert stream.status() is None


def test_the_named_source_is_copied_in_and_said_once():
    lines: list[str] = []
    stream, made = _stream(lines)
    for _ in range(2):
        stream.bind([_endpoint('/plant_x', 7)], set(), [], '/plant_x')
    assert [ln for ln in lines if 'copied in' in ln] == [
        "bridge: /command from /plant_x copied in (MOTION_CTRL_SERVO_PEER; a hop more of "
        "latency, and what joins the user's domain can hold it up)"]
    assert stream.status() is None             # nothing refused, nothing to say


@pytest.mark.parametrize('value, name', [('plant', '/plant'), ('/cell/plant/', '/cell/plant'),
                                         ('', None), (' / ', None)])
def test_the_named_peer_is_a_full_node_name(value, name):
    assert commander.named_peer({commander.PEER_ENV: value}) == name


@pytest.mark.parametrize('what, msg, reason', [
    ('target_position', dict(name=['x'], position=[float('nan')]),
     "target_position refused: non-finite position for ['x']"),
    ('target_velocity', dict(name=['x', 'y'], velocity=[0.01]),
     "target_velocity refused: velocity has 1 entries for 2 names ['x', 'y']"),
    ('target_position', dict(name=['x', 'x'], position=[0.0, 0.0]),
     "target_position refused: duplicate joint names ['x', 'x']"),
    ('target_position', dict(name=['x', 'no_such_axis'], position=[0.0, 0.0]), None),
    ('target_velocity', dict(name=['x'], velocity=[0.01]), None)])
def test_the_bridge_refuses_a_target_no_axis_could_take(what, msg, reason):
    """What the bridge stops before the servo bus (a NaN target flood no longer reaches the
    loop's thread); an unknown axis is the controller's to judge."""
    assert malformed_target(what, serialize_message(JointState(**msg))) == reason
    assert malformed_target(what, b'\x00\x01\x00\x00garbage').startswith(
        f'{what} refused: not a JointState')


@pytest.mark.parametrize('env, reaches', [
    ({}, False), ({'ROS_AUTOMATIC_DISCOVERY_RANGE': 'LOCALHOST'}, False),
    ({'ROS_AUTOMATIC_DISCOVERY_RANGE': 'subnet'}, True),
    ({'ROS_AUTOMATIC_DISCOVERY_RANGE': 'SYSTEM_DEFAULT'}, True),
    ({'ROS_AUTOMATIC_DISCOVERY_RANGE': 'LOCALHOST', 'ROS_STATIC_PEERS': '10.0.0.2'}, True),
    ({'ROS_DISCOVERY_SERVER': '10.0.0.1:11811'}, True)])
def test_a_domain_that_reaches_other_hosts_is_relayed(env, reaches):
    """The bridge's user side goes through a relay (servo_bus.relay) when the environment
    discovers beyond this host; its local domain is neither the user's nor the bus's."""
    assert relay.reaches_other_hosts(env) is reaches
    for user in range(0, 102):
        env = {'ROS_DOMAIN_ID': str(user)}
        assert relay.local_domain(env) not in (user, servo_bus.servo_domain(env))
        assert 1 <= relay.local_domain(env) <= 101


def test_a_relay_copies_no_servo_stream_in():
    """A relay's node is another bridge: whatever publishes `command` on the user's domain
    (another host), a named peer too, is refused by name, with why."""
    lines: list[str] = []
    stream, made = _stream(lines)
    stream.bind([_endpoint('/mine', 1), _endpoint('/laptop', 2)], set(), [], '/mine', relay=True)
    for gid in (1, 2):
        stream._sample(b'cdr', _sample(gid))
    assert made == []
    assert lines == [f'bridge: /command from {n} refused: /plant takes command from its peer on '
                     f'its own host only (this is a relay to other hosts)' for n in ('/mine',
                                                                                    '/laptop')]
