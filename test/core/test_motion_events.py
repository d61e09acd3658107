"""Moves, smoothing, stops and settling events of a whole axis, in the loop (harness, default
slide): the status word as RMP defines it (seed 004), Galil IT smoothing (seed 001), STOP / ESTOP
/ ABORT, on-the-fly re-planning, refused commands and soft limits.

The unit tests of the pieces are test_profile.py and test_settling.py; here every assertion is
made on what the axis did: `Axis.events`, the harness trace and, where the trace has no column
for it, a per-tick record taken in the harness' tick callback (the values of that very update).
"""
import math

import numpy as np
import pytest

from kit import COUNT
from msg_defs.status import Status
from motion_ctrl.core.soft_limits import stopping_distance
from motion_ctrl.sim.harness import Harness
from motion_ctrl.core.profile import Profile
from motion_ctrl.core.registers import INCH, axis_defaults
from motion_ctrl.core.config import ProfileConfig

S = Status
T = 1e-3
DEFAULTS = axis_defaults()
FINE = DEFAULTS['fine_position_tolerance']
VEL_TOL = DEFAULTS['velocity_tolerance']
A_MAX = DEFAULTS['max_acceleration']
V_MAX = DEFAULTS['max_velocity']
SETTLE = 0.05                  # settling_time used here: 50 servo ticks, easy to see in a trace
TICK_EPS = 1e-9                # times are sums of 1 ms steps: equal within this


class Recorder:
    """Per-tick values the trace has no column for, taken right after each update."""

    def __init__(self, h: Harness):
        self.h = h
        self.t: list[float] = []
        self.word: list[int] = []
        self.cmd: list[float] = []
        self.cmd_vel: list[float] = []
        self.cmd_acc: list[float] = []
        self.act: list[float] = []
        self.act_vel: list[float] = []
        self.done: list[bool] = []
        self.settle_start: list[float | None] = []

    def __call__(self, h):
        a, p = h.axis, h.axis.profile
        self.t.append(h.time)
        self.word.append(int(a.status))
        self.cmd.append(p.position)
        self.cmd_vel.append(p.velocity)
        self.cmd_acc.append(p.acceleration)
        self.act.append(a.actual_pos)
        self.act_vel.append(a.actual_vel)
        self.done.append(p.done)
        self.settle_start.append(a.settling.settle_start)

    def run(self, seconds, until=None, disturbance=None):
        """Harness.run, recording after each tick (and the disturbance first)."""
        def each(h):
            if disturbance is not None:
                disturbance(h)
            self(h)
        return self.h.run(seconds, until, each)


def done(h):
    return bool(h.axis.status & S.MOTION_DONE)


def first(words, bit, start=0):
    """Index of the first word from `start` with `bit` set (None if never)."""
    return next((i for i in range(start, len(words)) if words[i] & bit), None)


def first_event(events, bit, after=-1.0):
    """Time of the first Axis.events entry after `after` with `bit` set."""
    return next((t for t, w in events if t > after + TICK_EPS and w & bit), None)


def run_start(crit, k):
    """First index of the unbroken run of True in `crit` that ends at index k."""
    assert crit[k]
    while k > 0 and crit[k - 1]:
        k -= 1
    return k


def assert_braking_ramp(a, decel, duration):
    """Second differences `a` of a braking command: a straight-line velocity ramp at -decel
    lasting `duration` (all but its partial first and last ticks exactly -decel), no harder
    braking anywhere, no acceleration. Returns the ramp values."""
    ramp = a[np.abs(a + decel) < 1e-6 * decel]
    assert len(ramp) >= round(duration / T) - 2
    assert a.min() >= -decel * (1 + 1e-6) and a.max() <= 1e-6
    return ramp


def derivatives(x):
    """Velocity, acceleration and jerk of a 1 kHz position trace by finite differences."""
    v = np.diff(np.asarray(x)) / T
    a = np.diff(v) / T
    return v, a, np.diff(a) / T


# 1. ---------------------------------------------------------------- position move events
@pytest.mark.parametrize('coarse, coarse_before_at_target', [
    (2 * COUNT, False),      # two linear counts: the slide gets there after the command
    (1e-3, True),              # 1 mm: near the target while the command still decelerates
])
def test_position_move_event_order_and_settling_time(coarse, coarse_before_at_target):
    h = Harness(dict(settling_time=SETTLE, coarse_position_tolerance=coarse))
    rec = Recorder(h)
    n0 = len(h.axis.events)
    assert h.axis.move_to(INCH) == (True, '')
    assert rec.run(2.0, until=done)
    events = h.axis.events[n0:]
    t0 = events[0][0]

    # Axis.events: MOVING first (MOTION_DONE of the idle axis cleared with it) ...
    assert events[0][1] & S.MOVING and not events[0][1] & S.MOTION_DONE
    assert abs(t0 - T) < TICK_EPS                         # on the first tick of the move
    t_at = first_event(events, S.AT_TARGET)
    t_coarse = first_event(events, S.IN_COARSE_POSITION)
    t_fine = first_event(events, S.IN_FINE_POSITION)
    t_done = first_event(events, S.MOTION_DONE)
    # ... AT_TARGET and IN_COARSE_POSITION in the order the coarse tolerance makes them ...
    assert t0 < min(t_at, t_coarse)
    assert (t_coarse < t_at) == coarse_before_at_target
    # ... before IN_FINE_POSITION, then MOTION_DONE (RMP: raised with the first SETTLED)
    assert max(t_at, t_coarse) < t_fine <= t_done
    # MOVING drops exactly when the command reaches the target
    w_at = next(w for t, w in events if abs(t - t_at) < TICK_EPS)
    assert not w_at & S.MOVING
    assert all(w & S.MOVING for t, w in events if t < t_at - TICK_EPS)
    assert not any(w & (S.MOTION_AT_VELOCITY | S.STOPPED | S.ESTOPPED | S.ABORTED | S.LIMIT)
                   for _, w in events)

    # The trace says the same, tick by tick.
    words = h.trace.status
    k_done = first(words, S.MOTION_DONE)
    assert abs(h.trace.t[k_done] - t_done) < TICK_EPS
    assert first(words, S.IN_FINE_POSITION) == k_done

    # Settling criteria from what the axis measured: command == target, |error| <= fine,
    # |velocity| <= velocity tolerance. MOTION_DONE comes exactly settling_time after the
    # unbroken run that ends in it began, and never sooner after the criteria first held.
    crit = [c == INCH and abs(INCH - x) <= FINE and abs(v) <= VEL_TOL
            for c, x, v in zip(rec.cmd, rec.act, rec.act_vel)]
    k_first = crit.index(True)
    k_run = run_start(crit, k_done)
    assert rec.t[k_done] - rec.t[k_run] == pytest.approx(SETTLE, abs=TICK_EPS)
    assert rec.t[k_done] - rec.t[k_first] >= SETTLE - TICK_EPS
    # and it is the first run that held that long
    k = k_first
    while k < k_run:
        if crit[k]:
            end = k
            while crit[end + 1]:
                end += 1
            assert rec.t[end] - rec.t[k] < SETTLE - TICK_EPS
            k = end + 1
        else:
            k += 1
    assert abs(h.plant.x_l - INCH) * h.plant.load_counts_per_m < 1.0


def test_a_move_shorter_than_a_tick_shows_no_moving_but_clears_motion_done():
    """A fifth of a count after a settled move, on a tick that came 2 ms late (as a loaded machine
    skips one): the profile starts and ends within that tick, so no status word shows MOVING.
    MOTION_DONE still falls on that tick and rises again once settled: the event a client waits
    on (SlideClient.move_done)."""
    h = Harness(DEFAULTS)
    assert h.move(INCH) is not None
    step = DEFAULTS['fine_position_tolerance'] / 3          # 0.5 um, a fifth of a count
    assert h.axis.move_to(INCH + step) == (True, '')
    m, l = h.plant.encoder_counts()
    h.axis.update(2 * T, m, l)                               # the late tick
    assert h.axis.profile.done and h.axis.profile.position == INCH + step
    assert not h.axis.status & (S.MOVING | S.MOTION_DONE)
    rec = Recorder(h)
    assert rec.run(1.0, until=done)
    assert not any(w & S.MOVING for w in rec.word)


@pytest.mark.core_slow
def test_disturbance_during_settling_restarts_the_timer():
    """The same move twice: undisturbed, then shoved back 4 µm (motor and slide together, over
    5 ticks) half-way through the settling time. MOTION_DONE then comes a full settling time
    after the slide is back within the criteria, never sooner than settling_time after the
    disturbance ended."""
    regs = dict(settling_time=SETTLE)
    ref = Harness(regs)
    ref.axis.move_to(INCH)
    assert ref.run(2.0, until=done)
    t_done_ref = first_event(ref.axis.events, S.MOTION_DONE, after=0.0)
    t_run_ref = ref.axis.settling.settle_start
    assert t_done_ref - t_run_ref == pytest.approx(SETTLE, abs=TICK_EPS)

    h = Harness(regs)
    rec = Recorder(h)
    h.axis.move_to(INCH)
    rec.run(2.0, until=lambda h: h.time >= t_run_ref + SETTLE / 2 - TICK_EPS)
    assert h.axis.settling.settle_start == pytest.approx(t_run_ref, abs=TICK_EPS)  # timing
    assert not h.axis.status & (S.MOTION_DONE | S.IN_FINE_POSITION)
    t_shove = h.time

    def shove(h):
        h.plant.x_m -= 0.8e-6
        h.plant.x_l -= 0.8e-6

    rec.run(0.005, disturbance=shove)
    t_end = h.time                                   # the disturbance ended on this tick
    assert t_end - t_shove == pytest.approx(0.005, abs=TICK_EPS)
    assert rec.run(2.0, until=done)
    t_done = first_event(h.axis.events, S.MOTION_DONE, after=0.0)
    t_restart = h.axis.settling.settle_start
    # the timer was reset by the disturbance and restarted once the criteria held again
    assert t_restart > t_end
    assert t_done - t_restart == pytest.approx(SETTLE, abs=TICK_EPS)
    assert t_done >= t_end + SETTLE - TICK_EPS
    assert t_done > t_done_ref + SETTLE / 2
    # in between, the criteria broke: SETTLED was never reported before t_done
    k_shove = next(i for i, t in enumerate(rec.t) if t > t_shove + TICK_EPS)
    k_done = next(i for i, t in enumerate(rec.t) if abs(t - t_done) < TICK_EPS)
    assert any(abs(INCH - x) > FINE for x in rec.act[k_shove:k_done])
    assert not any(w & (S.IN_FINE_POSITION | S.MOTION_DONE) for w in rec.word[:k_done])
    test_disturbance_during_settling_restarts_the_timer.figures = dict(
        ref_done=t_done_ref, shove=(t_shove, t_end), restart=t_restart, done=t_done)


# 2. ---------------------------------------------------------------- jog, STOP, ESTOP, ABORT
@pytest.mark.parametrize('kind, bit, decel', [
    ('stop', S.STOPPED, DEFAULTS['stop_deceleration']),
    ('estop', S.ESTOPPED, DEFAULTS['estop_deceleration'])])
def test_jog_at_velocity_then_stop_or_estop(kind, bit, decel):
    v_jog = 0.08
    h = Harness(dict(settling_time=SETTLE))
    rec = Recorder(h)
    assert h.axis.jog(v_jog) == (True, '')
    rec.run(0.25)
    words = rec.word
    k_atv = first(words, S.MOTION_AT_VELOCITY)
    assert k_atv is not None
    # at velocity = profile at its constant velocity and |v - v_jog| <= tolerance, held for
    # settling_time: reported exactly then
    crit = [d and abs(v - v_jog) <= VEL_TOL for d, v in zip(rec.done, rec.act_vel)]
    k_run = run_start(crit, k_atv)
    assert rec.t[k_atv] - rec.t[k_run] == pytest.approx(SETTLE, abs=TICK_EPS)
    assert not any(crit[k] and rec.t[k] - rec.t[run_start(crit, k)] >= SETTLE - TICK_EPS
                   for k in range(k_atv))
    assert rec.t[k_run] >= v_jog / A_MAX - T               # not before the ramp ended
    assert all(w & S.MOVING for w in words)
    assert not any(w & (S.AT_TARGET | S.MOTION_DONE | S.IN_FINE_POSITION) for w in words)
    assert all(w & S.MOTION_AT_VELOCITY for w in words[k_atv:])

    k0 = len(h.trace.t)
    assert h.axis.stop(kind) == (True, '')
    assert rec.run(0.5, until=done)
    h.run(0.005)                                            # a few ticks at rest
    words = h.trace.status
    k_end = first(words, S.MOTION_DONE, k0)
    # The commanded velocity from the trace falls at the stop rate, in a straight line.
    v, a, _ = derivatives(h.trace.command[k0 - 2:k_end + 3])
    assert v[0] == pytest.approx(v_jog, rel=1e-9)
    assert v[-1] == 0.0
    ramp = assert_braking_ramp(a, decel, v_jog / decel)
    stop_time = k_end - k0 + 1                              # ticks from the stop to rest
    assert stop_time * T == pytest.approx(v_jog / decel, abs=1.01 * T)
    # It ends STOPPED (ESTOPPED) + MOTION_DONE, still enabled, MOVING gone on the same tick.
    w = words[k_end]
    assert w & bit and w & S.MOTION_DONE and w & S.ENABLED
    assert not w & (S.MOVING | S.AT_TARGET | S.MOTION_AT_VELOCITY | S.ABORTED)
    assert all(x & S.MOVING and not x & (S.MOTION_DONE | bit) for x in words[k0:k_end])
    test_jog_at_velocity_then_stop_or_estop.figures = getattr(
        test_jog_at_velocity_then_stop_or_estop, 'figures', {})
    test_jog_at_velocity_then_stop_or_estop.figures[kind] = dict(
        at_velocity_ms=rec.t[k_atv] * 1e3, settled_from_ms=rec.t[k_run] * 1e3,
        decel=float(-np.median(ramp)), stop_ms=stop_time)


def test_jog_beyond_max_velocity_is_refused_and_jog_zero_comes_to_rest():
    """jog(1 m/s) is refused naming max_velocity (Galil refuses an out-of-range SP) and changes
    nothing; jog(max_velocity) reaches MOTION_AT_VELOCITY; jog(0) brakes at max_acceleration and
    gives MOTION_DONE a settling time after the command is at rest and |v| <= tolerance, without
    STOPPED."""
    h = Harness(dict(settling_time=SETTLE))
    rec = Recorder(h)
    word = h.axis.status
    ok, reason = h.axis.jog(1.0)
    assert not ok and 'max_velocity' in reason, reason
    assert h.axis.status == word and not h.axis.profile.moving
    assert h.axis.jog(-V_MAX * 1.001)[0] is False
    assert h.axis.jog(V_MAX) == (True, '')
    assert rec.run(0.3, until=lambda h: h.axis.status & S.MOTION_AT_VELOCITY)
    assert max(rec.cmd_vel) == V_MAX
    k0 = len(rec.t)
    assert h.axis.jog(0.0) == (True, '')
    assert rec.run(0.5, until=done)
    v, a, _ = derivatives(h.trace.command[k0 - 2:])
    assert_braking_ramp(a, A_MAX, V_MAX / A_MAX)
    k_done = len(rec.t) - 1
    crit = [not (vc != 0.0 or not d) and abs(va) <= VEL_TOL
            for vc, d, va in zip(rec.cmd_vel, rec.done, rec.act_vel)]
    assert rec.t[k_done] - rec.t[run_start(crit, k_done)] == pytest.approx(SETTLE, abs=TICK_EPS)
    w = h.axis.status
    assert w == S.ENABLED | S.MOTION_DONE                 # no STOPPED: nobody pressed stop
    assert all(x & S.MOVING for x in rec.word[k0:k0 + int(V_MAX / A_MAX / T)])   # braking


def test_abort_opens_the_loop_at_once_and_reset_enable_close_it():
    h = Harness()
    h.axis.jog(0.05)
    h.run(0.1)
    assert h.trace.output[-1] != 0.0
    t_abort = h.axis.time
    assert h.axis.abort() == (True, '')
    # ENABLED is gone and ABORTED + MOTION_DONE are there before the next tick
    word = h.axis.status
    assert not word & S.ENABLED and word & S.ABORTED and word & S.MOTION_DONE
    assert h.axis.events[-1] == (t_abort, word)
    assert h.axis.output == 0.0
    k0 = len(h.trace.t)
    h.tick()
    assert h.trace.output[k0] == 0.0                       # exactly 0 on the very next update
    h.run(0.05)
    assert all(out == 0.0 for out in h.trace.output[k0:])
    assert h.plant.x_l > h.trace.load[k0] + 1e-4            # nothing holds it: it coasts
    assert h.trace.command[-1] == h.trace.actual[-1]         # the command follows (bumpless)
    assert all(w == S.ABORTED | S.MOTION_DONE for w in h.trace.status[k0:])
    for refused in (h.axis.move_to(0.0), h.axis.jog(0.01), h.axis.stop(), h.axis.correct()):
        assert refused[0] is False and 'not enabled' in refused[1]
    # reset clears ABORTED, the loop stays open; enable closes it where the slide is
    assert h.axis.reset() == (True, '')
    assert h.axis.status == S.MOTION_DONE
    h.run(0.01)
    assert not h.axis.status & S.ENABLED
    assert h.axis.enable(True) == (True, '')
    h.run(0.05)
    assert h.axis.status & S.ENABLED and h.axis.status & S.MOTION_DONE
    assert not h.axis.status & S.ABORTED


@pytest.mark.core_slow
def test_correct_on_demand_with_motor_feedback_lands_the_slide():
    """<axis>/correct with feedback motor (Galil #CORRECT run by hand): after the reversal the
    slide misses by the backlash (~20 counts); one correction sequence, CORRECTING and MOVING
    while it runs, brings it within a count and ends in MOTION_DONE. The next move plans
    without corrections (no CORRECTING), as feedback motor does."""
    h = Harness(DEFAULTS | {'feedback': 'motor'})
    assert h.move(2 * INCH) is not None and h.move(INCH) is not None
    assert h.load_error_counts(INCH) > 15.0                  # the backlash, uncorrected
    assert h.axis.correct() == (True, '')
    rec = Recorder(h)
    assert rec.run(3.0, until=lambda h: h.axis.status & S.MOTION_DONE
                   and not h.axis.status & S.CORRECTING)
    assert any(w & S.CORRECTING and w & S.MOVING and not w & S.MOTION_DONE for w in rec.word)
    assert 1 <= h.axis.correction_moves <= 5
    assert abs(h.load_error_counts(INCH)) <= 1.0
    rec = Recorder(h)
    h.axis.move_to(2 * INCH)
    assert rec.run(3.0, until=done)
    assert not any(w & S.CORRECTING for w in rec.word)


def test_a_feedback_change_ends_a_correction_with_motion_done():
    """feedback changed (at the next tick) while x/correct runs: the command holds where the
    motor is and nothing is pending, so the axis reports MOTION_DONE (it used to wait for good
    on the abandoned correction's settling)."""
    h = Harness(DEFAULTS | {'feedback': 'motor'})
    assert h.move(2 * INCH) is not None and h.move(INCH) is not None
    assert h.axis.correct() == (True, '')
    h.tick()
    assert h.axis.status & S.CORRECTING
    h.axis.configure(DEFAULTS | {'feedback': 'dual'})
    h.run(0.1)
    w = h.axis.status
    assert w & S.MOTION_DONE and not w & (S.CORRECTING | S.MOVING), repr(w)


@pytest.mark.parametrize('feedback', ['dual', 'load'])
def test_correct_refused_where_the_loop_closes_on_the_load_encoder(feedback):
    """feedback dual or load has nothing to correct: refused with the reason, the status word
    untouched (before the fix it showed CORRECTING and MOVING for good)."""
    h = Harness(DEFAULTS | {'feedback': feedback})
    h.run(0.05)
    word = h.axis.status
    ok, reason = h.axis.correct()
    assert not ok and f'feedback {feedback}' in reason and 'load encoder' in reason
    h.run(0.5)
    assert h.axis.status == word and not word & (S.CORRECTING | S.MOVING)


def test_fatal_following_error_aborts_reset_clears_it():
    h = Harness(dict(following_error_fatal=10e-6, following_error_warning=0.0))
    h.axis.move_to(0.01)
    h.run(0.2)
    word = h.axis.status
    assert word == S.FOLLOWING_ERROR_FATAL | S.ABORTED | S.MOTION_DONE
    k = first(h.trace.status, S.FOLLOWING_ERROR_FATAL)
    assert h.trace.status[k] == word                       # all together on the fatal tick
    assert h.trace.output[k] == 0.0
    ok, reason = h.axis.enable(True)
    assert not ok and 'reset' in reason
    h.run(0.3)                                             # the slide coasts to rest
    assert h.plant.v_m == 0.0 and h.plant.v_l == 0.0
    assert h.axis.reset() == (True, '')
    assert h.axis.status == S.MOTION_DONE                  # cleared; loop still open
    assert h.axis.enable(True) == (True, '')
    h.tick()
    assert h.axis.status & S.ENABLED and not h.axis.status & (S.ABORTED | S.FOLLOWING_ERROR_FATAL)


def test_disable_reports_motion_done_and_enable_is_bumpless():
    h = Harness()
    h.run(0.01)
    assert h.axis.enable(False) == (True, '')
    assert h.axis.status == S.MOTION_DONE                  # open loop, nothing being moved
    h.run(0.01)
    assert h.trace.output[-1] == 0.0
    assert h.axis.enable(True) == (True, '')
    h.run(0.05)
    assert h.axis.status == S.ENABLED | S.MOTION_DONE
    assert max(abs(o) for o in h.trace.output[-50:]) < 1.0


# 3. ---------------------------------------------------------------- Galil IT smoothing
def _move_with_smoothing(smoothing, distance=INCH):
    h = Harness(dict(smoothing=smoothing))
    rec = Recorder(h)
    h.axis.move_to(distance)
    assert rec.run(1.5, until=lambda h: h.axis.status & S.AT_TARGET)
    return h, rec


def _crossing(t, x, level):
    """Time at which x first crosses level (linear interpolation between samples)."""
    k = next(i for i, v in enumerate(x) if v >= level)
    return t[k - 1] + (level - x[k - 1]) / (x[k] - x[k - 1]) * (t[k] - t[k - 1])


def test_it_smoothing_in_the_loop():
    it = 0.1
    tau = -T / math.log1p(-it)                               # 9.49 ms
    plain_h, plain = _move_with_smoothing(1.0)
    smooth_h, smooth = _move_with_smoothing(it)

    # smoothing = 1: the command is the ruckig trapezoid itself, acceleration steps of a_max
    ref = Profile(0.0)
    ref.configure(ProfileConfig.of(dict(max_velocity=V_MAX, max_acceleration=A_MAX,
                                        max_jerk=0.0, smoothing=1.0)), T)
    ref.move_to(INCH)
    raw = []
    for _ in plain.t:
        ref.step(T)
        raw.append(ref.position)
    assert plain_h.trace.command == raw
    assert len(plain.t) == math.ceil(ref.duration / T - 1e-9)       # AT_TARGET when it ends
    assert max(abs(d) for d in np.diff(plain.cmd_acc)) == pytest.approx(A_MAX)

    # smoothing < 1: no acceleration step, in the profile's output and in the trace
    step_bound = A_MAX * (1 - math.exp(-T / tau))                      # 0.15 m/s² per tick
    assert np.abs(np.diff([0.0] + smooth.cmd_acc)).max() <= step_bound * (1 + 1e-9)
    _, a_trace, _ = derivatives([0.0] + smooth_h.trace.command)
    assert np.abs(np.diff(np.concatenate(([0.0], a_trace)))).max() < 1.1 * step_bound
    _, a_plain, _ = derivatives([0.0] + plain_h.trace.command)
    assert np.abs(np.diff(a_plain)).max() > 0.5 * A_MAX   # the trapezoid's steps (split in
    #                                                        two where not on a tick)
    assert np.abs(smooth.cmd_acc).max() <= A_MAX                      # never beyond the limit

    # The move takes longer by about tau: the command passes mid-way tau later, and its mean
    # delay (integral of raw - smoothed over the distance) is tau.
    t_mid_plain = _crossing(plain.t, plain_h.trace.command, INCH / 2)
    t_mid_smooth = _crossing(smooth.t, smooth_h.trace.command, INCH / 2)
    assert t_mid_smooth - t_mid_plain == pytest.approx(tau, abs=0.02 * tau)
    n = len(smooth.t)
    raw_padded = raw + [INCH] * (n - len(raw))
    mean_delay = T * sum(r - c for r, c in zip(raw_padded, smooth_h.trace.command)) / INCH
    assert mean_delay == pytest.approx(tau, rel=0.01)
    # within one linear count of the target: later by a few tau (exponential tail)
    count = 1 / smooth_h.plant.load_counts_per_m
    t_in_plain = next(t for t, c in zip(plain.t, plain.cmd) if INCH - c < count)
    t_in_smooth = next(t for t, c in zip(smooth.t, smooth.cmd) if INCH - c < count)
    assert tau < t_in_smooth - t_in_plain < 6 * tau
    test_it_smoothing_in_the_loop.figures = dict(
        tau_ms=tau * 1e3, mid_delay_ms=(t_mid_smooth - t_mid_plain) * 1e3,
        mean_delay_ms=mean_delay * 1e3, within_count_delay_ms=(t_in_smooth - t_in_plain) * 1e3,
        at_target_ms=(plain.t[-1] * 1e3, smooth.t[-1] * 1e3),
        max_da_per_tick=float(np.abs(np.diff([0.0] + smooth.cmd_acc)).max()))


# 4. ---------------------------------------------------------------- re-plan on the fly
@pytest.mark.parametrize('jerk', [0.0, 40.0])
@pytest.mark.parametrize('new_target', [
    0.002,     # at speed, back behind the axis: brake, turn round
    0.03,      # while braking for 0.02: accelerate again and go on
])
def test_replan_mid_move_through_move_to_is_continuous(jerk, new_target):
    h = Harness(dict(max_jerk=jerk))
    rec = Recorder(h)
    h.axis.move_to(0.02)
    if new_target < 0.02:
        rec.run(0.08)
    else:
        assert rec.run(0.5, until=lambda h: h.axis.profile.acceleration < -0.5 * A_MAX)
    assert h.axis.status & S.MOVING and abs(h.axis.profile.velocity) > 0.05
    k0 = len(h.trace.t)
    assert h.axis.move_to(new_target) == (True, '')
    assert rec.run(1.0, until=lambda h: h.axis.status & S.AT_TARGET)
    c = [0.0] + h.trace.command
    v, a, j = derivatives(c)
    assert np.abs(v).max() <= V_MAX * (1 + 1e-9)
    assert np.abs(np.diff(v)).max() <= A_MAX * T * (1 + 1e-6)          # velocity: no step
    if jerk:
        assert np.abs(np.diff(a)).max() <= jerk * T * (1 + 1e-6)      # acceleration: no step
        assert np.abs(np.diff(rec.cmd_acc)).max() <= jerk * T * (1 + 1e-6)
    # around the re-plan tick in particular (velocity and acceleration of the profile)
    assert abs(rec.cmd_vel[k0] - rec.cmd_vel[k0 - 1]) <= A_MAX * T * (1 + 1e-6)
    assert h.trace.command[-1] == new_target
    words = h.trace.status
    assert all(w & S.MOVING for w in words[:-1])              # one move, re-targeted
    assert first(words, S.AT_TARGET) == len(words) - 1
    if new_target < 0.02:
        assert min(rec.cmd_vel) < 0.0                        # it turned round


# 5. ---------------------------------------------------------------- refused commands
NOT_NUMBERS = [math.nan, math.inf, -math.inf, None, '0.01', True]


def test_bad_and_out_of_limit_targets_are_refused_and_do_not_disturb_a_move():
    target = 0.01
    ref = Harness()
    ref.axis.move_to(target)
    ref.run(0.5)

    h = Harness()
    h.axis.move_to(target)
    h.run(0.05)
    word = h.axis.status
    for bad in NOT_NUMBERS:
        ok, reason = h.axis.move_to(bad)
        assert not ok and 'not a finite number' in reason and reason.startswith('x:'), reason
        ok, reason = h.axis.jog(bad)
        assert not ok and 'not a finite number' in reason, reason
        assert h.axis.status == word                         # no LIMIT for these
    lo, hi = DEFAULTS['soft_limit_min'], DEFAULTS['soft_limit_max']
    for outside in (hi + 0.1, lo - 0.1, math.nextafter(hi, math.inf)):
        ok, reason = h.axis.move_to(outside)
        assert not ok and 'soft limits' in reason, reason
        assert h.axis.status == word | S.LIMIT               # raised at once
    h.run(0.45)
    # the move went on exactly as if nothing had been sent
    assert h.trace.command == ref.trace.command
    assert h.trace.output == ref.trace.output
    assert h.trace.command[-1] == target
    assert all(w & S.LIMIT for w in h.trace.status[50:])
    assert [w & ~S.LIMIT for w in h.trace.status] == ref.trace.status
    # a target on the limit itself is fine, and an accepted move clears LIMIT
    assert h.axis.move_to(hi) == (True, '')
    h.tick()
    assert not h.axis.status & S.LIMIT


def test_refused_target_on_an_idle_axis_starts_nothing():
    h = Harness()
    h.run(0.01)
    ok, reason = h.axis.move_to(0.75)
    assert not ok and '0.75' in reason
    h.run(0.05)
    assert not any(w & S.MOVING for w in h.trace.status)
    assert all(c == 0.0 for c in h.trace.command)
    assert h.axis.status == S.ENABLED | S.MOTION_DONE | S.LIMIT


@pytest.mark.parametrize('jerk', [0.0, 40.0])
@pytest.mark.parametrize('sign', [1, -1])
def test_jog_toward_a_soft_limit_stops_at_it(sign, jerk):
    """The jog cruises, then turns into a move that brakes at max_acceleration and stops with
    the command exactly on the limit (LIMIT raised); a further jog that way is refused, one
    the other way is accepted and clears LIMIT."""
    limit = 0.02
    v_jog = 0.08
    h = Harness(dict(soft_limit_min=-limit, soft_limit_max=limit, max_jerk=jerk,
                     settling_time=0.005))
    rec = Recorder(h)
    assert h.axis.jog(sign * v_jog) == (True, '')
    rec.run(0.6, until=lambda h: h.axis.status & S.AT_TARGET)
    c = np.array(h.trace.command) * sign
    assert c.max() <= limit                                  # never past it
    assert c[-1] == limit and h.axis.profile.raw_position == sign * limit
    words = h.trace.status
    k_atv, k_lim, k_at = (first(words, b) for b in
                          (S.MOTION_AT_VELOCITY, S.LIMIT, S.AT_TARGET))
    assert k_atv < k_lim < k_at
    assert all(w & S.LIMIT for w in words[k_lim:])
    assert not any(w & S.MOTION_AT_VELOCITY for w in words[k_lim:])
    # where it turned: the distance left was what braking needs, within a few ticks of travel
    left = limit - sign * rec.cmd[k_lim - 1]
    need = stopping_distance(v_jog, 0.0, A_MAX, jerk)
    assert need <= left <= need + 3 * v_jog * T
    # it braked at max_acceleration (jerk-limited: no faster), from the jog velocity
    v, a, _ = derivatives(h.trace.command)
    brake = sign * a[k_lim:]
    assert brake.min() >= -A_MAX * (1 + 1e-6)
    if not jerk:
        assert np.median(brake[brake < -1e-6]) == pytest.approx(-A_MAX, rel=1e-6)
    assert np.abs(v).max() <= v_jog * (1 + 1e-9)
    # at the limit: position-move events, then MOTION_DONE there
    assert rec.run(2.0, until=done)
    assert h.axis.status & S.LIMIT and h.axis.target == sign * limit
    ok, reason = h.axis.jog(sign * 0.01)
    assert not ok and 'soft limit' in reason
    assert h.axis.status & S.LIMIT
    h.run(0.01)
    assert h.axis.command_position == sign * limit
    assert h.axis.jog(-sign * 0.01) == (True, '')
    h.run(0.05)
    assert not h.axis.status & S.LIMIT
    assert sign * h.axis.command_position < limit


def test_stop_that_would_pass_a_soft_limit_brakes_to_it():
    """stop_deceleration 0.5 m/s² from 0.08 m/s needs 6.4 mm; STOP with 4.6 mm left: the axis
    brakes harder (what it takes) and ends STOPPED on the limit, LIMIT raised."""
    limit = 0.02
    h = Harness(dict(soft_limit_max=limit, stop_deceleration=0.5))
    h.axis.jog(0.08)
    h.run(0.5, until=lambda h: h.axis.command_position >= limit - 0.0046)
    k0 = len(h.trace.t)
    left = limit - h.axis.command_position
    assert stopping_distance(0.08, 0.0, 0.5, 0.0) > left > stopping_distance(0.08, 0.0, A_MAX, 0)
    assert h.axis.stop() == (True, '')
    h.tick()
    assert h.axis.status & S.LIMIT                 # from the STOP's tick on
    h.run(0.5, until=done)
    assert max(h.trace.command) == limit == h.trace.command[-1]
    w = h.axis.status
    assert w & S.STOPPED and w & S.MOTION_DONE and w & S.LIMIT and not w & S.AT_TARGET
    _, a, _ = derivatives(h.trace.command[k0 - 2:])
    ramp = a[1:-1][a[1:-1] < -1e-6]
    needed = 0.08 ** 2 / (2 * left)
    assert np.median(ramp) == pytest.approx(-1.02 * needed, rel=1e-3)   # brakes from the start


@pytest.mark.parametrize('feedback', ['dual', 'sampled'])
def test_settled_time_counts_only_ticks_with_a_new_encoder_sample(feedback):
    """Feedback held up (ticks without a new sample, within feedback_timeout, as over DDS when
    the encoder process stalls) adds no settled time and lets the sampled loop judge nothing:
    MOTION_DONE comes a settling time of fresh samples after the criteria hold, however long
    the samples stopped in between. (A frozen sample looks perfectly still.)"""
    h = Harness(DEFAULTS | {'settling_time': SETTLE, 'feedback': feedback})
    a = h.axis
    assert a.move_to(INCH)[0]
    assert h.run(5.0, until=lambda h: h.axis.settling.settle_start is not None)
    moves = a.sampled.moves
    m, l = h.plant.encoder_counts()
    for _ in range(round(4 * SETTLE / T)):                    # 200 ms without a new sample
        a.update(T, m, l, sample_dt=0.0)
        assert not a.status & S.MOTION_DONE
    assert a.sampled.moves == moves                           # no correction from a frozen sample
    resumed = h.time
    assert h.run(3.0, until=lambda h: h.axis.status & S.MOTION_DONE)
    assert h.time - resumed >= SETTLE - 2 * T
    assert abs(h.plant.x_l - INCH) <= INCH / 10000            # and the slide is there


def test_ticks_without_a_new_sample_hold_the_output_and_the_integrator():
    """A tick without a new encoder sample acts on nothing new: the output is held (a drive
    over a missed fieldbus frame) and the integrator does not wind up against the old sample;
    the next new sample is acted on over the time it covers."""
    h = Harness(DEFAULTS)
    a = h.axis
    assert a.move_to(INCH)[0]
    h.run(0.1)                                   # mid-move: error and integrator are busy
    m, l = h.plant.encoder_counts()
    out, integral = a.output, a.servo.integral
    for _ in range(20):
        assert a.update(T, m, l, sample_dt=0.0) == out
    assert a.servo.integral == integral
    assert a.update(T, m, l, sample_dt=21 * T) != out    # a new sample is acted on again
