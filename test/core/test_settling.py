"""Tests of motion_ctrl.core.settling: RMP settling criteria and motion events (seed 004).

Scripted sequences of update() calls with explicit numbers; dt = 1 ms, settling_time = 10 ms,
so "held for settling_time" means exactly 10 ticks after the first tick where the criteria hold.
"""

import math

import pytest

from motion_ctrl.core.config import SettlingConfig
from motion_ctrl.core.settling import MOTION_BITS, TIME_EPSILON, Settling
from msg_defs.status import Status

DT = 0.001
FINE = 2e-6
VEL_TOL = 1e-3
ST = 0.01
TARGET = 0.001

S = Status


def config(fine, coarse, vel, st) -> SettlingConfig:
    return SettlingConfig.of(dict(fine_position_tolerance=fine, coarse_position_tolerance=coarse,
                                  velocity_tolerance=vel, settling_time=st))


def make(coarse=5e-6, fine=FINE, vel=VEL_TOL, st=ST):
    return Settling(config(fine, coarse, vel, st))


def run(s, rows):
    """rows: (command_position, command_velocity, profile_done, actual_position, actual_velocity).

    Returns the list of bits, one per tick, and the clock after each tick.
    """
    out, clocks = [], []
    for cp, cv, done, ap, av in rows:
        bits = s.update(DT, command_position=cp, command_velocity=cv, profile_done=done,
                        actual_position=ap, actual_velocity=av)
        assert bits == s.bits
        assert bits & ~MOTION_BITS == 0
        out.append(bits)
        clocks.append(s.clock)
    return out, clocks


def first(bits, flag):
    """Index of the first tick where ``flag`` is set (None if never)."""
    return next((i for i, b in enumerate(bits) if b & flag), None)


def at_rest(n, pos=TARGET, cmd=TARGET, vel=0.0):
    return [(cmd, 0.0, True, pos, vel)] * n


# A scripted 1 mm move: the command ramps and reaches the target exactly at tick 4; the actual
# position lags and rings in; both fine criteria first hold on tick 7.
MOVE = [
    # cmd     cmd_vel done   actual     act_vel
    (0.0002, 0.2, False, 0.0,      0.1),    # 0  MOVING
    (0.0004, 0.2, False, 0.0001,   0.2),    # 1
    (0.0006, 0.2, False, 0.0003,   0.2),    # 2
    (0.0008, 0.2, False, 0.00055,  0.2),    # 3  |err| = 4.5e-4
    (0.001,  0.0, True,  0.0008,   0.2),    # 4  AT_TARGET (command == target), |err| = 2e-4
    (0.001,  0.0, True,  0.00095,  0.1),    # 5  |err| = 5e-5
    (0.001,  0.0, True,  0.000997, 0.02),   # 6  |err| = 3e-6 (< 5e-6 coarse), fast
    (0.001,  0.0, True,  0.000999, 0.0005), # 7  |err| = 1e-6 <= fine, |v| <= tol: first hold
] + at_rest(15)                             # 8..22


# 1. ------------------------------------------------------------------ event order
@pytest.mark.parametrize('coarse, coarse_tick', [(5e-6, 6), (5e-4, 3)])
def test_position_move_event_order(coarse, coarse_tick):
    s = make(coarse=coarse)
    s.start_position_move(TARGET)
    bits, clocks = run(s, MOVE)
    assert bits[0] == S.MOVING
    assert first(bits, S.MOVING) == 0
    assert [bool(b & S.MOVING) for b in bits[:6]] == [True] * 4 + [False] * 2
    assert first(bits, S.AT_TARGET) == 4
    assert first(bits, S.IN_COARSE_POSITION) == coarse_tick
    if coarse == 5e-4:
        assert first(bits, S.IN_COARSE_POSITION) < first(bits, S.AT_TARGET)
    else:
        assert first(bits, S.AT_TARGET) < first(bits, S.IN_COARSE_POSITION)
    # both fine criteria first hold on tick 7 -> settled exactly 10 ticks (= 10 ms) later
    assert first(bits, S.IN_FINE_POSITION) == 17
    assert first(bits, S.MOTION_DONE) == 17
    assert s.settle_start == pytest.approx(clocks[7], abs=1e-12)
    assert bits[16] & (S.IN_FINE_POSITION | S.MOTION_DONE) == 0
    assert bits[17] == S.AT_TARGET | S.IN_COARSE_POSITION | S.IN_FINE_POSITION | S.MOTION_DONE
    assert all(b & S.MOTION_DONE and b & S.IN_FINE_POSITION for b in bits[17:])
    assert not any(b & (S.MOTION_AT_VELOCITY | S.STOPPED | S.ESTOPPED | S.ABORTED) for b in bits)


def test_settling_time_zero_settles_on_first_holding_tick():
    s = make(st=0.0)
    s.start_position_move(TARGET)
    bits, _ = run(s, MOVE)
    assert first(bits, S.IN_FINE_POSITION) == 7
    assert first(bits, S.MOTION_DONE) == 7


@pytest.mark.parametrize('dt, st, ticks', [
    (0.001, 0.01, 10),     # sum of 10 x 1 ms = 0.010000000000000002
    (0.1, 1.0, 10),        # sum of 10 x 0.1 = 0.9999999999999999: needs TIME_EPSILON
    (0.0005, 0.01, 20),
    (0.001, 0.0015, 2),    # not a multiple of dt: first tick with held >= settling_time
])
def test_held_for_settling_time_exact_tick(dt, st, ticks):
    s = make(st=st)
    s.start_position_move(TARGET)
    done = []
    for _ in range(ticks + 3):
        b = s.update(dt, command_position=TARGET, command_velocity=0.0, profile_done=True,
                     actual_position=TARGET, actual_velocity=0.0)
        done.append(bool(b & S.MOTION_DONE))
    assert done.index(True) == ticks


def test_uneven_dt_sums_actual_time():
    s = make(st=0.01)
    s.start_position_move(TARGET)
    got = []
    for dt in [0.001, 0.004, 0.004, 0.001, 0.0009, 0.002]:   # held: 0, 4, 8, 9, 9.9, 11.9 ms
        b = s.update(dt, command_position=TARGET, command_velocity=0.0, profile_done=True,
                     actual_position=TARGET, actual_velocity=0.0)
        got.append(bool(b & S.IN_FINE_POSITION))
    assert got == [False] * 5 + [True]


def test_timing_independent_of_clock_magnitude():
    s = make()
    s.update(1e5, command_position=0.0, command_velocity=0.0, profile_done=True,
             actual_position=0.0, actual_velocity=0.0)      # the clock is now large
    s.start_position_move(TARGET)
    bits, clocks = run(s, MOVE)
    assert first(bits, S.MOTION_DONE) == 17
    assert s.settle_start == clocks[7]
    assert TIME_EPSILON < DT / 1000


# 2. ------------------------------------------------------------------ disturbance
def test_disturbance_resets_settling_timer():
    s = make()
    s.start_position_move(TARGET)
    rows = at_rest(5) + [(TARGET, 0.0, True, TARGET + 1e-5, 0.0)] + at_rest(20)
    bits, clocks = run(s, rows)
    # holds from tick 0; tick 5 is out of fine tolerance; holds again from tick 6
    assert not any(b & (S.IN_FINE_POSITION | S.MOTION_DONE) for b in bits[:16])
    assert first(bits, S.MOTION_DONE) == 16      # 10 ticks after the disturbance ended
    assert first(bits, S.IN_FINE_POSITION) == 16
    assert s.settle_start == pytest.approx(clocks[6], abs=1e-12)
    # sanity: without the disturbance it would have been tick 10
    s2 = make()
    s2.start_position_move(TARGET)
    assert first(run(s2, at_rest(20))[0], S.MOTION_DONE) == 10


def test_motion_done_latched_in_fine_keeps_tracking():
    s = make()
    s.start_position_move(TARGET)
    rows = at_rest(11) + [(TARGET, 0.0, True, TARGET - 1e-5, 0.0)] + at_rest(12)
    bits, _ = run(s, rows)
    assert first(bits, S.MOTION_DONE) == 10
    assert bits[11] & S.MOTION_DONE                        # raised once, stays for the move
    assert not bits[11] & S.IN_FINE_POSITION               # SETTLED tracks the disturbance
    assert not bits[11] & S.IN_COARSE_POSITION             # 1e-5 > coarse 5e-6
    assert [bool(b & S.IN_FINE_POSITION) for b in bits[12:]] == [False] * 10 + [True] * 2
    assert all(b & S.MOTION_DONE for b in bits[10:])
    s.start_position_move(TARGET)                          # a new move clears it
    assert not s.bits & S.MOTION_DONE
    assert not run(s, at_rest(1))[0][0] & S.MOTION_DONE


# 3. ------------------------------------------------------------------ velocity criterion
def test_velocity_tolerance_matters_for_position_moves():
    s = make()
    s.start_position_move(TARGET)
    rows = at_rest(50, vel=2e-3) + at_rest(11, vel=VEL_TOL)
    bits, _ = run(s, rows)
    assert all(b & S.AT_TARGET and b & S.IN_COARSE_POSITION for b in bits)
    assert not any(b & (S.IN_FINE_POSITION | S.MOTION_DONE) for b in bits[:60])
    assert first(bits, S.MOTION_DONE) == 60                # |v| <= tol from tick 50


def test_zero_velocity_tolerance_does_not_disable_criterion():
    s = make(vel=0.0)
    s.start_position_move(TARGET)
    bits, _ = run(s, at_rest(30, vel=1e-9))
    assert not any(b & (S.IN_FINE_POSITION | S.MOTION_DONE) for b in bits)
    bits, _ = run(s, at_rest(11, vel=0.0))
    assert first(bits, S.MOTION_DONE) == 10


def test_zero_fine_tolerance_does_not_disable_criterion():
    s = make(fine=0.0)
    s.start_position_move(TARGET)
    bits, _ = run(s, at_rest(30, pos=TARGET + 1e-9))
    assert not any(b & S.MOTION_DONE for b in bits)
    bits, _ = run(s, at_rest(11))
    assert first(bits, S.MOTION_DONE) == 10


# 4. ------------------------------------------------------------------ velocity moves
def test_velocity_move_at_velocity():
    s = make()
    v = 0.05
    s.start_velocity_move(v)
    ramp = [(0.00001 * (i + 1), 0.01 * (i + 1), False, 0.0, 0.008 * (i + 1)) for i in range(4)]
    cruise = [(0.001 + 0.00005 * i, v, True, 0.001 + 0.00005 * i, 0.0495) for i in range(15)]
    bad = [(0.002, v, True, 0.002, 0.052)]                 # |error| 2e-3 > tolerance
    again = [(0.002 + 0.00005 * i, v, True, 0.002, 0.0508) for i in range(12)]
    bits, _ = run(s, ramp + cruise + bad + again)
    assert all(b & S.MOVING for b in bits)                 # a jog keeps the generator active
    assert not any(b & (S.AT_TARGET | S.IN_COARSE_POSITION | S.IN_FINE_POSITION
                        | S.MOTION_DONE) for b in bits)
    # at constant velocity from tick 4 -> MOTION_AT_VELOCITY 10 ticks later
    assert first(bits, S.MOTION_AT_VELOCITY) == 14
    assert not bits[19] & S.MOTION_AT_VELOCITY              # cleared when broken
    assert [bool(b & S.MOTION_AT_VELOCITY) for b in bits[20:]] == [False] * 10 + [True] * 2
    # a velocity change clears it and restarts the timer
    s.start_velocity_move(0.06)
    bits, _ = run(s, [(0.003, 0.06, True, 0.003, 0.06)] * 11)
    assert first(bits, S.MOTION_AT_VELOCITY) == 10


def test_velocity_move_not_at_velocity_during_ramp():
    s = make()
    s.start_velocity_move(0.05)
    bits, _ = run(s, [(0.0, 0.049, False, 0.0, 0.05)] * 20)  # error small but still ramping
    assert not any(b & S.MOTION_AT_VELOCITY for b in bits)


def test_velocity_move_to_zero_gives_motion_done():
    s = make()
    s.start_velocity_move(0.0)
    decel = [(0.001, 0.02, False, 0.001, 0.02), (0.0011, 0.01, False, 0.0011, 0.01)]
    rest = [(0.0012, 0.0, True, 0.0012, 0.002)] * 3 + [(0.0012, 0.0, True, 0.0012, 0.0)] * 12
    bits, clocks = run(s, decel + rest)
    assert [bool(b & S.MOVING) for b in bits[:3]] == [True, True, False]
    assert first(bits, S.MOTION_DONE) == 15                # |v| <= tol from tick 5
    assert s.settle_start == pytest.approx(clocks[5], abs=1e-12)
    assert not any(b & (S.MOTION_AT_VELOCITY | S.AT_TARGET | S.IN_FINE_POSITION) for b in bits)


# 5. ------------------------------------------------------------------ STOP / ESTOP / ABORT
@pytest.mark.parametrize('kind, flag', [('stop', S.STOPPED), ('estop', S.ESTOPPED)])
def test_stop_and_estop(kind, flag):
    s = make()
    s.start_position_move(TARGET)
    run(s, MOVE[:3])
    s.start_stop(kind)
    decel = [(0.0007, 0.1, False, 0.0005, 0.15), (0.00075, 0.03, False, 0.0006, 0.05)]
    done = [(0.00076, 0.0, True, 0.0007, 0.02)] * 3
    bits, _ = run(s, decel + done)
    assert bits[:2] == [S.MOVING, S.MOVING]
    assert bits[2:] == [S.MOTION_DONE | flag] * 3           # at the end of the stop, unsettled
    s.start_position_move(TARGET)                            # stays until the next move
    assert s.bits == 0
    bits, _ = run(s, MOVE[:1])
    assert bits[0] == S.MOVING


def test_abort_at_once():
    s = make()
    s.start_position_move(TARGET)
    run(s, MOVE[:3])
    s.abort()
    assert s.bits == S.MOTION_DONE | S.ABORTED               # without an update()
    bits, _ = run(s, [(0.0006, 0.2, False, 0.0004, 0.2), (0.0006, 0.0, True, 0.0004, 0.0)])
    assert bits == [S.MOTION_DONE | S.ABORTED] * 2
    s.start_velocity_move(0.01)
    assert not s.bits & (S.ABORTED | S.MOTION_DONE)


def test_bad_stop_kind():
    s = make()
    with pytest.raises(ValueError, match='kind'):
        s.start_stop('halt')


def test_idle_nothing_pending():
    s = make()
    bits, _ = run(s, [(0.0, 0.0, True, 0.0, 0.0)])
    assert bits == [S.MOTION_DONE]                          # at rest, no move pending
    s.abort()
    s.idle()                                                # loop enabled again
    assert run(s, [(0.0, 0.0, True, 0.0, 0.3)])[0] == [S.MOTION_DONE]


# 6. ------------------------------------------------------------------ on-the-fly re-target
def test_retarget_on_the_fly():
    s = make(coarse=5e-5)
    s.start_position_move(TARGET)
    rows1 = [
        (0.0009, 0.1, False, 0.0008, 0.1),     # 0 |err| 2e-4
        (0.001, 0.0, True, 0.00096, 0.05),     # 1 AT_TARGET, |err| 4e-5 -> IN_COARSE
        (0.001, 0.0, True, 0.00099, 0.02),     # 2
    ]
    bits1, _ = run(s, rows1)
    assert [bool(b & S.IN_COARSE_POSITION) for b in bits1] == [False, True, True]
    assert [bool(b & S.AT_TARGET) for b in bits1] == [False, True, True]

    s.start_position_move(0.002)               # new target, command still at the old one
    rows2 = [
        (0.001, 0.0, False, 0.001, 0.0),       # 0 AT_TARGET cleared, |err| 1e-3
        (0.0015, 0.2, False, 0.0013, 0.2),     # 1
        (0.002, 0.0, True, 0.00196, 0.05),     # 2 AT_TARGET, |err| 4e-5 -> IN_COARSE again
        (0.002, 0.0, True, 0.0021, 0.0),       # 3 overshoot |err| 1e-4 -> IN_COARSE clears
        (0.002, 0.0, True, 0.00199, 0.0),      # 4 IN_COARSE again
    ]
    bits2, _ = run(s, rows2)
    assert [bool(b & S.AT_TARGET) for b in bits2] == [False, False, True, True, True]
    assert [bool(b & S.IN_COARSE_POSITION) for b in bits2] == [False, False, True, False, True]
    assert not any(b & S.MOTION_DONE for b in bits2)
    assert s.target == 0.002


# 7. ------------------------------------------------------------------ configuration
# The criteria come validated from the register table (SettlingConfig.of): a bad one is refused
# naming its register, before the Settling it was meant for changes.
@pytest.mark.parametrize('args, name', [
    ((2e-6, 1e-6, 1e-3, 0.01), 'coarse_position_tolerance must be >= fine'),
    ((-1e-6, 5e-6, 1e-3, 0.01), 'fine_position_tolerance'),
    ((2e-6, -5e-6, 1e-3, 0.01), 'coarse_position_tolerance'),
    ((2e-6, 5e-6, -1e-3, 0.01), 'velocity_tolerance'),
    ((2e-6, 5e-6, 1e-3, -0.01), 'settling_time'),
    ((math.nan, 5e-6, 1e-3, 0.01), 'fine_position_tolerance'),
    ((2e-6, math.nan, 1e-3, 0.01), 'coarse_position_tolerance'),
    ((2e-6, 5e-6, math.nan, 0.01), 'velocity_tolerance'),
    ((2e-6, 5e-6, 1e-3, math.nan), 'settling_time'),
    ((2e-6, math.inf, 1e-3, 0.01), 'coarse_position_tolerance'),
    ((2e-6, 5e-6, '1e-3', 0.01), 'velocity_tolerance'),
])
def test_bad_configuration_refused(args, name):
    s = make(coarse=5e-6)
    before = (s.fine_tolerance, s.coarse_tolerance, s.velocity_tolerance, s.settling_time)
    with pytest.raises(ValueError, match=name):
        s.configure(config(*args))
    assert (s.fine_tolerance, s.coarse_tolerance, s.velocity_tolerance,
            s.settling_time) == before
    s.start_position_move(TARGET)                           # still behaves as configured
    assert first(run(s, MOVE)[0], S.MOTION_DONE) == 17


def test_coarse_equal_fine_accepted():
    s = Settling(config(1e-6, 1e-6, 0.0, 0.0))
    assert (s.fine_tolerance, s.coarse_tolerance, s.velocity_tolerance,
            s.settling_time) == (1e-6, 1e-6, 0.0, 0.0)
