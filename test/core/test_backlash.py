"""Tests for motion_ctrl.core.backlash (PMAC Ixx85/86/87, DEFINE BLCOMP, DEFINE COMP).

All numbers worked by hand; SI units (m, m/s, s).
"""

import math

import numpy as np
import pytest

from motion_ctrl.core.backlash import BacklashCompensation, apply_correction, interpolate_table
from motion_ctrl.core.config import BacklashConfig

UM = 1e-6
MM = 1e-3


def reversal_reference(bc):
    """The running extreme in the current direction [m] that the hysteresis counts from (None
    before the first reset or step): internal state, read for these tests only."""
    return bc._extreme


TOL = 1e-12  # 1 pm: far below anything meaningful, above float noise


def approx(x):
    return pytest.approx(x, abs=TOL)


# This file's baseline: every register 0 / empty (the tests name what they turn on), under the
# short names the manual uses (distance = Ixx86, takeup_rate = Ixx85, hysteresis = Ixx87).
BASE = dict(distance=0.0, takeup_rate=0.0, hysteresis=0.0, backlash_table=[],
            backlash_table_spacing=0.0, leadscrew_table=[], leadscrew_table_spacing=0.0)
SHORT = {'distance': 'backlash_distance', 'takeup_rate': 'backlash_takeup_rate',
         'hysteresis': 'backlash_hysteresis'}


def config(**cfg) -> BacklashConfig:
    """The compensation registers, validated by the register table as the controller does."""
    return BacklashConfig.of({SHORT.get(k, k): v for k, v in (BASE | cfg).items()})


def make(**cfg):
    bc = BacklashCompensation(config(**cfg))
    bc.reset(0.0)
    return bc


# 1. dither smaller than the hysteresis never flips the direction
def test_dither_below_hysteresis_introduces_no_backlash():
    bc = make(distance=50 * UM, takeup_rate=0.01, hysteresis=4 * UM)
    assert bc.step(1 * MM, 1e-3) == approx(0.0)
    for _ in range(20):
        for pos in (1 * MM - 3 * UM, 1 * MM):
            corr = bc.step(pos, 1e-3)
            assert corr == approx(0.0)
            assert bc.register == 0.0
            assert bc.direction == +1
            assert not bc.active


# 2. reversal beyond the hysteresis: ramp at exactly takeup_rate*dt, hold, ramp back
def test_reversal_ramps_at_takeup_rate_and_back():
    dt = 1e-3
    bc = make(distance=50.8 * UM, takeup_rate=0.01, hysteresis=4 * UM)  # 10 um per 1 ms tick
    bc.step(1 * MM, dt)
    assert bc.register == 0.0 and bc.direction == +1 and not bc.active

    # reversal to negative (100 um > 4 um) detected on this tick: first 10 um
    bc.step(0.9 * MM, dt)
    regs = [bc.register]
    assert bc.direction == -1
    for _ in range(5):                  # stationary: background take-up continues
        bc.step(0.9 * MM, dt)
        regs.append(bc.register)
    assert regs == [approx(v * UM) for v in (10, 20, 30, 40, 50, 50.8)]
    assert bc.register == 50.8 * UM     # lands exactly on the distance
    for _ in range(3):                  # holds at the distance
        assert bc.step(0.9 * MM, dt) == approx(-50.8 * UM)
        assert bc.register == 50.8 * UM
        assert bc.active                # non-zero register -> BACKLASH_ACTIVE
    assert bc.correction == approx(-50.8 * UM)

    # reversal to positive (50 um > 4 um): ramps back to 0 at the same rate
    bc.step(0.95 * MM, dt)
    assert bc.direction == +1
    regs = [bc.register]
    actives = [bc.active]
    for _ in range(5):
        bc.step(0.95 * MM, dt)
        regs.append(bc.register)
        actives.append(bc.active)
    assert regs == [approx(v * UM) for v in (40.8, 30.8, 20.8, 10.8, 0.8, 0.0)]
    assert bc.register == 0.0
    assert actives == [True, True, True, True, True, False]
    assert bc.correction == 0.0


# 3. hysteresis counted from the extreme point, not from the previous sample
def test_hysteresis_counted_from_extreme_point():
    bc = make(distance=50 * UM, takeup_rate=0.0, hysteresis=4 * UM)  # rate 0: step
    for pos in (0.25 * MM, 0.5 * MM, 0.75 * MM, 1 * MM):
        bc.step(pos, 1e-3)
    assert reversal_reference(bc) == 1 * MM
    # creep back in steps each < 4 um; total 3.9 um from the 1 mm extreme -> nothing
    for pos in (0.999 * MM, 0.998 * MM, 0.997 * MM, 0.9961 * MM):
        assert bc.step(pos, 1e-3) == approx(0.0)
        assert bc.direction == +1 and bc.register == 0.0
    assert reversal_reference(bc) == 1 * MM
    # 0.9959 mm is 4.1 um below the extreme: reversal; rate 0 -> whole distance at once
    assert bc.step(0.9959 * MM, 1e-3) == approx(-50 * UM)
    assert bc.direction == -1 and bc.register == 50 * UM
    assert reversal_reference(bc) == 0.9959 * MM
    # the negative-going extreme is the running minimum
    bc.step(0.9 * MM, 1e-3)
    assert reversal_reference(bc) == 0.9 * MM
    bc.step(0.9 * MM + 4 * UM, 1e-3)            # exactly 4 um: not "more than"
    bc.step(0.9 * MM + 3.9 * UM, 1e-3)
    assert bc.direction == -1 and bc.register == 50 * UM
    bc.step(0.9 * MM + 4.1 * UM, 1e-3)          # 4.1 um above the minimum
    assert bc.direction == +1 and bc.register == 0.0


def test_zero_hysteresis_any_reversal_counts():
    bc = make(distance=20 * UM, takeup_rate=0.0, hysteresis=0.0)
    bc.step(1 * MM, 1e-3)
    bc.step(1 * MM - 1e-9, 1e-3)
    assert bc.direction == -1 and bc.register == 20 * UM
    bc.step(1 * MM - 1e-9, 1e-3)                # standing still is not a reversal
    assert bc.direction == -1
    bc.step(1 * MM, 1e-3)
    assert bc.direction == +1 and bc.register == 0.0


# 4. the nominal position is never modified nor replaced by the corrected one
def test_reported_position_never_includes_correction():
    bc = make(distance=30 * UM, takeup_rate=0.0, hysteresis=0.0,
              leadscrew_table=[0.0, 10 * UM], leadscrew_table_spacing=0.01)
    bc.step(2 * MM, 1e-3)
    nominal = np.float64(1.5 * MM)              # reversal to negative
    before = float(nominal)
    corr = bc.step(nominal, 1e-3)
    assert float(nominal) == before             # input untouched
    # correction = -30 um + leadscrew(1.5 mm) = -30 um + 1.5 um
    assert corr == approx(-28.5 * UM)
    assert bc.correction == corr
    assert bc.nominal_position == before        # what to report as "commanded"
    assert bc.motor_position == approx(before - 28.5 * UM)   # servo target only
    assert bc.motor_position != bc.nominal_position
    assert apply_correction(before, corr) == bc.motor_position
    # the class offers no "commanded" value carrying the correction
    assert not any("commanded" in name for name in dir(bc) if not name.startswith("_"))

    positions = [0.5 * MM, 0.4 * MM, 0.6 * MM]
    snapshot = list(positions)
    for p in positions:
        bc.step(p, 1e-3)
    assert positions == snapshot


# 5. tables: interpolation, end values, where each applies
def test_interpolate_table():
    table = [0.0, 10 * UM, 30 * UM]
    assert interpolate_table(table, 0.01, 0.015) == approx(20 * UM)
    assert interpolate_table(table, 0.01, 0.005) == approx(5 * UM)
    assert interpolate_table(table, 0.01, 0.01) == approx(10 * UM)
    assert interpolate_table(table, 0.01, -0.5) == 0.0          # below 0: first entry
    assert interpolate_table(table, 0.01, 0.02) == approx(30 * UM)
    assert interpolate_table(table, 0.01, 1.0) == 30 * UM       # beyond the end: last entry
    assert interpolate_table([7 * UM], 0.01, 0.5) == 7 * UM
    assert interpolate_table([], 0.0, 0.3) == 0.0
    assert interpolate_table((), 0.01, 0.3) == 0.0
    with pytest.raises(ValueError):
        interpolate_table(table, 0.0, 0.015)


def test_leadscrew_table_applies_both_directions():
    bc = make(leadscrew_table=[0.0, 10 * UM, 30 * UM], leadscrew_table_spacing=0.01,
              hysteresis=4 * UM)
    assert bc.step(0.015, 1e-3) == approx(20 * UM)              # moving +
    assert bc.step(0.005, 1e-3) == approx(5 * UM)               # moving -
    assert bc.direction == -1 and bc.register == 0.0            # distance 0: no backlash
    assert bc.step(0.025, 1e-3) == approx(30 * UM)              # + again, end value held
    assert bc.step(-0.01, 1e-3) == approx(0.0)


def test_backlash_table_adds_to_distance_only_moving_negative():
    bc = make(distance=50 * UM, takeup_rate=0.0, hysteresis=0.0,
              backlash_table=[0.0, 10 * UM, 30 * UM], backlash_table_spacing=0.01)
    assert bc.step(0.015, 1e-3) == approx(0.0)                  # + : nothing at all
    assert bc.register == 0.0
    # reversal at 0.012: 50 + (10 + 20 * 0.2) = 64 um
    assert bc.step(0.012, 1e-3) == approx(-64 * UM)
    assert bc.register == approx(64 * UM) and bc.target == approx(64 * UM)
    assert bc.step(0.005, 1e-3) == approx(-55 * UM)             # 50 + 5
    assert bc.step(0.02, 1e-3) == approx(0.0)                   # + again: table ignored
    assert bc.register == 0.0 and not bc.active


def test_register_follows_position_dependent_target_at_takeup_rate():
    # table 0..100 um over 10 mm; moving - at 0.1 mm per tick the target drops 1 um per tick;
    # rate 0.01 m/s at dt 1 ms = 10 um per tick
    bc = BacklashCompensation(config(takeup_rate=0.01, backlash_table=[0.0, 100 * UM],
                                     backlash_table_spacing=0.01))
    bc.reset(0.01)
    regs = {}
    for k in range(1, 21):
        bc.step(0.01 - k * 1e-4, 1e-3)
        regs[k] = bc.register
        assert bc.target == approx((100 - k) * UM)
    assert regs[1] == approx(10 * UM)       # target 99: ramping
    assert regs[5] == approx(50 * UM)       # target 95
    assert regs[9] == approx(90 * UM)       # target 91
    assert regs[10] == approx(90 * UM)      # caught up with target 90
    assert regs[11] == approx(89 * UM)      # now follows the target down
    assert regs[20] == approx(80 * UM)
    assert all(abs(regs[k + 1] - regs[k]) <= 10 * UM + TOL for k in range(1, 20))


def test_zero_takeup_rate_is_a_step_and_dt_zero_holds_ramp():
    bc = make(distance=50 * UM, takeup_rate=0.0)
    bc.step(1 * MM, 1e-3)
    bc.step(0.5 * MM, 0.0)
    assert bc.register == 50 * UM                # step even with dt = 0
    bc2 = make(distance=50 * UM, takeup_rate=0.01)
    bc2.step(1 * MM, 1e-3)
    bc2.step(0.5 * MM, 0.0)
    assert bc2.direction == -1 and bc2.register == 0.0
    assert bc2.active                           # still ramping toward 50 um


def test_reset_and_first_step_without_reset():
    bc = make(distance=50 * UM, takeup_rate=0.0)
    bc.step(1 * MM, 1e-3)
    bc.step(0.5 * MM, 1e-3)
    assert bc.register == 50 * UM
    bc.reset(0.2 * MM)                          # e.g. after an abort
    assert bc.direction == +1 and bc.register == 0.0 and not bc.active
    assert reversal_reference(bc) == 0.2 * MM
    bc.step(0.1 * MM, 1e-3)                     # reversal counted from the reset point
    assert bc.direction == -1

    fresh = BacklashCompensation(config(distance=50 * UM, takeup_rate=0.0))
    assert fresh.step(1 * MM, 1e-3) == 0.0      # first step = reset there
    assert fresh.direction == +1 and reversal_reference(fresh) == 1 * MM


# 6. bad configuration is refused (by the register table) and the previous one keeps working
@pytest.mark.parametrize("bad", [
    dict(distance=99 * UM, takeup_rate=-0.01),
    dict(distance=float("nan")),
    dict(distance=float("inf")),
    dict(takeup_rate=float("nan")),
    dict(hysteresis=-1 * UM),
    dict(hysteresis=float("nan")),
    dict(distance=True),
    dict(distance="50e-6"),
    dict(backlash_table=[1 * UM, 2 * UM], backlash_table_spacing=0.0),
    dict(backlash_table=[1 * UM], backlash_table_spacing=-0.01),
    dict(leadscrew_table=[0.0, 1 * UM], leadscrew_table_spacing=0.0),
    dict(leadscrew_table=[0.0, float("nan")], leadscrew_table_spacing=0.01),
    dict(leadscrew_table="abc", leadscrew_table_spacing=0.01),
    dict(leadscrew_table=[0.0, None], leadscrew_table_spacing=0.01),
    dict(backlash_table=5.0, backlash_table_spacing=0.01),
])
def test_bad_configuration_raises_and_keeps_previous(bad):
    bc = make(distance=50 * UM, takeup_rate=0.0, hysteresis=4 * UM,
              leadscrew_table=[0.0, 10 * UM], leadscrew_table_spacing=0.01)
    with pytest.raises(ValueError):
        bc.configure(config(**bad))
    assert (bc.distance, bc.takeup_rate, bc.hysteresis) == (50 * UM, 0.0, 4 * UM)
    bc.step(1 * MM, 1e-3)
    # 10 um back > 4 um hysteresis: step to 50 um; leadscrew(0.99 mm) = 0.99 um
    assert bc.step(0.99 * MM, 1e-3) == approx(-50 * UM + 0.99 * UM)
    assert bc.register == 50 * UM


def test_bad_step_arguments_raise_without_changing_state():
    bc = make(distance=50 * UM, takeup_rate=0.01)
    bc.step(1 * MM, 1e-3)
    for pos, dt in ((float("nan"), 1e-3), (0.5 * MM, -1e-3), (0.5 * MM, float("inf"))):
        with pytest.raises(ValueError):
            bc.step(pos, dt)
    assert bc.direction == +1 and bc.register == 0.0
    assert reversal_reference(bc) == 1 * MM and bc.nominal_position == 1 * MM
    assert math.isfinite(bc.correction)
