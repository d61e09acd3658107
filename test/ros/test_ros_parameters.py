"""The product over DDS, its parameters: the controller's and the plant's registers through
the parameter services `ros2 param` uses (set, set atomically, get, describe), what is
refused and why, and that what is accepted is what the loop runs with. Plant, controller,
probe and fixtures: nodes_kit.py (one slide for the module).
"""
from __future__ import annotations

import math

import pytest

rclpy = pytest.importorskip('rclpy')

from rclpy.parameter import Parameter  # noqa: E402
from rcl_interfaces.msg import ParameterType  # noqa: E402

from msg_defs.status import Status  # noqa: E402
from kit import COUNT, spin_for  # noqa: E402
from nodes_kit import Probe, changed, far_target  # noqa: E402
from nodes_kit import axis_fixture, slide_fixture  # noqa: E402,F401 (fixtures axis, slide)

try:                            # the project venv has pytest-timeout: a hung wait fails, not hangs
    import pytest_timeout  # noqa: F401
    pytestmark = pytest.mark.timeout(120)
except ImportError:
    pass


# -- the parameter services (`ros2 param`) ---------------------------------------------------------
def _axis_diag(p: Probe, key: str, since: float):
    """`key` of axis x in the newest /diagnostics stamped after `since` [s], or None."""
    for _, m in reversed(p.diag):
        if m.header.stamp.sec + m.header.stamp.nanosec * 1e-9 <= since:
            break
        for st in m.status:
            if st.name.endswith('axis x'):
                return {kv.key: kv.value for kv in st.values}.get(key)
    return None


def test_set_kp_is_applied(axis):
    """`ros2 param set /controller x.kp ...`: accepted, read back, in the loop (the gains
    /diagnostics reports are those the axis runs with), and the loop still moves and settles
    with it. (Fails if the node does not stage the new kp, checked by breaking it; that the
    law then pushes with it is test_servo_loop's test_a_kp_set_is_what_the_loop_pushes_with.)"""
    p = axis
    old = p.get_params('x.kp')['x.kp']
    new = old * 1.2
    results = p.set_params({'x.kp': new})
    assert results[0].successful, results[0].reason
    t0 = p.now() + 0.01             # applied at the tick after the answer: diagnostics after it
    try:
        assert p.get_params('x.kp') == {'x.kp': new}
        assert p.spin_until(lambda: _axis_diag(p, 'kp', t0) is not None, 2.5)
        assert float(_axis_diag(p, 'kp', t0)) == new
        p.move_and_wait(far_target(p.position(), 0.005))
    finally:
        assert p.set_params({'x.kp': old})[0].successful
    assert p.get_params('x.kp') == {'x.kp': old}


def test_output_limit_caps_the_command(axis):
    """output_limit (Ixx69) lowered to 0.5 V: joint_states effort never exceeds 0.5 V in the
    next move, and OUTPUT_SATURATED shows it is the limit at work."""
    p = axis
    with changed(p, {'x.output_limit': 0.5}):
        assert p.get_params('x.output_limit') == {'x.output_limit': 0.5}
        target = far_target(p.position(), 20 * COUNT)
        n0 = p.joint_count
        mark = p.publish_target(target)
        p.spin_until(lambda: p.done_since(mark), 3.0)
        p.spin_for_messages(50)                                 # and a while at rest
        during = list(p.joint_log)[-(p.joint_count - n0):]
        peak = max(abs(e) for *_, e in during)
        assert peak <= 0.5 + 1e-12, f'effort {peak} V above output_limit 0.5 V'
        assert any(w & Status.OUTPUT_SATURATED for w in p.words_since(mark)), \
            'the command never reached the limit: the test proves nothing'
    p.move_and_wait(far_target(p.position(), 0.001))


@pytest.mark.parametrize('value', [-1.0, math.nan], ids=['negative', 'nan'])
def test_invalid_kp_refused_loop_keeps_running(axis, value):
    p = axis
    old = p.get_params('x.kp')['x.kp']
    result = p.set_params({'x.kp': value})[0]
    assert not result.successful
    assert 'x.kp' in result.reason, result.reason
    assert p.get_params('x.kp') == {'x.kp': old}
    p.assert_loop_running()
    p.move_and_wait(far_target(p.position(), 0.002))


def test_nan_refused_for_a_register_without_range(axis):
    p = axis
    old = p.get_params('x.soft_limit_max')
    result = p.set_params({'x.soft_limit_max': math.nan})[0]
    assert not result.successful and 'x.soft_limit_max' in result.reason, result.reason
    assert p.get_params('x.soft_limit_max') == old


def test_integer_for_a_double_refused(axis):
    """Types are strict: `ros2 param set /controller x.kp 2` is refused (document 2.0), with a
    reason that names the parameter and the type."""
    p = axis
    old = p.get_params('x.kp')
    result = p.set_params({'x.kp': Parameter('x.kp', Parameter.Type.INTEGER, 2)})[0]
    assert not result.successful
    assert 'type' in result.reason.lower(), result.reason
    assert 'x.kp' in result.reason, result.reason
    assert p.get_params('x.kp') == old


def test_unknown_mode_refused(axis):
    p = axis
    old = p.get_params('x.mode')
    result = p.set_params({'x.mode': 'bogus'})[0]
    assert not result.successful and 'x.mode' in result.reason, result.reason
    assert 'position_pid' in result.reason        # the reason lists the valid choices
    assert p.get_params('x.mode') == old


def test_coarse_below_fine_tolerance_refused(axis):
    p = axis
    names = ('x.fine_position_tolerance', 'x.coarse_position_tolerance')
    old = p.get_params(*names)
    result = p.set_params({'x.coarse_position_tolerance': old[names[0]] / 2})[0]
    assert not result.successful
    assert 'x.coarse_position_tolerance' in result.reason
    assert 'fine_position_tolerance' in result.reason, result.reason
    assert p.get_params(*names) == old


def test_atomic_set_of_tolerances(axis):
    """Raising both tolerances above the old coarse one: the new fine alone is refused (it
    exceeds the old coarse), in one set_parameters_atomically call with the new coarse it is
    accepted and both apply. Going back down, the old coarse alone is refused (below the new
    fine); together with the old fine it is accepted."""
    p = axis
    fine, coarse = 'x.fine_position_tolerance', 'x.coarse_position_tolerance'
    old = p.get_params(fine, coarse)
    new = {fine: 2 * old[coarse], coarse: 4 * old[coarse]}
    alone = p.set_params({fine: new[fine]})[0]
    assert not alone.successful, alone.reason
    assert fine[2:] in alone.reason and coarse[2:] in alone.reason, alone.reason   # both named
    assert p.get_params(fine, coarse) == old
    result = p.set_atomically(new)
    assert result.successful, result.reason
    try:
        assert p.get_params(fine, coarse) == new
        p.move_and_wait(far_target(p.position(), 0.002))     # the loop runs with them
        alone = p.set_params({coarse: old[coarse]})[0]
        assert not alone.successful and coarse in alone.reason, alone.reason
        assert p.get_params(fine, coarse) == new
    finally:
        result = p.set_atomically(old)
    assert result.successful, result.reason
    assert p.get_params(fine, coarse) == old


def test_parameters_set_together_apply_on_the_same_tick(axis):
    """bias 1.5 V with output_limit 0.2 V in one call: had bias been applied a tick before the
    limit, that tick's command would be over 1 V; back to the old bias and limit in one call:
    had the limit come first, a tick would send the 1.5 V bias unclipped. Every command the
    controller sent (read reliably) shows neither. The bias pushes the way the output at rest
    already holds the slide, so the clipped 0.2 V changes the output by less than 0.2 V and
    does not break the slide loose (the other way, 0.4 V from a rest output of -0.19 V did:
    the loop then wound its error up to more than the limit, and the output after the set
    was the slide's recovery, not the set's)."""
    p = axis
    old = p.get_params('x.bias', 'x.output_limit')
    spin_for(p, 0.2)
    t0 = p.now()
    at_rest = [e for s, e in p.command_log if s > t0 - 0.2]
    assert at_rest, 'no command seen at rest'
    rest = max(abs(e) for e in at_rest)
    assert rest < 0.4, f"the axis is not at rest: {rest} V"
    way = 1.0 if sum(at_rest) >= 0.0 else -1.0
    assert p.set_atomically({'x.bias': way * 1.5, 'x.output_limit': 0.2}).successful
    spin_for(p, 0.3)
    t1 = p.now()
    result = p.set_atomically(old)
    assert result.successful, result.reason
    spin_for(p, 0.3)
    during = [abs(e) for s, e in p.command_log if t0 < s <= t1]
    after = [abs(e) for s, e in p.command_log if s > t1]
    # At rest the output stays within about `rest`; a tick with the bias and not the limit (or
    # the reverse) would send 1.5 V plus that.
    assert 0.2 in during, 'the limit never clipped the bias: the set was not applied'
    assert max(during) < 0.5 + rest, f'{max(during)} V: bias applied before output_limit'
    assert after and max(after) < 0.5 + rest, \
        f'{max(after)} V: output_limit applied before bias'


def test_read_only_servo_rate_refused(axis):
    p = axis
    old = p.get_params('servo_rate')
    result = p.set_params({'servo_rate': 500.0})[0]
    assert not result.successful
    assert 'servo_rate' in result.reason and 'read-only' in result.reason, result.reason
    assert p.get_params('servo_rate') == old == {'servo_rate': 1000.0}


def test_plant_parameters_use_the_same_rules(axis):
    """The plant's physics are parameters too: a valid set is applied, a wrong type or a
    negative backlash is refused naming the parameter."""
    plant = axis.plant_params
    assert plant.wait_for_services(10.0)
    old = axis.answer(lambda: plant.get_parameters(['x.backlash'])).values[0].double_value
    for value, ok in ((Parameter('x.backlash', Parameter.Type.INTEGER, 0), False),
                      (Parameter('x.backlash', value=-1e-5), False),
                      (Parameter('x.backlash', value=old), True)):
        (result,) = axis.answer(lambda: plant.set_parameters([value])).results
        assert result.successful == ok, result.reason
        assert ok or 'x.backlash' in result.reason, result.reason


def test_describe_kp(axis):
    (d,) = axis.describe('x.kp')
    assert d.name == 'x.kp' and d.type == ParameterType.PARAMETER_DOUBLE
    assert 'V/m' in d.description and 'Ixx30' in d.description, d.description
    assert len(d.floating_point_range) == 1
    assert d.floating_point_range[0].from_value == 0.0
    assert not d.read_only


# -- refused while moving (the axis's safety rules, issue 12) --------------------------------------
def test_limit_and_feedback_changes_refused_while_moving(slide, axis):
    """While a 50 mm move runs, a soft limit it would cross and a feedback change are refused
    naming the register and why; the move ends at its target within 3 counts."""
    p = axis
    here = p.position()
    target = far_target(here, 0.05)
    mark = p.publish_target(target)
    assert p.wait_status(lambda s: s & Status.MOVING)
    name, limit = (('x.soft_limit_max', here + 0.01) if target > here
                   else ('x.soft_limit_min', here - 0.01))
    result = p.set_params({name: limit})[0]
    assert not result.successful and name in result.reason and 'moves' in result.reason, \
        result.reason
    result = p.set_params({'x.feedback': 'motor'})[0]
    assert not result.successful and 'x.feedback' in result.reason, result.reason
    assert p.spin_until(lambda: p.done_since(mark), 6.0), repr(p.word)
    assert not p.word & Status.LIMIT
    p.spin_for_messages(5)
    assert abs(p.load_position() - target) <= 3 * COUNT
