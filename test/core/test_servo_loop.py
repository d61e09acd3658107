"""ServoLoop, the controller's whole tick, without ROS and in microseconds: the feedback
watchdog, the loop-closing gate, scheduled targets and register sets applied together."""
import pytest

from kit import COUNT
from motion_ctrl.core.axis import Axis
from motion_ctrl.core.registers import AXIS_REGISTERS, axis_defaults
from motion_ctrl.core.config import CorrectionConfig
from motion_ctrl.core.dual_loop import SampledCorrection
from motion_ctrl.core.servo_loop import STREAM_SETTLE, ServoLoop
from msg_defs.status import Status as S

T = 1e-3
TIMEOUT = 0.02


def _loop(sim_time=False, **registers) -> ServoLoop:
    values = axis_defaults(AXIS_REGISTERS) | registers
    return ServoLoop({'x': Axis('x', values, T)}, {'x': values}, T, TIMEOUT, sim_time)


def _run(loop, t0, t1, samples=True):
    """Ticks from t0 to t1 [s], a fresh sample (at rest at 0) before each when `samples`."""
    ticks = []
    for k in range(round((t1 - t0) / T)):
        now = t0 + k * T
        if samples:
            loop.feedback('x', 0, 0, now)
        ticks.append(loop.tick(now))
    return ticks


def test_the_loop_closes_after_the_stream_has_run_its_settling_time():
    """Real time: no output and the loop open until the samples span STREAM_SETTLE (PMAC
    Ixx80 = 1 once the encoders are there); sim time: at the first sample."""
    loop = _loop()
    ticks = _run(loop, 0.0, STREAM_SETTLE - 0.01)
    assert all(t.names == [] for t in ticks) and not loop.axes['x'].enabled
    _run(loop, STREAM_SETTLE - 0.01, STREAM_SETTLE + 0.01)
    assert loop.axes['x'].enabled
    sim = _loop(sim_time=True)
    sim.feedback('x', 0, 0, 0.0)
    assert sim.tick(0.0).names == ['x'] and sim.axes['x'].enabled


def test_a_kp_set_is_what_the_loop_pushes_with_from_the_next_tick():
    """`ros2 param set /controller x.kp`: the node stages it (as here) and from the next tick
    the axis pushes harder by exactly the new gain times its following error (the other terms
    are the same: at rest, the slide held 10 counts off). test_ros_parameters'
    test_set_kp_is_applied checks the node stages it; this, that the law runs with it."""
    def outputs(kp_factor):
        loop = _loop()
        _run(loop, 0.0, 1.0)
        kp = loop.current('x')['kp']
        if kp_factor != 1.0:
            loop.stage('x', {'kp': kp * kp_factor})
        out = []
        for k in range(5):
            loop.feedback('x', 0, 10, 1.0 + k * T)
            out.append((loop.tick(1.0 + k * T).outputs[0], loop.axes['x'].following_error))
        return kp, out
    kp, before = outputs(1.0)
    _, after = outputs(1.2)
    assert before[0][1] == pytest.approx(-10 * COUNT)
    for (old, error), (new, same_error) in zip(before, after):
        assert same_error == error
        assert new - old == pytest.approx(0.2 * kp * error, rel=1e-9), (old, new)


def test_feedback_fault_after_the_timeout_logged_once():
    loop = _loop()
    _run(loop, 0.0, 1.0)
    word = loop.axes['x'].status
    assert word & S.ENABLED
    last = 1.0 - T                                             # the last sample's tick
    n, lines = 0, []
    while not loop.axes['x'].faults:
        n += 1
        lines += loop.tick(last + n * T).log
        assert n < 100
    assert TIMEOUT / T < n <= TIMEOUT / T + 2                    # 20–22 ticks without samples
    t = last + (n + 1) * T
    assert len(lines) == 1 and 'FEEDBACK_FAULT' in lines[0][1] and 'loop opened' in lines[0][1]
    assert not loop.axes['x'].enabled
    lines = [x for tick in _run(loop, t, t + 0.1, samples=False) for x in tick.log]
    assert lines == []                                           # once, not per tick


def test_a_sample_older_than_the_one_in_hand_is_dropped():
    """Two paths to the loop (the plant's stream and a bridge's copy of it, a hop later:
    doc/plants.md) deliver a sample twice, the copy after newer ones. The loop does not step
    back to it, and stale copies do not feed the feedback watchdog."""
    loop = _loop()
    _run(loop, 0.0, 1.0)
    t = 1.0
    loop.feedback('x', 10, 10, t)                     # the slide 10 counts off
    loop.tick(t)
    loop.feedback('x', 0, 0, t - T)                   # the copy of the sample before it
    loop.tick(t + T)
    assert loop.axes['x'].following_error == pytest.approx(-10 * COUNT)
    n = 1
    while not loop.axes['x'].faults and n < 100:      # the plant stops; old copies go on
        n += 1
        loop.feedback('x', 0, 0, t - n * T)
        loop.tick(t + n * T)
    assert TIMEOUT / T < n <= TIMEOUT / T + 2


def test_ticks_that_find_no_new_sample_are_counted_and_hold_the_output():
    """/diagnostics' ticks_without_new_sample: a tick whose sample came just after it (or not
    at all) holds the output; the window counts such ticks, once a tick."""
    loop = _loop()
    _run(loop, 0.0, 1.0)
    loop.stats.reset_window()
    t = 1.0
    loop.feedback('x', 0, 10, t)
    held = loop.tick(t).outputs[0]
    for k in (1, 2, 3):                               # no sample for three ticks
        assert loop.tick(t + k * T).outputs[0] == held
    loop.feedback('x', 0, 10, t + 4 * T)
    loop.tick(t + 4 * T)
    assert loop.stats.summary()['ticks_without_new_sample'] == 3


def test_a_late_tick_counts_at_most_two_periods():
    """A controller held up 50 ms (its samples waiting in its queue) does not fault: the late
    tick counts 2 ms of waiting, not 50."""
    loop = _loop()
    _run(loop, 0.0, 1.0)
    loop.tick(1.05)                                   # no new sample, 50 ms late
    assert not loop.axes['x'].faults
    assert loop.waited['x'] == pytest.approx(2 * T)


def test_scheduled_target_starts_at_its_stamp_or_is_cancelled_by_a_stop():
    loop = _loop()
    _run(loop, 0.0, 1.0)
    loop.schedule(1.2, 'x', 0.01)
    _run(loop, 1.0, 1.19)
    assert not loop.axes['x'].status & S.MOVING
    _run(loop, 1.19, 1.21)
    assert loop.axes['x'].status & S.MOVING

    loop = _loop()
    _run(loop, 0.0, 1.0)
    loop.schedule(1.2, 'x', 0.01)
    assert loop.axes['x'].stop('estop')[0]
    lines = [x for tick in _run(loop, 1.0, 1.3) for x in tick.log]
    assert any('cancelled by ESTOP' in text for _, text in lines), lines
    assert not loop.axes['x'].status & S.MOVING and loop.scheduled == []


def test_targets_posted_between_ticks_the_latest_of_each_axis_wins():
    """A stream of targets faster than the loop (a 5 kHz publisher: five a tick) costs one
    re-plan per tick: only the latest posted of each axis is tried, at the next tick; one
    superseded before it is never tried (an out-of-limit target followed by a valid one leaves
    no LIMIT and no refusal); a refused latest one is reported by the tick; a jog posted after a
    target replaces it."""
    loop = _loop()
    _run(loop, 0.0, 1.0)
    axis = loop.axes['x']
    loop.post('x', 0.9)                              # beyond soft_limit_max (0.5 m)
    for k in range(1, 6):
        loop.post('x', 0.001 * k)
    assert axis.target is None                       # nothing before the tick
    [tick] = _run(loop, 1.0, 1.0 + T)
    assert tick.refused == [] and not axis.status & S.LIMIT
    assert axis.target == 0.005 and axis.status & S.MOVING
    loop.post('x', 0.003)
    loop.post('x', 0.9)
    [tick] = _run(loop, 1.0 + T, 1.0 + 2 * T)
    assert [(w, a) for w, a, _ in tick.refused] == [('target_position', 'x')], tick.refused
    assert 'outside the soft limits' in tick.refused[0][2] and axis.target == 0.005
    loop.post('x', 0.002)
    loop.post('x', 0.01, jog=True)
    _run(loop, 1.0 + 2 * T, 1.0 + 3 * T)
    assert axis.profile.kind == 'velocity' and axis.profile.target_velocity == 0.01
    loop.post('x', 0.004)
    log, refused = loop.flush()                      # (before another command: now)
    assert refused == [] and axis.target == 0.004 and loop.pending == {}


def test_register_sets_apply_together_at_the_next_tick_or_before_a_move():
    loop = _loop()
    _run(loop, 0.0, 1.0)
    loop.stage('x', {'kp': 1.0})
    loop.stage('x', {'ki': 2.0})
    assert loop.axes['x'].r['kp'] != 1.0                      # not before the tick
    loop.tick(1.0)
    assert (loop.axes['x'].r['kp'], loop.axes['x'].r['ki']) == (1.0, 2.0)
    loop.stage('x', {'feedback': 'motor'})
    assert loop.move({'x': 0.01}) == []                       # the set first, then the move
    assert loop.axes['x'].r['feedback'] == 'motor' and loop.axes['x'].target == 0.01


def test_correction_moves_that_make_the_error_grow_are_not_repeated():
    """Galil's #CORRECT repeats V2 = V1 − TE until the load error is within tolerance. A
    correction may overshoot on its way in, but once the load error is more than four times the
    one the first correction was for (stale or wrong readings, a blocked slide), the
    corrections end instead of driving the slide away (correction_max_moves is 200), and the
    loop says so once."""
    c = _correction(correction_tolerance=2 * COUNT)

    def settled(error_counts):
        return _settled(c, error_counts)
    assert settled(20) == pytest.approx(20 * COUNT)          # first correction: V2 = V1
    assert settled(-30) == pytest.approx(-30 * COUNT)        # overshot: still corrected
    assert settled(81) is None and c.phase == c.DONE            # > 4 × the first: no more
    assert c.diverged == (20, 81) and c.moves == 2
    # Within 4 coarse windows (40 counts) an error is an overshoot on the way in, however small
    # the first: a 3-count correction across the backlash left the slide 14 counts the other
    # side (over DDS), and is corrected.
    c.start_now()
    assert settled(3) == pytest.approx(3 * COUNT)
    assert settled(-21) == pytest.approx(-21 * COUNT)
    assert settled(1) is None and c.phase == c.DONE and c.diverged is None

    loop = _loop(sim_time=True, feedback='motor')
    axis = loop.axes['x']
    loop.feedback('x', 0, 0, 0.0)
    loop.tick(0.0)
    axis.sampled.diverged = (20, 81)
    lines = [line for k in range(1, 4) for line in (_tick_log(loop, k * T))]
    assert lines == [('warning', 'x: correction moves stopped: the load error grew from 20 to '
                                 '81 counts')]


def _correction(**config) -> SampledCorrection:
    """Galil's #CORRECT loop on a linear encoder of 1/COUNT counts a metre, started now."""
    c = SampledCorrection(CorrectionConfig.of(dict(
        correction_tolerance=COUNT, correction_max_moves=200, load_counts_per_m=1 / COUNT,
        settling_time=0.02, coarse_position_tolerance=10 * COUNT, correction_acceleration=0.1,
        window_centre='reading') | config))
    c.start_now()
    return c


def _settled(c: SampledCorrection, error_counts: int):
    """Ticks at rest with the load `error_counts` short of the target until a correction is
    due (its V2 [m]) or the corrections end (None)."""
    for _ in range(200):
        v2 = c.update(1e-3, profile_done=True, motor_settled=True, motor_counts=0, load_counts=0,
                      load_error_counts=error_counts, motor_error=0.0,
                      load_error=error_counts * COUNT)
        if v2 is not None or c.phase == c.DONE:
            return v2
    return None


@pytest.mark.parametrize('window_centre, error, v2', [
    ('reading', 0, None), ('reading', 1, 1.0), ('reading', -1, -1.0), ('reading', 2, 2.0),
    ('count_middle', 0, None), ('count_middle', 1, None), ('count_middle', -1, -1.5),
    ('count_middle', 2, 1.5)])
def test_the_sampled_loop_judges_the_load_where_the_other_windows_judge_it(window_centre, error,
                                                                          v2):
    """A quadrature counter reads the lower edge of its count. With window_centre reading only
    the target's own reading ends the corrections (the slide 0 ... +1 count from it); with
    count_middle the reading one below it ends them too (the slide within a count either
    way), and a correction aims the count's middle at the target."""
    assert _settled(_correction(window_centre=window_centre), error) == (
        None if v2 is None else pytest.approx(v2 * COUNT))


def _tick_log(loop, now):
    loop.feedback('x', 0, 0, now)
    return loop.tick(now).log
