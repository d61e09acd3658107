"""The axis's safety rules (issue 12), in process on the harness: command precedence (ABORT >
ESTOP > STOP > move / jog), what cancels scheduled targets (command_epoch), live register
changes that bear on a move in progress, and memory that stays flat over status changes."""
import gc
import tracemalloc

import pytest

from kit import INCH
from motion_ctrl.core.axis import Axis
from motion_ctrl.core.commands import CommandResult
from motion_ctrl.sim.harness import Harness
from motion_ctrl.core.registers import AXIS_REGISTERS, axis_defaults
from msg_defs.status import Status as S

DEFAULTS = axis_defaults(AXIS_REGISTERS)
ESTOP_DEC, STOP_DEC = 1.0, 0.25       # m/s²: the case


def _cruising(**registers) -> Harness:
    """The slide moving toward 2 inches at max_velocity."""
    h = Harness(DEFAULTS | dict(estop_deceleration=ESTOP_DEC, stop_deceleration=STOP_DEC)
                | registers)
    assert h.axis.move_to(2 * INCH) == (True, '')
    assert h.run(1.0, until=lambda h: h.axis.profile.velocity >= DEFAULTS['max_velocity'])
    return h


def _stop_distance(h, until_done=2.0) -> float:
    start = h.plant.x_l
    assert h.run(until_done, until=lambda h: h.axis.status & S.MOTION_DONE)
    return h.plant.x_l - start


def test_a_stop_does_not_lower_an_estop():
    """ESTOP, then STOP 20 ms later: the STOP is refused with the reason, the slide stops over
    the ESTOP's distance (v²/2a = 5 mm at 0.1 m/s and 1 m/s², not the STOP's 20 mm), and the
    axis ends ESTOPPED."""
    ref = _cruising()
    assert ref.axis.stop('estop') == (True, '')
    estop_only = _stop_distance(ref)

    h = _cruising()
    assert h.axis.stop('estop') == (True, '')
    start = h.plant.x_l
    h.run(0.02)
    ok, reason = h.axis.stop('stop')
    assert not ok and 'ESTOP is in progress' in reason, reason
    travel = h.plant.x_l - start + _stop_distance(h)
    assert travel == pytest.approx(estop_only, abs=1e-4)
    assert travel < 0.006                                      # 5 mm + the servo lag
    assert h.axis.status & S.ESTOPPED and not h.axis.status & S.STOPPED


def test_an_estop_raises_a_stop_in_progress():
    h = _cruising()
    assert h.axis.stop('stop') == (True, '')
    h.run(0.02)
    assert h.axis.stop('estop') == (True, '')
    _stop_distance(h)
    assert h.axis.status & S.ESTOPPED and not h.axis.status & S.STOPPED


@pytest.mark.parametrize('kind', ['stop', 'estop'])
def test_targets_and_jogs_refused_while_a_stop_decelerates_then_accepted(kind):
    h = _cruising()
    assert h.axis.stop(kind)[0]
    h.run(0.01)
    for ok, reason in (h.axis.move_to(0.0), h.axis.jog(-0.05)):
        assert not ok and f'a {kind.upper()} is in progress' in reason, reason
    _stop_distance(h)
    assert h.axis.move_to(0.0) == (True, '')                   # at rest: a new move is fine


def test_a_command_answers_accepted_or_the_reason_it_was_refused():
    """Every command answers a CommandResult: a tuple, so `ok, reason = ...` reads it, with
    named fields for code that keeps it."""
    h = _cruising()
    answer = h.axis.jog(2 * DEFAULTS['max_velocity'])
    assert isinstance(answer, CommandResult) and not answer.accepted
    assert answer.reason == (f"x: jog at {2 * DEFAULTS['max_velocity']:g} m/s refused: above "
                             f"max_velocity {DEFAULTS['max_velocity']:g} m/s"), answer.reason
    assert h.axis.stop() == CommandResult(accepted=True, reason='')


@pytest.mark.parametrize('command, why', [
    (lambda a: a.stop('stop'), 'STOP'),
    (lambda a: a.stop('estop'), 'ESTOP'),
    (lambda a: a.abort(), 'ABORT'),
    (lambda a: a.enable(False), 'disable'),
])
def test_stops_and_disable_cancel_what_was_scheduled(command, why):
    """The controller node drops scheduled targets of an older command_epoch."""
    h = _cruising()
    epoch = h.axis.command_epoch
    assert command(h.axis)[0]
    assert h.axis.command_epoch == epoch + 1 and h.axis.cancelled_by == why


def test_a_fault_cancels_what_was_scheduled_and_says_why():
    h = Harness(DEFAULTS | dict(following_error_fatal=10e-6, following_error_warning=0.0))
    epoch = h.axis.command_epoch
    h.axis.move_to(0.01)
    h.run(0.2)
    assert h.axis.faults == S.FOLLOWING_ERROR_FATAL
    assert h.axis.command_epoch == epoch + 1
    assert h.axis.cancelled_by == 'FOLLOWING_ERROR_FATAL'
    assert 'following_error_fatal 0.01 mm' in h.axis.fault_reason, h.axis.fault_reason


def test_a_soft_limit_the_move_would_cross_is_refused_while_moving():
    """soft_limit_max 0.02 m while moving to 0.0508 m: refused naming the register and the
    travel; one the move stays inside is fine; at rest the lower limit applies."""
    h = _cruising()
    reason = h.axis.live_change_refusal({'soft_limit_max': 0.02})
    assert reason and 'x.soft_limit_max' in reason and '0.0508' in reason, reason
    assert h.axis.live_change_refusal({'soft_limit_min': -0.02}) is None
    assert h.axis.live_change_refusal({'soft_limit_max': 0.06}) is None
    _stop_distance(h, 3.0)
    assert h.axis.live_change_refusal({'soft_limit_max': 0.02}) is None


def test_a_jog_takes_a_limit_ahead_and_refuses_one_behind():
    """A limit lowered ahead of a jog is braked onto (LIMIT, at rest on it); one the command has
    already passed is refused."""
    h = Harness()
    assert h.axis.jog(0.05) == (True, '')
    h.run(0.2)
    here = h.axis.command_position
    reason = h.axis.live_change_refusal({'soft_limit_max': here - 0.001})
    assert reason and 'x.soft_limit_max' in reason, reason
    ahead = here + 0.01
    assert h.axis.live_change_refusal({'soft_limit_max': ahead}) is None
    h.axis.configure(h.axis.r | {'soft_limit_max': ahead})
    assert h.run(2.0, until=lambda h: h.axis.status & S.MOTION_DONE)
    assert h.axis.status & S.LIMIT
    assert h.axis.command_position == pytest.approx(ahead, abs=1e-9)


def test_a_feedback_change_is_refused_while_moving():
    """It used to drop the move with a hard stop ~12 mm in, MOTION_DONE 39 mm short."""
    h = _cruising()
    reason = h.axis.live_change_refusal({'feedback': 'motor'})
    assert reason and 'x.feedback' in reason and 'stop first' in reason, reason
    assert h.axis.live_change_refusal({'feedback': DEFAULTS['feedback']}) is None
    _stop_distance(h, 3.0)
    assert h.axis.live_change_refusal({'feedback': 'motor'}) is None


@pytest.mark.core_slow
def test_memory_flat_over_10000_status_word_changes():
    """The node's axes keep no history of status words (Axis.events is for the harness): 10,000
    changes allocate < 50 kB that stay (it was ~75 bytes a change)."""
    a = Axis('x', DEFAULTS)
    a.home(0, 0)
    for _ in range(100):                                  # warm the Status word cache
        a.enable(False)
        a.enable(True)
    gc.collect()
    tracemalloc.start()
    before = tracemalloc.get_traced_memory()[0]
    for _ in range(5000):
        a.enable(False)
        a.enable(True)
    gc.collect()
    grown = tracemalloc.get_traced_memory()[0] - before
    tracemalloc.stop()
    assert grown < 50_000, grown


# The precedence table of doc/interface.md, every pair: (state in progress, command) -> accepted?
_COMMANDS = {
    'move': lambda a: a.move_to(0.0),
    'jog': lambda a: a.jog(-0.05),
    'stop': lambda a: a.stop('stop'),
    'estop': lambda a: a.stop('estop'),
    'abort': lambda a: a.abort(),
    'disable': lambda a: a.enable(False),
}
_TABLE = {
    'moving': dict(move=True, jog=True, stop=True, estop=True, abort=True, disable=True),
    'stop': dict(move=False, jog=False, stop=True, estop=True, abort=True, disable=True),
    'estop': dict(move=False, jog=False, stop=False, estop=True, abort=True, disable=True),
}


@pytest.mark.parametrize('state, command', [(s, c) for s in _TABLE for c in _COMMANDS])
def test_command_precedence_table(state, command):
    h = _cruising()
    if state != 'moving':
        assert h.axis.stop(state)[0]
        h.run(0.01)
        assert h.axis.stopping
    ok, reason = _COMMANDS[command](h.axis)
    assert ok is _TABLE[state][command], reason
    if not ok:
        assert 'in progress' in reason, reason
