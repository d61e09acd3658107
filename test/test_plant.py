"""The backlash slide plant: what it must conserve and show (issue 2)."""
import math

import pytest

from motion_ctrl.plant import SlidePlant
from motion_ctrl.registers import INCH

COUNT = INCH / 10000            # one linear count, 2.54 um


def run(p, volts, seconds, dt=1e-3):
    for _ in range(round(seconds / dt)):
        p.step(volts, dt)


def test_default_scaling_is_the_galil_slide():
    p = SlidePlant()
    # 1 inch = 40,000 rotary counts = 10,000 linear counts.
    assert p.motor_counts_per_m * INCH == pytest.approx(40000)
    assert p.load_counts_per_m * INCH == pytest.approx(10000)
    assert p.params['backlash'] == pytest.approx(20 * COUNT)
    assert 150 < p.resonance_hz < 300          # "a few hundred hertz"


def test_no_drift_at_zero_command():
    p = SlidePlant()
    run(p, 0.0, 2.0)
    assert (p.x_m, p.x_l, p.v_m, p.v_l) == (0.0, 0.0, 0.0, 0.0)
    assert p.encoder_counts() == (0, 0)


def test_stiction_holds_a_small_command():
    # 0.08 V drives ~4.9 N on the screw: less than the motor's breakaway (5.6 N).
    p = SlidePlant()
    assert 0.08 * p._force_per_volt < p.params['motor_stiction'] * 2 * math.pi / p.params['lead']
    run(p, 0.08, 1.0)
    assert p.encoder_counts() == (0, 0)


def test_forward_move_keeps_contact_and_reversal_shows_the_backlash():
    p = SlidePlant(pitch_error_slope=0.0, pitch_error_amplitude=0.0)
    run(p, 1.5, 0.3)
    run(p, 0.0, 0.5)
    m, l = p.x_m, p.x_l
    assert l > 0.01
    # Positive drive: nut on the positive flank, motor and slide agree within the elastic
    # deflection (less than a linear count).
    assert abs(m - l) < COUNT
    run(p, -1.5, 0.15)
    run(p, 0.0, 0.5)
    # After the reversal the slide trails the motor by the whole gap (plus deflection).
    gap = p.x_l - p.x_m
    assert gap == pytest.approx(p.params['backlash'], abs=COUNT)
    mc, lc = p.encoder_counts()
    assert (lc / p.load_counts_per_m - mc / p.motor_counts_per_m) == \
        pytest.approx(p.params['backlash'], abs=2 * COUNT)


def test_amplifier_saturates_at_its_limit():
    a, b = SlidePlant(), SlidePlant()
    run(a, 10.0, 0.05)
    run(b, 50.0, 0.05)
    assert a.x_m == b.x_m and b.volts == 10.0


def test_non_finite_command_is_zero():
    p = SlidePlant()
    run(p, math.nan, 0.1)
    assert p.x_m == 0.0


def test_brake_holds_the_slide_and_end_stop_stops_it():
    p = SlidePlant(brake=1)
    run(p, 3.0, 0.3)
    assert p.x_l == 0.0 and p.x_m - p.x_l < 1e-4          # motor only compresses the screw
    q = SlidePlant(travel_max=0.005)
    run(q, 3.0, 0.5)
    assert q.x_l == pytest.approx(0.005, abs=2 * COUNT)


def test_pitch_error_moves_the_slide_not_the_motor():
    p = SlidePlant(pitch_error_slope=1e-3, pitch_error_amplitude=0.0)
    run(p, 1.5, 0.3)
    run(p, 0.0, 0.5)
    assert p.x_l - p.x_m == pytest.approx(1e-3 * p.x_m, abs=COUNT)


def test_bad_parameters_are_refused_and_change_nothing():
    p = SlidePlant()
    with pytest.raises(ValueError, match='slide_mass'):
        p.configure(slide_mass=-1.0)
    with pytest.raises(ValueError, match='slide_stiction'):
        p.configure(slide_stiction=1.0)            # below Coulomb
    with pytest.raises(ValueError, match='unknown'):
        p.configure(mass=1.0)
    assert p.params['slide_mass'] == 5.0
