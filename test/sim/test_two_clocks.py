"""The two-process loop replayed on its own clocks (motion_ctrl.sim.two_clocks), and what it says
of the shipped tuning (doc/gains.md): with the integrator held during moves (PMAC Ixx34 = 1) the
demo's moves settle within 150 ms of the profile's end wherever the controller's tick falls
between the plant's; integrating always, the same gains end moves a count past the target at
some of those phases and come back through the backlash in most of a second; on the shipped
S-curve the motor stays on the slide at the profile's end, on a trapezoid it runs back off it.

data/demo_clocks.npz: the tick times of three two-process demo runs on 2026-11-27 (this 2-core
VM), the plant's (`plant_states` stamps) and the controller's (`joint_states` stamps), in µs
from the first: run1 recorded `command` and `encoders` as well and ticked at ~700 Hz; runs 2
and 3 did not.
"""
from __future__ import annotations

import pathlib
import statistics

import numpy as np
import pytest

from motion_ctrl.core.registers import INCH, LOAD_COUNTS_PER_M, SHIPPED_SLIDE_TUNING
from motion_ctrl.sim.two_clocks import DEMO_END, TwoClockHardware, demo_loop, demo_moves, repeat

CLOCKS = pathlib.Path(__file__).parents[1] / 'data' / 'demo_clocks.npz'
GRID = [k * 1e-3 for k in range(3300)]              # the plant's ticks, exactly 1 ms apart
PHASES = [0.05e-3 + k * 0.1e-3 for k in range(10)]  # where the controller ticks after them
SHIPPED = dict(SHIPPED_SLIDE_TUNING)
ALWAYS = SHIPPED | {'integration_mode': 'always'}
TRAPEZOID = SHIPPED | {'max_jerk': 0.0}


def _recorded():
    data = np.load(CLOCKS)
    for run in ('run1', 'run2', 'run3'):
        plant = (data[f'{run}_plant_us'] * 1e-6).tolist()
        loop = (data[f'{run}_controller_us'] * 1e-6).tolist()
        yield run, repeat(plant, DEMO_END), repeat(loop, DEMO_END)


def _median_ms(results) -> float:
    return statistics.median(r.after_profile if r.after_profile is not None else 9.999
                             for r in results) * 1e3


def test_a_command_holds_from_the_first_plant_period_that_ends_after_it_arrived():
    hw = TwoClockHardware('x', {}, [0.0, 1e-3, 2e-3, 3e-3], d_in=0.15e-3, d_out=0.25e-3)
    hw.activate()
    io = hw.io['x']
    hw.read(0.5e-3)                           # nothing new: the plant's first tick is t = 0
    assert io.stamp == 0.0
    io.output, io.commanded = 1.0, True
    hw.write(0.7e-3)                          # arrives at 0.95 ms: holds for (0, 1 ms]
    io.output = 2.0
    hw.write(0.9e-3)                          # arrives at 1.15 ms: the period (1, 2 ms]
    hw.read(1.2e-3)                           # the 1 ms sample has reached the loop
    assert io.stamp == 1e-3 and hw.plant.commanded == 1.0
    hw.read(2.2e-3)
    assert io.stamp == 2e-3 and hw.plant.commanded == 2.0


@pytest.mark.parametrize('phase', PHASES, ids=lambda p: f'{p * 1e3:.2f}ms')
def test_the_shipped_tuning_settles_the_demo_wherever_the_loop_ticks(phase):
    results = demo_moves(SHIPPED, {}, GRID, [t + phase for t in GRID])
    assert _median_ms(results) <= 150.0, results
    assert all(abs(r.error) <= 1.0 and r.overshoot <= 2.0 for r in results), results


def test_integrating_always_the_same_gains_end_moves_past_the_target_at_some_phases():
    medians = [_median_ms(demo_moves(ALWAYS, {}, GRID, [t + p for t in GRID])) for p in PHASES]
    assert min(medians) <= 35.0, medians          # the harness's 30 ms where the phase is right
    assert sum(m > 300.0 for m in medians) >= 3, medians


@pytest.mark.parametrize('run, plant, loop', list(_recorded()), ids=['run1', 'run2', 'run3'])
def test_on_recorded_clocks_the_shipped_tuning_settles(run, plant, loop):
    shipped = demo_moves(SHIPPED, {}, plant, loop)
    assert _median_ms(shipped) <= 150.0, shipped
    assert all(abs(r.error) <= 1.0 for r in shipped), shipped


def test_on_recorded_clocks_integrating_always_does_not():
    """Two of the three runs: medians 592 and 555 ms (the third 27 ms; with window_centre
    reading all three, 403-592 ms)."""
    medians = [_median_ms(demo_moves(ALWAYS, {}, plant, loop)) for _, plant, loop in _recorded()]
    assert sum(m > 300.0 for m in medians) >= 2, medians


def test_on_recorded_clocks_the_s_curve_keeps_the_motor_on_the_slide_at_the_profiles_end():
    """The shipped S-curve (max_jerk 60 m/s³): in the 40 ms after each profile's end the motor
    never runs back faster than 0.3 mm/s (0.14 here). On a trapezoid the acceleration
    feedforward stops at once, and the motor, braking on it late, runs back off the slide
    (run1: 0.91 and 0.72 mm/s; over DDS, up to 6.8 mm/s: doc/gains.md)."""
    shipped, trapezoid = [], []
    for _, plant, loop in _recorded():
        shipped += demo_moves(SHIPPED, {}, plant, loop)
        trapezoid += demo_moves(TRAPEZOID, {}, plant, loop)
    assert max(r.motor_back for r in shipped) <= 0.3e-3, shipped
    assert max(r.motor_back for r in trapezoid) >= 0.8e-3, trapezoid


def _reversal_with_a_hold_up(hold: float, at: float = 0.68):
    """The demo's reversal (+2 in, back to +1 in) with both processes held up at `at` s, at
    speed: the loop for `hold`, the plant for 5 ms, the plant's samples of the hold-up reaching
    the loop after its first tick. Returns (peak |output| [V] and |following error| [counts] in
    the 60 ms after it, the slide's final error [counts])."""
    plant = [t for t in GRID[:2500] if not at < t < at + 0.005]
    loop_ticks = [t + 0.45e-3 for t in GRID[:2500] if not at < t + 0.45e-3 < at + hold]
    hw, axis, loop = demo_loop(SHIPPED, {}, plant, held_samples=(at, at + hold + 1e-3))
    moves = [(0.05, 2 * INCH), (0.6, INCH)]
    peak = gap = 0.0
    for now in loop_ticks:
        if moves and now >= moves[0][0]:
            loop.move({'x': moves.pop(0)[1]})
        loop.cycle(now)
        if at < now < at + 0.06:
            peak = max(peak, abs(hw.io['x'].output))
            gap = max(gap, abs(axis.following_error) * LOAD_COUNTS_PER_M)
    return peak, gap, (hw.plant.x_l - INCH) * LOAD_COUNTS_PER_M


@pytest.mark.parametrize('hold', [0.008, 0.012])
def test_after_a_hold_up_the_plan_waits_for_a_new_sample(hold):
    """Both processes held up mid-move, the loop's first tick after it finds no new sample
    (the README's demo plot, 2026-11-27: 8 ms at 78 mm/s). The plan is made again from the
    first sample that comes, not from the last one, as old as the hold-up (that gave 7.2 V and
    a following error of 258 counts at 8 ms, 10 V at 12 ms): the output stays the move's own
    (1.4 V without a hold-up), and the following error, each sample against the command of
    its own time, grows by no more than the command's acceleration over the hold-up, a h²/2;
    the move lands within a count."""
    _, calm, _ = _reversal_with_a_hold_up(0.0005)
    peak, error, final = _reversal_with_a_hold_up(hold)
    a_h2 = 1.5 * hold ** 2 / 2 * LOAD_COUNTS_PER_M             # max_acceleration 1.5 m/s²
    assert peak <= 1.6 and error <= calm + a_h2 + 5.0, (peak, error, calm, a_h2)
    assert abs(final) <= 1.0, final
