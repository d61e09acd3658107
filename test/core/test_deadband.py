"""Tests for motion_ctrl.core.deadband (Delta RMC Output Deadband + Deadband Tolerance, seed 000).

Numbers: a 0.4 V deadband, a 1 mm tolerance, and the default slide's linear encoder
(2.54 um per count, so half a raw count = 1.27 um).
"""

import pytest

from kit import COUNT
from motion_ctrl.core.deadband import anti_hunting, limit_integral_to_wind_down, output_deadband

DB = 0.4          # V
TOL = 1e-3        # m
HALF_COUNT = 0.5 * COUNT     # m, half a linear count of the Galil slide


def pos(output, error, tolerance=TOL, stopped=True, deadband=DB):
    return output_deadband(output, deadband, error, tolerance, stopped, True)


def vel(output, error, tolerance=TOL, stopped=True, deadband=DB):
    return output_deadband(output, deadband, error, tolerance, stopped, False)


# ---------------------------------------------------------------- position modes: ratioing

def test_ratioed_deadband_is_half_at_half_the_tolerance():
    # error = tolerance / 2 -> half the deadband: 1.0 V + 0.2 V
    assert pos(1.0, 0.5e-3) == pytest.approx(1.2, abs=1e-12)
    assert pos(1.0, -0.5e-3) == pytest.approx(1.2, abs=1e-12)     # |error| is what counts
    assert pos(1.0, 0.25e-3) == pytest.approx(1.1, abs=1e-12)     # a quarter -> 0.1 V
    assert pos(0.05, 0.0) == pytest.approx(0.05, abs=1e-12)       # zero error -> nothing


def test_full_deadband_outside_tolerance_and_while_moving():
    assert pos(1.0, 2e-3) == pytest.approx(1.4, abs=1e-12)        # outside the window
    assert pos(1.0, 1e-3) == pytest.approx(1.4, abs=1e-12)        # at the edge: full
    assert pos(1.0, 0.5e-3, stopped=False) == pytest.approx(1.4, abs=1e-12)  # target moving
    assert pos(1.0, 0.5e-3, tolerance=0.0) == pytest.approx(1.4, abs=1e-12)  # no tolerance


def test_deadband_sign_follows_output():
    assert pos(-1.0, 0.5e-3) == pytest.approx(-1.2, abs=1e-12)
    assert pos(-1.0, 2e-3) == pytest.approx(-1.4, abs=1e-12)
    # the sign of the OUTPUT, not of the error
    assert pos(-1.0, +2e-3) == pytest.approx(-1.4, abs=1e-12)
    assert pos(0.0, 2e-3) == 0.0                                   # zero output: nothing added
    assert pos(1.0, 2e-3, deadband=0.0) == 1.0


# ---------------------------------------------------------------- velocity modes

def test_velocity_mode_tolerance_turns_deadband_off_at_zero_target():
    assert vel(1.0, 0.5e-3) == 1.0                                 # target 0, tolerance != 0
    assert vel(-1.0, 5e-3) == -1.0
    assert vel(1.0, 0.5e-3, stopped=False) == pytest.approx(1.4, abs=1e-12)  # moving: full
    assert vel(1.0, 0.5e-3, tolerance=0.0) == pytest.approx(1.4, abs=1e-12)  # tol 0: full
    assert vel(-1.0, 0.5e-3, stopped=False) == pytest.approx(-1.4, abs=1e-12)


def test_velocity_mode_has_no_ratioing():
    # inside the "window" while moving: full deadband, never a fraction
    assert vel(1.0, 0.5e-3, stopped=False) == pytest.approx(1.4, abs=1e-12)
    assert vel(1.0, 1e-9, stopped=False) == pytest.approx(1.4, abs=1e-12)


def test_negative_or_nan_settings_refused():
    with pytest.raises(ValueError):
        pos(1.0, 0.0, deadband=-0.1)
    with pytest.raises(ValueError):
        pos(1.0, 0.0, tolerance=-1e-3)
    with pytest.raises(ValueError):
        pos(1.0, 0.0, deadband=float('nan'))


# ---------------------------------------------------------------- anti-hunting

def test_anti_hunting_half_count_window_with_zero_tolerance():
    assert anti_hunting(True, 1.0e-6, 0.0, HALF_COUNT) is True      # 1.0 um < 1.27 um
    assert anti_hunting(True, -1.0e-6, 0.0, HALF_COUNT) is True
    assert anti_hunting(True, 1.5e-6, 0.0, HALF_COUNT) is False     # 1.5 um > 1.27 um
    assert anti_hunting(False, 1.0e-6, 0.0, HALF_COUNT) is False    # target moving
    assert anti_hunting(True, 0.0, 0.0, 0.0) is False               # no window at all


def test_anti_hunting_tolerance_window():
    assert anti_hunting(True, 0.5e-3, TOL, HALF_COUNT) is True
    assert anti_hunting(True, 0.999e-3, TOL, HALF_COUNT) is True
    assert anti_hunting(True, 1e-3, TOL, HALF_COUNT) is False       # not less than tolerance
    assert anti_hunting(False, 0.5e-3, TOL, HALF_COUNT) is False


# ---------------------------------------------------------------- integrator wind-down

def test_integral_may_shrink():
    assert limit_integral_to_wind_down(2.0, 1.5) == 1.5
    assert limit_integral_to_wind_down(-2.0, -0.5) == -0.5
    assert limit_integral_to_wind_down(2.0, 0.0) == 0.0
    assert limit_integral_to_wind_down(2.0, 2.0) == 2.0


def test_integral_never_grows():
    assert limit_integral_to_wind_down(2.0, 2.5) == 2.0
    assert limit_integral_to_wind_down(-2.0, -3.0) == -2.0
    assert limit_integral_to_wind_down(0.0, 0.1) == 0.0
    assert limit_integral_to_wind_down(0.0, -0.1) == 0.0


def test_integral_never_crosses_zero():
    assert limit_integral_to_wind_down(2.0, -0.5) == 0.0
    assert limit_integral_to_wind_down(-2.0, 0.5) == 0.0
    assert limit_integral_to_wind_down(0.3, -5.0) == 0.0     # crossing by more than it had


def test_integrator_under_anti_hunting_winds_down_only():
    # A stopped axis hunting +/-0.8 um around the target (inside half a count): the integral
    # (Ki * T * error added each tick) starts at 1.0 V and may only decay toward 0, never
    # grow, never change sign.
    ki_t = 1e5
    integral = 1.0
    history = [integral]
    for k in range(200):
        error = 0.8e-6 if k % 3 else -0.8e-6
        assert anti_hunting(True, error, 0.0, HALF_COUNT)
        integral = limit_integral_to_wind_down(integral, integral + ki_t * error)
        history.append(integral)
    assert all(b <= a for a, b in zip(history, history[1:]))
    assert min(history) >= 0.0
    assert history[-1] == 0.0
