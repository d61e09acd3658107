"""Tests of the one-axis move generator (motion_ctrl.core.profile)."""

import math

import pytest

from kit import INCH
from motion_ctrl.core.profile import Profile
from motion_ctrl.core.registers import CONTROLLER_AXIS
from motion_ctrl.core.config import ProfileConfig

T = 0.001          # 1 kHz servo period
VMAX = 0.1
AMAX = 1.0
JMAX = 20.0
REL = 1e-9         # relative slack on limits (float rounding only)


def limits(vmax=VMAX, amax=AMAX, jerk=0.0, smoothing=1.0) -> ProfileConfig:
    return ProfileConfig.of(dict(max_velocity=vmax, max_acceleration=amax, max_jerk=jerk,
                                 smoothing=smoothing))


def make(jerk=0.0, smoothing=1.0, position=0.0, vmax=VMAX, amax=AMAX):
    return Profile(position, limits(vmax, amax, jerk, smoothing), T)


def snap(p):
    return (p.position, p.velocity, p.acceleration,
            p.raw_position, p.raw_velocity, p.raw_acceleration,
            p.kind, p.target, p.target_velocity, p.done, p.at_target,
            p.moving, p.duration)


def run(p, dt=T, max_time=5.0, until=None):
    """Step until the profile stops moving (or `until(p)`); return the samples."""
    rows = []
    t = 0.0
    while t < max_time:
        p.step(dt)
        t += dt
        rows.append(dict(t=t, p=p.position, v=p.velocity, a=p.acceleration,
                         rp=p.raw_position, rv=p.raw_velocity, ra=p.raw_acceleration,
                         done=p.done, moving=p.moving, at_target=p.at_target,
                         kind=p.kind))
        if (until(p) if until else not p.moving):
            return rows
    raise AssertionError(f'profile still moving after {max_time} s')


def max_step(rows, key, dt=T):
    return max(abs(b[key] - a[key]) for a, b in zip(rows, rows[1:]))


# 1. Trapezoid --------------------------------------------------------------

def test_trapezoid_duration_limits_and_exact_end():
    p = make(jerk=0.0)
    p.move_to(INCH)
    # by hand: accel 0.1 s (5 mm) + cruise 15.4 mm / 0.1 m/s = 0.154 s + decel 0.1 s
    assert p.duration == pytest.approx(0.354, rel=1e-12)
    assert p.kind == 'position' and p.target == INCH and not p.done
    rows = run(p)
    assert max(abs(r['v']) for r in rows) <= VMAX * (1 + REL)
    assert max(abs(r['a']) for r in rows) <= AMAX * (1 + REL)
    assert max(abs(r['v']) for r in rows) == pytest.approx(VMAX)   # cruise reached
    assert max(r['p'] for r in rows) <= INCH                        # no overshoot
    assert p.position == INCH and p.raw_position == INCH         # exact, no residue
    assert p.velocity == 0.0 and p.acceleration == 0.0
    assert p.done and p.at_target and not p.moving
    assert rows[-1]['t'] == pytest.approx(0.354, abs=1.5 * T)


def test_trapezoid_triangular_move_does_not_reach_vmax():
    p = make(jerk=0.0, position=0.5)
    p.move_to(0.5 - 0.004)            # backwards, 4 mm
    assert p.duration == pytest.approx(2 * math.sqrt(0.004 / AMAX), rel=1e-12)  # 0.12649 s
    rows = run(p)
    peak = max(abs(r['v']) for r in rows)
    assert peak == pytest.approx(math.sqrt(0.004 * AMAX), rel=0.02) and peak < VMAX
    assert max(abs(r['a']) for r in rows) <= AMAX * (1 + REL)
    assert p.position == 0.5 - 0.004 and p.at_target


# 2. Jerk limited -----------------------------------------------------------

def test_jerk_limited_move():
    p = make(jerk=JMAX)
    p.move_to(0.05)
    # by hand: a/j = 0.05 s ramps, v/a + a/j = 0.15 s accel, 0.035 m cruise at 0.1 m/s
    assert p.duration == pytest.approx(0.15 + 0.35 + 0.15, rel=1e-12)
    rows = run(p)
    assert max(abs(r['v']) for r in rows) <= VMAX * (1 + REL)
    assert max(abs(r['a']) for r in rows) <= AMAX * (1 + REL)
    assert max(abs(r['a']) for r in rows) == pytest.approx(AMAX)
    # finite-difference jerk: the mean jerk over a tick can never exceed the limit
    assert max_step(rows, 'a') / T <= JMAX * (1 + 1e-6)
    assert p.position == 0.05 and p.at_target and not p.moving


# 3. Mid-move re-plan -------------------------------------------------------

def _assert_continuous(rows, i, jerk):
    """Step across the re-plan (rows[i-1] -> rows[i]) is within what the limits allow."""
    a, b = rows[i - 1], rows[i]
    assert abs(b['rp'] - a['rp']) <= VMAX * T * (1 + REL)
    assert abs(b['rv'] - a['rv']) <= AMAX * T * (1 + REL)
    if jerk:
        assert abs(b['ra'] - a['ra']) <= jerk * T * (1 + 1e-6)


@pytest.mark.parametrize('jerk', [JMAX, 0.0])
@pytest.mark.parametrize('new_target', [0.08, -0.02])
def test_replan_mid_move_is_continuous(jerk, new_target):
    p = make(jerk=jerk)
    p.move_to(0.05)
    # re-plan while accelerating (a != 0 matters for jerk continuity)
    before = run(p, until=lambda q: q.raw_velocity > 0.05)
    assert 0 < p.raw_acceleration
    p.move_to(new_target)
    assert p.target == new_target and not p.done
    after = run(p)
    rows = before + after
    i = len(before)
    _assert_continuous(rows, i, jerk)
    assert max_step(rows, 'rp') <= VMAX * T * (1 + REL)
    assert max_step(rows, 'rv') <= AMAX * T * (1 + REL)
    if jerk:
        assert max_step(rows, 'ra') / T <= jerk * (1 + 1e-6)
    assert max(abs(r['v']) for r in rows) <= VMAX * (1 + REL)
    assert max(abs(r['a']) for r in rows) <= AMAX * (1 + REL)
    assert p.position == new_target and p.at_target and not p.moving
    if new_target < 0:
        # it had to brake forward first, then come back
        assert max(r['p'] for r in after) > before[-1]['p']


def test_replan_after_lowering_limits_brakes_down_to_new_vmax():
    p = make(jerk=JMAX)
    p.move_to(0.1)
    run(p, until=lambda q: q.raw_velocity == pytest.approx(VMAX) and q.raw_acceleration == 0)
    p.configure(limits(0.05, AMAX, JMAX, 1.0), T)
    rows = run(p, until=lambda q: True) + run(p, until=lambda q: True)
    assert all(r['rv'] == pytest.approx(VMAX) for r in rows)  # no re-plan by itself
    p.move_to(0.1)                                            # re-plan from v > v_max
    rows += run(p)
    assert max_step(rows, 'ra') / T <= JMAX * (1 + 1e-6)
    assert max(abs(r['a']) for r in rows) <= AMAX * (1 + REL)
    late = [r for r in rows if r['t'] > 0.2]
    assert max(abs(r['v']) for r in late) <= 0.05 * (1 + REL)
    assert p.position == 0.1 and p.at_target


# 4. IT smoothing -----------------------------------------------------------

def _crossing_time(rows, key, level):
    for a, b in zip(rows, rows[1:]):
        if b[key] >= level > a[key]:
            return a['t'] + (level - a[key]) / (b[key] - a[key]) * (b['t'] - a['t'])
    raise AssertionError('level not crossed')


def test_it_smoothing_removes_acceleration_steps_and_lags_by_tau():
    it = 0.1
    tau = -T / math.log(1 - it)               # 9.49 ms
    p = make(jerk=0.0, smoothing=it)
    p.move_to(INCH)
    raw_duration = p.duration
    rows = run(p)
    # raw trapezoid steps its acceleration by a_max; smoothed one changes by <= IT*a_max per tick
    assert max_step(rows, 'ra') == pytest.approx(AMAX)
    assert max_step(rows, 'a') <= 0.1 * AMAX
    assert max_step(rows, 'v') <= AMAX * T * (1 + REL)
    assert max(abs(r['v']) for r in rows) <= VMAX * (1 + REL)
    # during cruise the command trails the raw profile by exactly v*tau (time shift tau)
    cruise = [r for r in rows if abs(r['t'] - 0.18) < T / 2][0]
    assert cruise['rp'] - cruise['p'] == pytest.approx(VMAX * tau, rel=1e-3)
    half = INCH / 2
    assert (_crossing_time(rows, 'p', half) - _crossing_time(rows, 'rp', half)
            == pytest.approx(tau, rel=1e-3))
    # exponential tail: within 1 um after ~4.5 tau, 1 nm after ~11.4 tau, exact
    # (snap below 1e-12 m) after ~18 tau; all well below the raw duration + 25 tau
    late_um = max(r['t'] for r in rows if abs(r['p'] - INCH) >= 1e-6) - raw_duration
    late_nm = max(r['t'] for r in rows if abs(r['p'] - INCH) >= 1e-9) - raw_duration
    assert 2 * tau < late_um < 6 * tau
    assert 8 * tau < late_nm < 14 * tau
    assert rows[-1]['t'] - raw_duration < 25 * tau
    # raw finished long before the command: still 'moving' meanwhile
    first_done = next(r for r in rows if r['done'])
    assert first_done['moving'] and first_done['at_target']
    assert p.position == INCH and p.velocity == 0.0 and p.acceleration == 0.0
    assert not p.moving


def test_smoothing_off_is_identical_to_raw():
    p = make(jerk=JMAX, smoothing=1.0)
    p.move_to(0.03)
    rows = run(p)
    for r in rows:
        assert (r['p'], r['v'], r['a']) == (r['rp'], r['rv'], r['ra'])
    assert rows[-1]['t'] == pytest.approx(p.duration, abs=1.5 * T)


# 5. Jog and stop -----------------------------------------------------------

def test_jog_reaches_velocity_and_jog_zero_brings_to_rest():
    p = make(jerk=JMAX)
    p.jog(-0.05)
    assert p.kind == 'velocity' and p.target_velocity == -0.05 and p.target is None
    rows = run(p, until=lambda q: q.done)
    assert p.raw_velocity == -0.05 and p.velocity == -0.05
    assert max(abs(r['a']) for r in rows) <= AMAX * (1 + REL)
    assert max_step(rows, 'a') / T <= JMAX * (1 + 1e-6)
    assert not any(r['at_target'] for r in rows)
    # constant speed: done, but the axis is still moving
    p0 = p.position
    for _ in range(100):
        p.step(T)
    assert p.done and p.moving and not p.at_target
    assert p.position - p0 == pytest.approx(-0.05 * 0.1, rel=1e-9)
    # beyond v_max it is clamped
    p.jog(1.0)
    assert p.target_velocity == VMAX
    rows = run(p, until=lambda q: q.done)
    assert max(abs(r['v']) for r in rows) <= VMAX * (1 + REL) and p.velocity == VMAX
    p.jog(0.0)
    rows = run(p)
    assert p.velocity == 0.0 and p.acceleration == 0.0 and p.done and not p.moving
    assert max(abs(r['a']) for r in rows) <= AMAX * (1 + REL)
    assert not any(r['at_target'] for r in rows)


@pytest.mark.parametrize('jerk', [JMAX, 0.0])
def test_stop_decelerates_at_given_rate_then_idle(jerk):
    p = make(jerk=jerk)
    p.jog(VMAX)
    run(p, until=lambda q: q.done)
    x0 = p.position
    dec = 0.5
    p.stop(dec)
    assert p.kind == 'stop' and p.target_velocity is None
    rows = run(p)
    assert max(abs(r['a']) for r in rows) <= dec * (1 + REL)
    assert all(r['kind'] == 'stop' for r in rows[:-1]) and p.kind == 'idle'
    assert p.velocity == 0.0 and p.acceleration == 0.0 and p.done and not p.moving
    # symmetric braking: distance = v * (v/dec + dec/j) / 2
    t_brake = VMAX / dec + (dec / jerk if jerk else 0.0)
    assert p.position - x0 == pytest.approx(VMAX * t_brake / 2, abs=1e-12)


def test_estop_during_move_may_exceed_max_acceleration_and_aborts_move():
    p = make(jerk=1000.0)
    p.move_to(0.05)
    run(p, until=lambda q: q.raw_position > 0.02)
    p.stop(5.0)                       # ESTOP harder than the move's a_max
    rows = run(p)
    assert max(abs(r['a']) for r in rows) == pytest.approx(5.0)
    assert max_step(rows, 'a') / T <= 1000.0 * (1 + 1e-6)
    assert p.kind == 'idle' and not p.at_target and p.position < 0.05
    assert p.target == 0.05           # last position move is still reported
    p.stop(5.0)                       # at rest already: straight back to idle
    assert p.kind == 'idle' and not p.moving


def test_a_stop_not_jerk_limited_is_a_ramp_at_its_rate_on_an_s_curve_profile():
    """ESTOP (jerk_limited=False) on a jerk-limited profile: the acceleration steps to the
    rate at once and the axis stops in v²/2d, not in the jerk-limited distance (at 20 m/s³
    and 5 m/s², v = 0.1 m/s: 1 mm against 13.5 mm); a stall's re-plan keeps it a ramp."""
    dec = 5.0
    for stall in (False, True):
        p = make(jerk=JMAX)
        p.jog(VMAX)
        run(p, until=lambda q: q.done)
        x0 = p.position
        p.stop(dec, jerk_limited=False)
        rows = run(p, until=lambda q: q.raw_velocity < 0.05)
        assert rows[0]['ra'] == pytest.approx(-dec)
        if stall:
            assert p.rebase(p.raw_position, p.raw_velocity)
        rows += run(p)
        assert p.kind == 'idle' and p.velocity == 0.0
        assert max(abs(r['a']) for r in rows) <= dec * (1 + REL)
        assert p.position - x0 == pytest.approx(VMAX ** 2 / (2 * dec), abs=1e-9)


def test_hold_resets_to_rest():
    p = make(jerk=JMAX, smoothing=0.1)
    p.move_to(0.05)
    run(p, until=lambda q: q.raw_position > 0.02)
    p.hold(0.3)
    assert (p.position, p.velocity, p.acceleration) == (0.3, 0.0, 0.0)
    assert (p.raw_position, p.raw_velocity, p.raw_acceleration) == (0.3, 0.0, 0.0)
    assert p.kind == 'idle' and p.done and not p.moving and not p.at_target
    p.step(T)
    assert p.position == 0.3 and not p.moving


# 6. Invalid input ----------------------------------------------------------

@pytest.mark.parametrize('call', [
    lambda p: p.move_to(float('nan')),
    lambda p: p.move_to(float('inf')),
    lambda p: p.move_to(1e20),                 # finite but ruckig fails: its error -> ValueError
    lambda p: p.jog(float('nan')),
    lambda p: p.jog(-float('inf')),
    lambda p: p.stop(0.0),
    lambda p: p.stop(float('nan')),
    lambda p: p.hold(float('nan')),
    lambda p: p.step(float('nan')),
    lambda p: p.step(-T),
    lambda p: p.configure(limits(0.0, AMAX, JMAX, 1.0), T),
    lambda p: p.configure(limits(VMAX, -1.0, JMAX, 1.0), T),
    lambda p: p.configure(limits(VMAX, AMAX, -1.0, 1.0), T),
    lambda p: p.configure(limits(VMAX, AMAX, float('nan'), 1.0), T),
    lambda p: p.configure(limits(float('inf'), AMAX, JMAX, 1.0), T),
    lambda p: p.configure(limits(VMAX, AMAX, JMAX, 0.003), T),
    lambda p: p.configure(limits(VMAX, AMAX, JMAX, 1.5), T),
    lambda p: p.configure(limits(VMAX, AMAX, JMAX, 1.0), 0.0),
])
def test_invalid_input_raises_and_changes_nothing(call):
    p = make(jerk=JMAX, smoothing=0.5)
    p.move_to(0.05)
    run(p, until=lambda q: q.raw_position > 0.02)
    state = snap(p)
    limits = (p.max_velocity, p.max_acceleration, p.max_jerk, p.smoothing, p.servo_period)
    with pytest.raises(ValueError):
        call(p)
    assert snap(p) == state
    assert (p.max_velocity, p.max_acceleration, p.max_jerk,
            p.smoothing, p.servo_period) == limits
    run(p)                                   # keeps going to the old target
    assert p.position == 0.05 and p.at_target


def test_a_new_profile_runs_the_tables_limits():
    p = Profile(0.1)
    assert (p.max_velocity, p.max_acceleration, p.max_jerk, p.smoothing) == (
        CONTROLLER_AXIS['max_velocity'].default, CONTROLLER_AXIS['max_acceleration'].default,
        CONTROLLER_AXIS['max_jerk'].default, CONTROLLER_AXIS['smoothing'].default)
    p.stop(1.0)                              # STOP/ESTOP always work
    assert p.kind == 'idle' and p.position == 0.1


# 7. Variable dt ------------------------------------------------------------

@pytest.mark.parametrize('smoothing', [1.0, 0.1])
def test_variable_dt_follows_same_path_and_ends_exactly(smoothing):
    ref = make(jerk=JMAX, smoothing=smoothing)
    var = make(jerk=JMAX, smoothing=smoothing)
    ref.move_to(INCH)
    var.move_to(INCH)
    k = 0
    while ref.moving or var.moving:
        ref.step(T)
        ref.step(T)
        var.step(0.5 * T)
        var.step(1.5 * T)
        k += 1
        assert k < 5000
        # same instants every 2 ms: same raw profile
        assert var.raw_position == pytest.approx(ref.raw_position, abs=1e-12)
        assert var.raw_velocity == pytest.approx(ref.raw_velocity, abs=1e-9)
        # smoothing integrated exactly for linear input: only second-order error
        assert var.position == pytest.approx(ref.position, abs=1e-6)
    assert var.position == INCH and var.at_target
    assert ref.position == INCH and ref.at_target


@pytest.mark.parametrize('jerk', [0.0, JMAX], ids=['trapezoid', 'jerk-limited'])
@pytest.mark.parametrize('fast', [1.0, 1.1, 1.4])
def test_a_re_plan_after_a_stall_never_passes_the_target(jerk, fast):
    """rebase (the catch-up rule after a stall) from a measured state late in the deceleration:
    32 counts behind the command, moving `fast` x its speed (a speed from counts over a late
    sample reads high). The new plan stops at the target without passing it. Planned from that
    speed as measured, on the slide's registers (1.5 m/s²), the command overran the target by
    76 counts at 1.1 x and 460 at 1.4 x; the demo over DDS once ended a move 40 counts past its
    target so."""
    count = 2.54e-6
    p = make(jerk)
    p.move_to(INCH)
    while INCH - p.position > 512 * count:
        p.step(T)
    assert p.rebase(p.position - 32 * count, p.velocity * fast)
    furthest = p.position
    for _ in range(2000):
        p.step(T)
        furthest = max(furthest, p.position)
    assert furthest <= INCH + 1e-12, f'{(furthest - INCH) / count:+.2f} counts past'
    assert p.position == INCH and p.velocity == 0.0
