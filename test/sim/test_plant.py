"""The backlash slide plant: what it must conserve and show (issue 2)."""
import math

import pytest

from motion_ctrl.sim.plant import SlidePlant
from kit import COUNT, INCH


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


# -- the amplifier's command watchdog (issue 11) ----------------------------------------------
def cruise(p, volts=1.5, seconds=0.4, dt=1e-3):
    """Drive with a command every cycle, as a live controller does."""
    for _ in range(round(seconds / dt)):
        p.command(volts)
        p.advance(dt)


def test_watchdog_drives_the_last_command_for_command_timeout_then_0_volts():
    p = SlidePlant(command_timeout=0.005)
    assert p.tripped                               # no command yet: output 0
    cruise(p)
    assert not p.tripped and p.volts == 1.5
    ages = []
    for _ in range(10):                            # the controller is gone
        p.advance(1e-3)
        ages.append(p.tripped)
    # The last command drove 5 cycles (1 in cruise), then 0 V.
    assert ages == [False] * 4 + [True] * 6
    assert p.volts == 0.0
    p.command(0.7)                                 # commands again: it drives them at once
    p.advance(1e-3)
    assert not p.tripped and p.volts == 0.7
    p.advance(0.05, cycle=1e-3)                    # a late cycle (the plant held up) counts 2
    p.advance(1e-3, cycle=1e-3)
    assert not p.tripped
    p.advance(1e-3, cycle=1e-3)
    assert not p.tripped
    p.advance(1e-3, cycle=1e-3)
    assert p.tripped


def test_watchdog_stops_a_slide_at_max_velocity_within_5_mm():
    """The default timeout and dynamic brake: a slide moving at the default max_velocity
    (0.1 m/s) when its commands stop travels <= 5 mm more and rests within 0.5 s; with the
    dynamic brake off it coasts against friction alone for ~9 mm."""
    from motion_ctrl.sim.harness import Harness

    def after_loss(**plant):
        h = Harness(plant=plant)
        h.axis.move_to(0.3)
        h.run(0.5)
        p = h.plant
        assert p.v_l == pytest.approx(0.1, rel=0.02)     # cruising at max_velocity
        p.command(h.trace.output[-1])        # the last command the axis sent
        x0, rest = p.x_l, None
        for i in range(1, 601):
            p.advance(1e-3)                  # no more commands
            if rest is None and p.tripped and abs(p.v_l) <= 1e-3:
                rest = i * 1e-3
        return p.x_l - x0, rest, p.v_l
    travel, rest, v = after_loss()
    assert travel <= 0.005 and rest <= 0.5 and v == 0.0
    coast, _, _ = after_loss(dynamic_brake=0.0)
    assert coast > 0.008
    late, _, _ = after_loss(command_timeout=0.1)        # the old 100 ms hold
    assert late > 0.005


def test_commanded_cycles_are_the_plain_physics():
    """A command every cycle (lockstep, a live controller) is exactly step(volts, dt)."""
    a, b = SlidePlant(), SlidePlant()
    for i in range(300):
        v = 2.0 if i < 150 else -1.0
        a.command(v)
        a.advance(1e-3)
        b.step(v, 1e-3)
    assert (a.x_m, a.v_m, a.x_l, a.v_l) == (b.x_m, b.v_m, b.x_l, b.v_l)
