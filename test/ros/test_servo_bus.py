"""The servo bus's rules that need no running node (motion_ctrl.ros.servo_bus, bridge)."""
import types

import pytest

pytest.importorskip('rclpy')

from rclpy.serialization import serialize_message  # noqa: E402
from sensor_msgs.msg import JointState  # noqa: E402

from motion_ctrl.ros import servo_bus  # noqa: E402
from motion_ctrl.ros.refusals import malformed_target  # noqa: E402
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


def test_a_stream_published_by_a_node_off_the_bus_is_foreign():
    """The servo streams are copied in from the user's domain only when a node that is not a
    bridge publishes them there (a plant of another make); a bridge's copy out is not, nor an
    endpoint whose node is not known yet."""
    user_side = [('controller', '/'), ('_bridge_controller_in', '/'), ('plant', '/'),
                 ('_bridge_plant_in', '/')]

    def bridge(*publishers, nodes=user_side):
        infos = [types.SimpleNamespace(node_name=n, node_namespace=ns) for n, ns in publishers]
        return types.SimpleNamespace(public=types.SimpleNamespace(
            get_publishers_info_by_topic=lambda topic: infos,
            get_node_names_and_namespaces=lambda: nodes))
    assert not Bridge._foreign_publisher(bridge(), '/encoders')
    assert not Bridge._foreign_publisher(bridge(('plant', '/')), '/encoders')
    assert not Bridge._foreign_publisher(bridge(('_NODE_NAME_UNKNOWN_', '/')), '/encoders')
    assert Bridge._foreign_publisher(bridge(('plant', '/'), nodes=user_side[:2] + [('plant', '/')]),
                                     '/encoders')
    assert Bridge._foreign_publisher(bridge(('plant', '/'), ('drive', '/x')), '/encoders')


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
