"""The actual-velocity limit (overspeed_velocity, a drive's overspeed fault) and the catch-up rule
after a stall of the servo loop (core.axis STALL_PERIODS), without ROS: the loop ticks the
simulated slide (SimHardware) and is held up mid-move while the slide's amplifier runs on by
itself, as the plant node does while the controller's process is frozen (SIGSTOP)."""
import random

import pytest

from motion_ctrl.core.axis import STALL_PERIODS, Axis
from motion_ctrl.core.config import OVERSPEED_RATIO
from motion_ctrl.core.registers import (AXIS_REGISTERS, INCH, LOAD_COUNTS_PER_M,
                                        SHIPPED_SLIDE_TUNING, axis_defaults, consistency)
from motion_ctrl.core.servo_loop import ServoLoop
from motion_ctrl.sim.hardware import SimHardware
from motion_ctrl.sim.plant import SlidePlant
from msg_defs.status import Status as S

T = 1e-3
TIMEOUT = 0.02
TARGET = 0.05          # m: 500 ms of a 0.1 m/s cruise
V_MAX = axis_defaults(AXIS_REGISTERS)['max_velocity']


def _slide_loop(**registers):
    values = axis_defaults(AXIS_REGISTERS) | registers
    hw = SimHardware(['x'], T)
    loop = ServoLoop({'x': Axis('x', values, T)}, {'x': values}, T, TIMEOUT, True, hw)
    hw.configure()
    hw.activate()
    return loop, hw


def _hold_up(hw, periods: int) -> int:
    """The loop held up `periods` servo periods: the plant node's cycles run on with no command
    coming. Returns `periods`."""
    for _ in range(periods):
        hw.plants['x'].advance(T, T)
        hw.time += T
    return periods


def _move_with_stall(stall: float, at: float = 0.2, end: float = 1.6, *,
                     sampled_before: bool = False, **registers):
    """The slide's move to TARGET with the loop held up `stall` s at `at` s while the slide runs
    on (its amplifier's watchdog trips after command_timeout and brakes it). With
    `sampled_before`, the tick after the stall has no sample of its own but one taken just
    before the stall that the loop has not used yet (over DDS: the plant's sample came in after
    the last tick, the loop's timer fires before the samples of the stall are taken). Returns
    (peak slide speed after the stall [m/s], final slide error [counts], status word, log
    lines)."""
    loop, hw = _slide_loop(**registers)
    plant = hw.plants['x']
    n_at, n_end, k_stall = round(at / T), round(end / T), round(stall / T)
    log, peak, k = [], 0.0, 0
    while k < n_end:
        if k == n_at and k_stall:
            if sampled_before:
                hw.read(k * T)
            k += _hold_up(hw, k_stall)
            if sampled_before:
                log += loop.tick(k * T).log
                hw.write(k * T)
                k += 1
                continue
        tick = loop.cycle(k * T)
        log += tick.log
        if k == 1:
            assert loop.move({'x': TARGET}) == []
        if k > n_at:
            peak = max(peak, abs(plant.v_l))
        k += 1
    axis = loop.axes['x']
    return peak, (plant.x_l - TARGET) * LOAD_COUNTS_PER_M, axis.status, log


@pytest.mark.parametrize('stall', [0.003, 0.01, 0.02, 0.05, 0.2])
def test_a_move_held_up_lands_without_a_sprint(stall):
    """The loop held up mid-move while the slide runs on (the amplifier holds its last command
    for its 10 ms watchdog, then brakes): a late tick within STALL_PERIODS is stepped as it
    comes; after a longer stall the move is planned again from the measured state. The slide
    never exceeds overspeed_velocity (1.5 x max_velocity) and the move lands within a count,
    unfaulted. Without the rule the command is the stall ahead and the output at its limit to
    catch up: 20 ms ran the slide at 0.151 m/s, 50 ms at 0.2 m/s into OVERSPEED, 200 ms into
    FOLLOWING_ERROR_FATAL. (With it, the peaks: 0.101, 0.108, 0.103, 0.102, 0.103 m/s; with
    the stall's plan kept instead of planned again on the next sample, which gives the speed
    now rather than the mean over the stall: 0.101, 0.109, 0.121, 0.109, 0.103.)"""
    peak, error, status, log = _move_with_stall(stall)
    print(f'{stall * 1e3:g} ms: peak {peak:.4f} m/s, final error {error:+.2f} counts')
    assert peak <= OVERSPEED_RATIO * V_MAX, f'{peak:.4f} m/s after a {stall * 1e3:g} ms stall'
    assert abs(error) <= 1.0, f'{error:+.2f} counts'
    assert status & S.MOTION_DONE and not status & (S.OVERSPEED | S.FOLLOWING_ERROR_FATAL), \
        (status, log)


@pytest.mark.parametrize('stall', [0.01, 0.05, 0.2])
def test_a_move_held_up_after_a_sample_it_had_not_used_lands_without_a_fault(stall):
    """The tick after the stall finds a sample from just before it, as old as the stall (the
    freeze of the controller's process with SIGSTOP over DDS): the move is not planned again
    from it (the slide ran on from there) but from the first sample of after the stall. The
    move lands within a count, unfaulted, no faster than overspeed_velocity. (Planned again
    from the old sample, the command stood the stall's run behind the slide at once: a 50 ms
    stall at 0.1 m/s is a following error of 5 mm, FOLLOWING_ERROR_FATAL on the shipped
    following_error_fatal, as the 50 ms freeze over ROS faulted one run in three.)"""
    peak, error, status, log = _move_with_stall(stall, sampled_before=True)
    print(f'{stall * 1e3:g} ms: peak {peak:.4f} m/s, final error {error:+.2f} counts')
    assert status & S.MOTION_DONE and not status & (S.OVERSPEED | S.FOLLOWING_ERROR_FATAL), \
        (S(status), log)
    assert peak <= OVERSPEED_RATIO * V_MAX, f'{peak:.4f} m/s after a {stall * 1e3:g} ms stall'
    assert abs(error) <= 1.0, f'{error:+.2f} counts'


def test_a_stall_at_rest_changes_nothing():
    peak, error, status, _ = _move_with_stall(0.05, at=1.2)
    assert abs(error) <= 1.0 and status & S.MOTION_DONE and peak < 0.001


def _fed_loop(**registers):
    values = axis_defaults(AXIS_REGISTERS) | registers
    return ServoLoop({'x': Axis('x', values, T)}, {'x': values}, T, TIMEOUT, True)


def test_overspeed_opens_the_loop_with_its_own_bit_and_reason():
    """Encoder samples of a motor (and slide) running at 0.2 m/s, twice max_velocity, beyond
    the default limit (OVERSPEED_RATIO × max_velocity = 0.15 m/s): the loop opens on that
    tick, output 0, OVERSPEED (not a following error) with the speed and the limit in the log,
    once; reset clears it."""
    loop = _fed_loop()
    motor_cpm = loop.axes['x'].r['motor_counts_per_m']
    for k in range(5):                           # at rest
        loop.feedback('x', 0, 0, k * T)
        loop.tick(k * T)
    assert loop.axes['x'].enabled
    lines, outputs = [], []
    for j in range(1, 4):
        k = 4 + j
        x = 0.2 * j * T
        loop.feedback('x', round(x * motor_cpm), round(x * LOAD_COUNTS_PER_M), k * T)
        tick = loop.tick(k * T)
        lines += tick.log
        outputs += tick.outputs
    axis = loop.axes['x']
    assert axis.status & S.OVERSPEED and not axis.status & S.FOLLOWING_ERROR_FATAL
    assert not axis.enabled and outputs == [0.0, 0.0, 0.0]
    assert len(lines) == 1, lines
    level, text = lines[0]
    assert level == 'error' and text == ('x: OVERSPEED: motor velocity +0.2000 m/s beyond '
                                         'overspeed_velocity 0.15 m/s; loop opened, call x/reset')
    assert f'{OVERSPEED_RATIO * V_MAX:g}' == '0.15'
    ok, _ = loop.reset('x')
    assert ok and not axis.status & S.OVERSPEED


def test_overspeed_velocity_is_a_register_above_max_velocity():
    """0 (the default) is OVERSPEED_RATIO × max_velocity; a value at or below max_velocity is
    refused naming both; a set value is the limit the tick compares with."""
    values = axis_defaults(AXIS_REGISTERS)
    assert values['overspeed_velocity'] == 0.0
    reasons = consistency(values | {'overspeed_velocity': 0.1})
    assert reasons and 'overspeed_velocity' in reasons[0] and 'max_velocity' in reasons[0]
    assert consistency(values | {'overspeed_velocity': 0.12}) == []
    # 0.12 m/s set: samples at 0.13 m/s fault (the default, 0.15, would not)
    for limit, faults in ((0.12, True), (0.0, False)):
        loop = _fed_loop(overspeed_velocity=limit)
        motor_cpm = loop.axes['x'].r['motor_counts_per_m']
        for k in range(5):
            loop.feedback('x', 0, 0, k * T)
            loop.tick(k * T)
        x = 0.13 * T
        loop.feedback('x', round(x * motor_cpm), round(x * LOAD_COUNTS_PER_M), 5 * T)
        loop.tick(5 * T)
        assert bool(loop.axes['x'].status & S.OVERSPEED) == faults, limit


def _moves_with_late_ticks(seed: int, share: float = 0.02, most: int = 25):
    """The shipped slide's moves back and forth (+1, +2 in, three times) with `share` of the
    ticks coming 1 to `most` periods late, at random (`seed`), while the slide runs on.
    Returns (the motor's fastest measured speed [m/s], each move's final error [counts])."""
    rng = random.Random(seed)
    loop, hw = _slide_loop(**dict(SHIPPED_SLIDE_TUNING))
    axis, plant = loop.axes['x'], hw.plants['x']
    targets, fastest, k = [INCH, 2 * INCH] * 3, 0.0, 0
    errors: list[float] = []
    since = -100
    while k < 20000 and len(errors) < 6:
        if rng.random() < share:
            k += rng.randint(1, most)
        loop.cycle(k * T)
        fastest = max(fastest, abs(axis.motor_vel))
        assert not axis.status & S.OVERSPEED, (seed, k, axis.motor_vel)
        if axis.status & S.MOTION_DONE and k - since > 50:
            _next_target(loop, plant, targets, errors)
            since = k
        k += 1
    return fastest, errors


def _next_target(loop, plant, targets: list[float], errors: list[float]) -> None:
    """At MOTION_DONE: the slide's error from the target reached (if one was set) into
    `errors` [counts], then the next of `targets` started."""
    axis = loop.axes['x']
    if axis.target is not None:
        errors.append((plant.x_l - axis.target) * LOAD_COUNTS_PER_M)
    if targets:
        assert loop.move({'x': targets.pop(0)}) == []


def test_late_ticks_at_random_neither_sprint_nor_trip():
    """A loaded machine: 2 % of the ticks come 1-25 periods late, at random, while the slide
    runs on (sim.hardware: the amplifier's watchdog brakes it after 10 ms without a command).
    Over 10 seeds the motor is never faster than 0.12 m/s (max_velocity 0.1; here 0.116),
    never OVERSPEED, and every move is done within a count. Before, a stall's re-plan took the
    speed of its sample (the mean over the stall) for the speed now, and the sim's watchdog
    counted a late tick as two periods: the command ran ahead of a braked slide, the output
    saturated, and the next late tick held it there: 0.130 m/s here, 0.199 m/s and OVERSPEED
    in other such runs (as test_ros_sim's headline once in a full run). With the re-plan on
    the next sample alone 0.128 m/s; with the watchdog alone 0.140 m/s."""
    worst = 0.0
    for seed in range(10):
        fastest, errors = _moves_with_late_ticks(seed)
        worst = max(worst, fastest)
        assert len(errors) == 6 and all(abs(e) <= 1.0 for e in errors), (seed, errors)
    assert worst < 0.12, worst


def _following_error_after_a_stall_on_samples_a_period_old() -> tuple[float, float]:
    """A move on a fed loop whose samples come a period old (as over DDS: the plant's sample of
    the last cycle) and follow the command of their time exactly; the loop held up 10 periods
    at cruise while the slide runs on at the same speed. Returns (the following error before the
    stall, at the tick after it) [counts]."""
    loop = _fed_loop()
    axis = loop.axes['x']
    motor_cpm = axis.r['motor_counts_per_m']
    positions: dict[int, float] = {}

    def fed_tick(k):
        x = positions.get(k - 1, 0.0)
        loop.feedback('x', round(x * motor_cpm), round(x * LOAD_COUNTS_PER_M), (k - 1) * T)
        loop.tick(k * T)
        positions[k] = axis.profile.position
        return axis.following_error * LOAD_COUNTS_PER_M
    for k in range(6):
        fed_tick(k)
    assert loop.move({'x': TARGET}) == []
    for k in range(6, 300):
        before = fed_tick(k)
    assert axis.profile.velocity == pytest.approx(V_MAX)
    positions[308] = positions[299] + V_MAX * 9 * T    # the slide ran on
    return before, fed_tick(309)


def test_a_re_plan_on_a_sample_a_period_old_is_stepped_to_now():
    """The stall's re-plan starts from the sample, at the sample's time, and is stepped on by
    the sample's age to the tick's: the following error after it is as small as before it. (Not
    stepped, the command stood at the sample's position now: -40 counts at 0.1 m/s, a kick of
    the output of kp × 0.1 mm for a tick.)"""
    before, after = _following_error_after_a_stall_on_samples_a_period_old()
    print(f'following error before the stall {before:+.2f}, after {after:+.2f} counts')
    assert abs(before) < 1.0 and abs(after) < 1.0, (before, after)


def _moves_over_dds(seed: int, share: float, most: int) -> tuple[list[float], list[str]]:
    """The shipped slide's moves back and forth (+1, +2 in, three times) on a loop fed as over
    DDS: the plant samples every period and each sample reaches the loop 0.2-1.6 ms later (2 %
    of them 2-8 ms); `share` of the ticks come 6 to `most` periods late (a stall: the plant's
    watchdog brakes the slide after 10 ms), and the tick after a stall has only what reached
    the loop before it stopped. Returns (each move's final error [counts], the faults)."""
    rng = random.Random(seed)
    loop = _fed_loop(**dict(SHIPPED_SLIDE_TUNING))
    axis, plant = loop.axes['x'], SlidePlant()
    queue: list[tuple[float, float, int, int]] = []     # (reaches the loop, stamp, counts)
    targets, since, t, k = [INCH, 2 * INCH] * 3, -100, 0.0, 0
    errors: list[float] = []

    def plant_to(until: float) -> None:
        nonlocal t
        while t < until - 1e-9:
            plant.advance(T, T)
            t += T
            late = rng.uniform(0.2e-3, 1.6e-3) if rng.random() > 0.02 else rng.uniform(2e-3, 8e-3)
            queue.append((t + late, t, plant.motor_count(), plant.load_count()))
    for _ in range(20000):           # ticks
        if len(errors) == 6:
            break
        cut = k * T                  # what reached the loop by the tick it missed, or by this
        if k > 10 and rng.random() < share:
            k += rng.randint(6, most)
        plant_to(k * T)
        for sample in [q for q in queue if q[0] <= cut]:
            queue.remove(sample)
            loop.feedback('x', sample[2], sample[3], sample[1])
        tick = loop.tick(k * T)
        if tick is not None and tick.outputs:
            plant.command(tick.outputs[0])
        if axis.status & (S.OVERSPEED | S.FOLLOWING_ERROR_FATAL):
            return errors, [axis.fault_reason]
        if axis.enabled and axis.status & S.MOTION_DONE and k - since > 50:
            _next_target(loop, plant, targets, errors)
            since = k
        k += 1
    return errors, []


@pytest.mark.parametrize('share, most', [(0.01, 60), (0.02, 200), (0.03, 500)])
def test_stalls_with_samples_late_as_over_dds_neither_sprint_nor_trip(share, most):
    """Stalls at random with the samples coming as over DDS, the tick after each finding
    only samples from before it (doc/input_limits.md, "After a stall"): over 10 seeds every
    move is done within a count, never OVERSPEED or FOLLOWING_ERROR_FATAL. Before (the old
    sample taken for fresh; a move whose plan ran out while the loop waited for a fresh one
    not planned again, the slide braked short of it), 1 % of the ticks 6-60 periods late
    faulted 17 runs in 30, 2 % up to 200 periods every run; with the servo law integrating
    the error over a whole stall at once, a 0.5 s stall at rest drove 5.6 V on 0.07 mm, then
    OVERSPEED (3 % up to 500 periods, seed 2)."""
    for seed in range(10):
        errors, faults = _moves_over_dds(seed, share, most)
        assert faults == [] and len(errors) == 6, (seed, faults, errors)
        assert all(abs(e) <= 1.0 for e in errors), (seed, errors)


def _path_after_a_stall(stall_ticks: int | None):
    """A trajectory on a fed loop (the slide's samples follow the command exactly): the
    commanded (unsmoothed) path position after tick 100, then, with `stall_ticks`, the loop held
    up that many periods, a tick with no new sample (the encoders' process was held up with the
    loop) and a tick with one; without, ticks as they come. Returns the raw command after each
    tick from 100 on."""
    loop = _fed_loop()
    axis = loop.axes['x']
    motor_cpm = axis.r['motor_counts_per_m']

    def fed_tick(k, fresh=True):
        x = axis.profile.raw_position
        if fresh:
            loop.feedback('x', round(x * motor_cpm), round(x * LOAD_COUNTS_PER_M), k * T)
        loop.tick(k * T)
        return axis.profile.raw_position
    for k in range(5):
        fed_tick(k)
    assert loop.trajectory({'names': ['x'], 'times': [1.0], 'positions': [[0.02]],
                            'velocities': [[0.0]], 'accelerations': []}) is None
    for k in range(5, 100):
        fed_tick(k)
    if stall_ticks is None:
        return [fed_tick(k) for k in range(100, 120)]
    k = 100 + stall_ticks
    return [fed_tick(k, fresh=False), fed_tick(k + 1)]


def test_a_path_resumes_after_a_stall_whose_tick_had_no_sample_one_period_a_tick():
    """A trajectory is stepped STALL_PERIODS over a stall (the rest of the stall is lost, the
    path runs that much later; no sprint): over a 10 ms stall whose first tick had no new
    sample, the path stands STALL_PERIODS on at that tick and one period further at the next,
    as a tick that comes in time steps it. (It was stepped STALL_PERIODS again at the next
    tick: 5 ms of path in one period, a jump of the command.)"""
    steady = _path_after_a_stall(None)          # after ticks 100, 101, ...
    stale, fresh = _path_after_a_stall(10)      # ticks 99, then 110 (stale) and 111
    assert stale == pytest.approx(steady[STALL_PERIODS - 1], abs=1e-12)
    assert fresh == pytest.approx(steady[STALL_PERIODS], abs=1e-12)


def _sampled_reversal_with_stalls(seed: int) -> tuple[float, float]:
    """The headline's sampled dual loop (shipped tuning, `feedback: sampled`): +2 in, then back
    to +1 in across the backlash, with the loop held up 1-12 periods on 2 % of its ticks while
    the slide runs on (random, seeded). Returns the slide's error [counts] at the second move's
    MOTION_DONE and 1.5 s after it."""
    rnd = random.Random(seed)
    loop, hw = _slide_loop(**(SHIPPED_SLIDE_TUNING | {'feedback': 'sampled'}))
    plant, axis = hw.plants['x'], loop.axes['x']
    k = 0

    def tick() -> int:
        nonlocal k
        if rnd.random() < 0.02:
            k += _hold_up(hw, rnd.randint(1, 12))
        loop.cycle(k * T)
        k += 1
        return axis.status
    for _ in range(5):
        tick()
    for target in (2 * INCH, INCH):
        assert loop.move({'x': target}) == []
        cleared = False
        for _ in range(10000):
            word = tick()
            cleared = cleared or not word & S.MOTION_DONE
            if cleared and word & S.MOTION_DONE:
                break
    at_done = (plant.x_l - INCH) * LOAD_COUNTS_PER_M
    for _ in range(1500):
        tick()
    return at_done, (plant.x_l - INCH) * LOAD_COUNTS_PER_M


@pytest.mark.parametrize('seed', [0, 10, 13, 20])
def test_the_sampled_correction_ends_with_the_motor_at_its_command(seed):
    """Galil's #CORRECT ends on |V2| = |V1 − TE| < 2: the load there and the motor at its
    command. Ended on V1 alone, a stall on the way in left the motor stopped 2-3 counts short
    of its command by stiction; MOTION_DONE came with the slide in place (-0.6 to -1.0
    counts), and the motor's integrator then broke it loose and took the slide 1.4-3.9 counts
    off (these seeds; over DDS, test_ros_headline's sampled reversal missed so in ~1 run of 5)."""
    at_done, later = _sampled_reversal_with_stalls(seed)
    print(f'seed {seed}: {at_done:+.2f} counts at MOTION_DONE, {later:+.2f} 1.5 s later')
    assert abs(at_done) <= 1.0 and abs(later) <= 1.0, (at_done, later)
