"""Unit tests of motion_ctrl.core.servo_law (PMAC PID, RMC I-PD, velocity forms) and of the servo
registers in the register table.

Every expected number is worked by hand from the manuals' equations (RMC Deadband Tolerance;
PMAC Ixx34..Ixx39), in SI units:

    PID   out = kp·FE + I + kvff·CV + kaff·CA − kd·AV + friction_ff·sgn(CV) + bias,
          I += ki·FE·dt (Ixx33), |I| <= integration_limit (Ixx63), FE clipped at Ixx67
    I-PD  CO(n) = CO(n−1) + ki·T·e − kp·Δact − kd·Δ(act vel)

The servo period is T = 1 ms throughout. No ROS.
"""
import math

import numpy as np
import pytest

from kit import COUNT
from motion_ctrl.core import notch
from motion_ctrl.core.registers import AXIS_REGISTERS, CONTROLLER_AXIS, axis_defaults, consistency
from motion_ctrl.core.config import LawConfig, register_fields
from motion_ctrl.core.servo_law import AntiWindupStrategy, ServoLaw

T = 1e-3
HALF_COUNT = 0.5 * COUNT        # half a linear count of the Galil slide, m

# Every register the servo law reads, pinned here so that changes of the table's defaults (the
# tuning is somebody else's) cannot change these hand-worked numbers.
PINNED = dict(mode='position_pid', feedback='dual', kp=0.0, ki=0.0, kd=0.0, kvff=0.0, kaff=0.0,
              friction_ff=0.0, friction_ff_at_rest=0.0, bias=0.0, integration_mode='always',
              integration_limit=10.0, output_limit=10.0, output_deadband=0.0,
              deadband_tolerance=0.0, notch_n1=0.0, notch_n2=0.0, notch_d1=0.0, notch_d2=0.0,
              position_error_limit=0.0)


def law(**registers) -> ServoLaw:
    s = ServoLaw()
    s.configure(LawConfig.of(axis_defaults(AXIS_REGISTERS) | PINNED | registers))
    return s


def tick(s, fe=0.0, *, cmd_vel=0.0, cmd_acc=0.0, act_pos=0.0, act_vel=0.0, vel_loop_vel=0.0,
         vel_loop_acc=0.0, target_stopped=None, half_count=HALF_COUNT):
    """One tick with following error `fe` (cmd_pos = act_pos + fe). The target counts as stopped
    when the commanded velocity is 0, unless told otherwise."""
    if target_stopped is None:
        target_stopped = cmd_vel == 0.0
    return s.update(T, cmd_pos=act_pos + fe, cmd_vel=cmd_vel, cmd_acc=cmd_acc, act_pos=act_pos,
                    act_vel=act_vel, vel_loop_vel=vel_loop_vel, vel_loop_acc=vel_loop_acc,
                    target_stopped=target_stopped, half_count=half_count)


# ---------------------------------------------------------------------------------------------
# Ixx34 integration mode

def test_at_rest_holds_the_integrator_output_during_a_move_and_integrates_at_rest():
    # ki 1e5 V/(m·s), FE 1e-4 m: ki·FE·dt = 0.01 V per tick; 10 ticks at rest -> I = 0.1 V
    s = law(kp=1000.0, ki=1e5, integration_mode='at_rest')
    for _ in range(10):
        tick(s, 1e-4)
    assert s.integral == pytest.approx(0.1, abs=1e-12)
    assert not s.integrator_held
    # commanded move (CV = 10 mm/s), FE 2e-4 m for 20 ticks: input off, output held at 0.1 V --
    # constant and not zero (PMAC: "kept constant ... but is generally not zero")
    for _ in range(20):
        out = tick(s, 2e-4, cmd_vel=0.01)
        assert s.integral == pytest.approx(0.1, abs=1e-12)
        assert s.integrator_held
        assert out == pytest.approx(1000.0 * 2e-4 + 0.1, abs=1e-12)      # 0.3 V
    # at rest again: integrates from the held value, 0.1 + 1e5·2e-4·1e-3 = 0.12 V
    tick(s, 2e-4)
    assert s.integral == pytest.approx(0.12, abs=1e-12)
    assert not s.integrator_held


def test_float_noise_of_a_path_standing_still_is_at_rest():
    """A coordinate that stands still on a path (y along a side of a square) is sampled as
    ~5e-16 m/s: at rest for Ixx34 (the integrator integrates) and for Ixx68 (no friction push)."""
    s = law(kp=1000.0, ki=1e5, friction_ff=0.3, integration_mode='at_rest')
    for noise in (5e-16, -1e-18, 5e-16):
        out = tick(s, 1e-4, cmd_vel=noise, target_stopped=False)
        assert not s.integrator_held
    assert s.integral == pytest.approx(0.03, abs=1e-12)
    assert out == pytest.approx(1000.0 * 1e-4 + 0.03, abs=1e-9)          # no ±0.3 V
    tick(s, 1e-4, cmd_vel=1e-6, target_stopped=False)                      # 1 um/s moves
    assert s.integrator_held


def test_always_integrates_during_a_move():
    s = law(kp=1000.0, ki=1e5, integration_mode='always')
    for _ in range(10):
        tick(s, 1e-4)
    for _ in range(20):
        tick(s, 2e-4, cmd_vel=0.01)
        assert not s.integrator_held
    assert s.integral == pytest.approx(0.1 + 20 * 0.02, abs=1e-12)             # 0.5 V


# ---------------------------------------------------------------------------------------------
# Ixx69 saturation, Ixx63 integration limit, Ixx67 error limit

@pytest.mark.parametrize('mode, strategies', [
    ('position_pid', {'conditional_integration', 'integration_limit', 'wind_down_only'}),
    ('velocity_pid', {'conditional_integration', 'integration_limit', 'wind_down_only'}),
    ('position_ipd', {'state_clamp', 'wind_down_only'}),
    ('velocity_ipd', {'state_clamp', 'wind_down_only'})])
def test_each_law_names_its_anti_windup_strategies(mode, strategies):
    """PMAC's PID integrates conditionally (Ixx69) within its limit (Ixx63); RMC's I-PD clamps
    its one state; both only wind down inside anti-hunting's window (the tests below)."""
    s = law(mode=mode)
    assert all(isinstance(a, AntiWindupStrategy) for a in s.anti_windup)
    assert {a.value for a in s.anti_windup} == strategies


def test_no_wind_up_while_the_output_is_saturated():
    s = law(kp=1e4, ki=1e5, output_limit=10.0)
    for _ in range(10):
        tick(s, 1e-5)                         # 10 × 1e5·1e-5·1e-3 = 0.01 V
    assert s.integral == pytest.approx(0.01, abs=1e-12)
    # FE 1 mm: kp·FE = 10 V + I -> at the limit: nothing is added, for as long as it lasts
    for _ in range(50):
        out = tick(s, 1e-3)
        assert out == 10.0 and s.saturated
        assert s.integral == pytest.approx(0.01, abs=1e-12)
        assert s.integrator_held
    # out of saturation: FE 5e-5 -> 0.5 V + I, integrating again by 1e5·5e-5·1e-3 = 0.005 V
    out = tick(s, 5e-5)
    assert s.integral == pytest.approx(0.015, abs=1e-12)
    assert out == pytest.approx(0.5 + 0.015, abs=1e-12)
    assert not s.saturated and not s.integrator_held


def test_integration_that_would_saturate_the_output_is_not_made():
    # kp·FE + I = 1e4·9.989e-4 + 0.01 = 9.999 V; this tick's ki·FE·dt = 0.09989 V would take
    # the output to 10.099 V: the test is on this tick's output, so the integrator is not changed
    # and the output stays just below the limit.
    s = law(kp=1e4, ki=1e5)
    for _ in range(10):
        tick(s, 1e-5)
    out = tick(s, 9.989e-4)
    assert s.integral == pytest.approx(0.01, abs=1e-12)
    assert out == pytest.approx(9.999, abs=1e-9)
    assert s.integrator_held and not s.saturated


def test_saturation_is_judged_on_the_final_output_after_the_deadband():
    # kp·FE = 9.7 V, deadband 0.4 V -> 10.1 V: saturated, so the integrator input is off even
    # though the loop sum alone is below the limit
    s = law(kp=1e4, ki=1e5, output_deadband=0.4)
    for _ in range(5):
        out = tick(s, 9.7e-4)
        assert out == 10.0 and s.saturated and s.integrator_held
    assert s.integral == 0.0


def test_lowering_the_integration_limit_clamps_a_held_integrator():
    s = law(ki=1e5, integration_mode='at_rest')
    for _ in range(5):
        tick(s, 1e-3)                         # 0.5 V
    s.configure(LawConfig.of(axis_defaults(AXIS_REGISTERS) | PINNED
                             | dict(ki=1e5, integration_mode='at_rest', integration_limit=0.2)))
    assert tick(s, 1e-3, cmd_vel=0.01) == pytest.approx(0.2, abs=1e-12)   # held, but clamped


def test_integration_limit_clamps_the_integrator_output():
    # 0.1 V per tick; Ixx63 = 0.35 V -> 0.1, 0.2, 0.3, 0.35, 0.35 ...
    s = law(kp=100.0, ki=1e5, integration_limit=0.35)
    seen = [tick(s, 1e-3) and s.integral for _ in range(6)]
    assert seen == pytest.approx([0.1, 0.2, 0.3, 0.35, 0.35, 0.35], abs=1e-12)
    assert s.output == pytest.approx(100.0 * 1e-3 + 0.35, abs=1e-12)
    for _ in range(20):                       # and on the negative side
        tick(s, -1e-3)
    assert s.integral == pytest.approx(-0.35, abs=1e-12)


def test_position_error_limit_clips_the_error_seen_by_kp_and_the_integrator():
    # Ixx67 = 0.1 mm: FE 0.5 mm is seen as 0.1 mm -> kp·0.1 mm = 1 V (not 5 V)
    s = law(kp=1e4, position_error_limit=1e-4)
    assert tick(s, 5e-4) == pytest.approx(1.0, abs=1e-12)
    assert tick(s, -5e-4) == pytest.approx(-1.0, abs=1e-12)
    assert tick(s, 5e-5) == pytest.approx(0.5, abs=1e-12)    # inside: unchanged
    s = law(ki=1e5, position_error_limit=1e-4)
    tick(s, 5e-4)
    assert s.integral == pytest.approx(1e5 * 1e-4 * T, abs=1e-12)      # 0.01 V, not 0.05 V
    assert tick(law(kp=1e4), 5e-4) == pytest.approx(5.0, abs=1e-12)    # 0 = off


# ---------------------------------------------------------------------------------------------
# feedforward, bias, damping

def test_friction_feedforward_by_the_sign_of_the_commanded_velocity():
    s = law(friction_ff=0.3)
    assert tick(s, cmd_vel=0.01, act_vel=-0.02) == pytest.approx(0.3, abs=1e-12)
    assert tick(s, cmd_vel=-0.01, act_vel=0.02) == pytest.approx(-0.3, abs=1e-12)
    assert tick(s, cmd_vel=0.0, act_vel=0.02) == 0.0          # at rest: nothing


def test_friction_at_rest_by_the_sign_of_an_error_outside_the_anti_hunting_window():
    """friction_ff_at_rest: once the command has stopped, a slide held short by stiction is
    pushed by the sign of its error, until the error is inside the anti-hunting window (half a
    count, or deadband_tolerance); never while the command moves or the target is not stopped,
    nor in a velocity mode, nor where the position loop is on the motor encoder (motor,
    sampled: the motor's error, free inside a backlash gap, made the axis hunt)."""
    s = law(friction_ff=0.3, friction_ff_at_rest=0.2)
    assert tick(s, 3 * HALF_COUNT) == pytest.approx(0.2, abs=1e-12)       # short: pushed on
    assert tick(s, -3 * HALF_COUNT) == pytest.approx(-0.2, abs=1e-12)     # long: pushed back
    assert tick(s, 0.9 * HALF_COUNT) == 0.0                               # inside the window
    assert tick(s, 3 * HALF_COUNT, cmd_vel=0.01) == pytest.approx(0.3, abs=1e-12)   # Ixx68
    assert tick(s, 3 * HALF_COUNT, target_stopped=False) == 0.0           # still settling in
    s = law(friction_ff_at_rest=0.2, deadband_tolerance=10 * HALF_COUNT)
    assert tick(s, 3 * HALF_COUNT) == 0.0                                 # the wider window
    assert tick(law(friction_ff_at_rest=0.2, mode='velocity_pid'), 3 * HALF_COUNT) == 0.0
    assert tick(law(friction_ff=0.3), 3 * HALF_COUNT) == 0.0             # off by default
    # only on the slide's encoder: the loop on load (as dual) pushes, the motor loops do not
    assert tick(law(friction_ff_at_rest=0.2, feedback='load'), 3 * HALF_COUNT) == \
        pytest.approx(0.2, abs=1e-12)
    for feedback in ('motor', 'sampled'):
        assert tick(law(friction_ff_at_rest=0.2, feedback=feedback), 3 * HALF_COUNT) == 0.0


def test_bias_is_added():
    assert tick(law(bias=0.5)) == pytest.approx(0.5, abs=1e-12)
    assert tick(law(bias=-0.25, kp=1e3), 1e-4) == pytest.approx(-0.25 + 0.1, abs=1e-12)


def test_velocity_and_acceleration_feedforward_contributions():
    # kvff·CV = 200 V·s/m × 0.01 m/s = 2 V; kaff·CA = 0.6 V·s²/m × 2 m/s² = 1.2 V
    assert tick(law(kvff=200.0), cmd_vel=0.01) == pytest.approx(2.0, abs=1e-12)
    assert tick(law(kaff=0.6), cmd_acc=2.0) == pytest.approx(1.2, abs=1e-12)
    assert tick(law(kvff=200.0, kaff=0.6), cmd_vel=0.01, cmd_acc=2.0) == \
        pytest.approx(3.2, abs=1e-12)
    assert tick(law(kvff=200.0, kaff=0.6), cmd_vel=-0.01, cmd_acc=-2.0) == \
        pytest.approx(-3.2, abs=1e-12)


def test_kd_acts_on_the_velocity_loop_encoder():
    # dual loop: the position-loop (load) encoder says 1 mm/s, the velocity-loop (motor) encoder
    # 4 mm/s: −kd·AV uses the latter, −250 × 0.004 = −1 V
    s = law(kd=250.0)
    assert tick(s, act_vel=0.001, vel_loop_vel=0.004) == pytest.approx(-1.0, abs=1e-12)
    assert tick(s, act_vel=-0.05, vel_loop_vel=0.004) == pytest.approx(-1.0, abs=1e-12)
    # PMAC form: derivative of the error = kvff = kd (CV − AV)
    s = law(kd=250.0, kvff=250.0)
    assert tick(s, cmd_vel=0.004, vel_loop_vel=0.004) == pytest.approx(0.0, abs=1e-12)


# ---------------------------------------------------------------------------------------------
# RMC output deadband and deadband tolerance (seed 000)

def test_ratioed_deadband_through_the_servo_law():
    # deadband 0.4 V, tolerance 0.1 mm; FE = tolerance/2 -> half the deadband, 0.2 V
    regs = dict(kp=1e4, output_deadband=0.4, deadband_tolerance=1e-4)
    assert tick(law(**regs), 5e-5) == pytest.approx(0.5 + 0.2, abs=1e-12)
    assert tick(law(**regs), -5e-5) == pytest.approx(-0.5 - 0.2, abs=1e-12)
    assert tick(law(**regs), 2.5e-5) == pytest.approx(0.25 + 0.1, abs=1e-12)
    # full deadband outside the tolerance, and while the target moves
    assert tick(law(**regs), 2e-4) == pytest.approx(2.0 + 0.4, abs=1e-12)
    assert tick(law(**regs), 5e-5, target_stopped=False) == pytest.approx(0.5 + 0.4, abs=1e-12)
    # no tolerance: full deadband
    assert tick(law(kp=1e4, output_deadband=0.4), 5e-5) == pytest.approx(0.9, abs=1e-12)


def test_anti_hunting_lets_the_integral_shrink_but_never_grow():
    regs = dict(ki=1e5, deadband_tolerance=1e-4)
    s = law(**regs)
    for _ in range(10):                       # target moving: integrates normally, 0.01 V/tick
        tick(s, 1e-4, cmd_vel=0.01)
    assert s.integral == pytest.approx(0.1, abs=1e-12) and not s.anti_hunting
    # target stopped, |FE| = 5e-5 < tolerance, same sign: growth refused, integral held
    for _ in range(10):
        tick(s, 5e-5)
        assert s.anti_hunting and s.integrator_held
        assert s.integral == pytest.approx(0.1, abs=1e-12)
    # opposite sign: winds down by 1e5·5e-5·1e-3 = 0.005 V per tick
    for k in range(1, 5):
        tick(s, -5e-5)
        assert s.integral == pytest.approx(0.1 - 0.005 * k, abs=1e-12)
        assert s.anti_hunting and not s.integrator_held
    # a step that would cross zero stops at zero, never beyond
    s2 = law(ki=1e7, deadband_tolerance=1e-4)
    tick(s2, 1e-6, cmd_vel=0.01)              # 1e7·1e-6·1e-3 = 0.01 V
    tick(s2, -5e-5)                           # would be 0.01 − 0.5 = −0.49 V
    assert s2.integral == 0.0
    tick(s2, -5e-5)                           # and from 0 it may not grow either way
    assert s2.integral == 0.0 and s2.integrator_held
    # outside the tolerance it integrates as usual
    tick(s, 2e-4)
    assert s.integral == pytest.approx(0.08 + 0.02, abs=1e-12) and not s.anti_hunting


def test_anti_hunting_half_count_window_with_zero_tolerance():
    s = law(ki=1e5)
    tick(s, 1e-6)                             # |FE| < half a count (1.27 um): anti-hunting
    assert s.anti_hunting and s.integral == 0.0
    tick(s, COUNT)                          # a whole count: integrates
    assert not s.anti_hunting and s.integral == pytest.approx(1e5 * COUNT * T, abs=1e-15)


# ---------------------------------------------------------------------------------------------
# RMC I-PD

def test_ipd_target_step_has_no_proportional_kick():
    # target jumps 1 mm with the axis at rest: PID would output kp·e = 30 V (clipped to 10 V);
    # I-PD outputs ki·T·e = 1e6·1e-3·1e-3 = 1 V, then 2 V, ...
    regs = dict(kp=3e4, ki=1e6, kd=200.0)
    s = law(mode='position_ipd', **regs)
    assert tick(s, 1e-3) == pytest.approx(1.0, abs=1e-12)
    assert tick(s, 1e-3) == pytest.approx(2.0, abs=1e-12)
    assert tick(law(mode='position_pid', **regs), 1e-3) == 10.0
    # the axis moves 10 um at 10 mm/s: CO = 2 + 1e6·1e-3·(0.99e-3) − 3e4·1e-5 − 200·0.01
    #                                      = 2 + 0.99 − 0.3 − 2.0 = 0.69 V
    out = s.update(T, cmd_pos=1e-3, cmd_vel=0.0, cmd_acc=0.0, act_pos=1e-5, act_vel=0.01,
                   vel_loop_vel=0.01, vel_loop_acc=10.0, target_stopped=True,
                   half_count=HALF_COUNT)
    assert out == pytest.approx(0.69, abs=1e-12)


def test_ipd_output_clamp_prevents_wind_up():
    s = law(mode='position_ipd', ki=1e6, output_limit=5.0)
    for _ in range(100):                      # 1 V per tick: reaches 5 V and stays clamped
        out = tick(s, 1e-3)
    assert out == 5.0 and s.integral == 5.0 and s.integrator_held and s.saturated
    # error reversed: the output comes down on the very next tick (no wound-up excess)
    assert tick(s, -1e-3) == pytest.approx(4.0, abs=1e-12)
    # with a feedforward the clamp leaves room for it: CO + ff within ±limit
    s = law(mode='position_ipd', ki=1e6, output_limit=5.0, bias=2.0)
    for _ in range(100):
        tick(s, 1e-3)
    assert s.integral == pytest.approx(3.0, abs=1e-12) and s.output == 5.0
    for _ in range(100):
        tick(s, -1e-3)
    assert s.integral == pytest.approx(-7.0, abs=1e-12) and s.output == -5.0


def test_ipd_anti_hunting_only_winds_down():
    s = law(mode='position_ipd', ki=1e5, deadband_tolerance=1e-4)
    for _ in range(10):
        tick(s, 1e-4, cmd_vel=0.01, target_stopped=False)     # CO = 0.1 V
    tick(s, 5e-5)
    assert s.integral == pytest.approx(0.1, abs=1e-12) and s.integrator_held
    tick(s, -5e-5)
    assert s.integral == pytest.approx(0.095, abs=1e-12)
    # from CO = 0 it may not grow in either direction, nor cross zero
    s = law(mode='position_ipd', ki=1e5, deadband_tolerance=1e-4)
    tick(s, 5e-5)
    assert s.integral == 0.0 and s.integrator_held
    tick(s, -5e-5)
    assert s.integral == 0.0
    s = law(mode='position_ipd', ki=1e7, deadband_tolerance=1e-4)
    tick(s, 1e-6, target_stopped=False)       # CO = 0.01 V
    tick(s, -5e-5)                            # would be 0.01 − 0.5 V
    assert s.integral == 0.0


# ---------------------------------------------------------------------------------------------
# velocity modes

def test_velocity_pid_acts_on_the_velocity_error():
    # kp 100 V·s/m × (0.05 − 0.03) m/s = 2 V; a position error is ignored
    s = law(mode='velocity_pid', kp=100.0)
    assert s.update(T, cmd_pos=1.0, cmd_vel=0.05, cmd_acc=0.0, act_pos=0.0, act_vel=0.03,
                    vel_loop_vel=0.03, vel_loop_acc=0.0, target_stopped=False,
                    half_count=HALF_COUNT) == pytest.approx(2.0, abs=1e-12)
    # ki 1000 V/m: 1000 × 0.02 × 1e-3 = 0.02 V per tick; kd 2 V·s²/m on the velocity-loop
    # acceleration 0.5 m/s² -> −1 V
    s = law(mode='velocity_pid', ki=1000.0, kd=2.0)
    for _ in range(5):
        out = tick(s, cmd_vel=0.05, act_vel=0.03, vel_loop_acc=0.5)
    assert s.integral == pytest.approx(0.1, abs=1e-12)
    assert out == pytest.approx(0.1 - 1.0, abs=1e-12)


def test_velocity_ipd_acts_on_the_velocity_error_without_a_kick():
    s = law(mode='velocity_ipd', kp=100.0, ki=1000.0)
    # target velocity steps to 0.05 m/s: ki·T·e = 1000·1e-3·0.05 = 0.05 V (not kp·e = 5 V)
    assert tick(s, cmd_vel=0.05) == pytest.approx(0.05, abs=1e-12)
    # actual velocity rises by 0.01: 0.05 + 1000·1e-3·0.04 − 100·0.01 = −0.91 V
    assert tick(s, cmd_vel=0.05, act_vel=0.01) == pytest.approx(-0.91, abs=1e-12)


# ---------------------------------------------------------------------------------------------
# notch (design numbers are test_notch.py's; here: the registers filter the loop output)

def _notch_registers(f, servo_period=T):
    c = notch.design(0.9 * f, 0.05, 1.2 * f, 0.7, servo_period, prewarp=True)
    return dict(zip(('notch_n1', 'notch_n2', 'notch_d1', 'notch_d2'), c)), c


def _amplitude(s, f, n_settle=400, n_fit=2000):
    k = np.arange(n_settle + n_fit)
    fe = 1e-5 * np.sin(2 * math.pi * f * T * k)
    y = np.array([tick(s, float(e)) for e in fe])[n_settle:]
    kk = k[n_settle:]
    basis = np.column_stack([np.sin(2 * math.pi * f * T * kk), np.cos(2 * math.pi * f * T * kk)])
    (a, b), *_ = np.linalg.lstsq(basis, y, rcond=None)
    return math.hypot(a, b)


def test_notch_registers_filter_the_loop_output():
    f = 200.0
    regs, coeffs = _notch_registers(f)
    plain = _amplitude(law(kp=1e4), f)            # kp·1e-5 m = 0.1 V
    filtered = _amplitude(law(kp=1e4, **regs), f)
    assert plain == pytest.approx(0.1, rel=1e-9)
    predicted = 10 ** (notch.gain_db(coeffs, f, T) / 20)
    print(f'\nnotch at {f:g} Hz: loop output {plain:.4f} V -> {filtered:.5f} V '
          f'({20 * math.log10(filtered / plain):.1f} dB, designed '
          f'{notch.gain_db(coeffs, f, T):.1f} dB)')
    assert filtered / plain == pytest.approx(predicted, rel=0.01)
    assert filtered / plain < 10 ** (-10 / 20)      # at least 10 dB down
    # unity DC gain: a constant error gives kp·FE
    s = law(kp=1e4, **regs)
    for _ in range(300):
        out = tick(s, 1e-4)
    assert out == pytest.approx(1.0, abs=1e-9)


def test_notch_is_before_the_deadband_and_the_limit():
    regs, _ = _notch_registers(200.0)
    s = law(kp=1e4, output_deadband=0.4, **regs)
    g = s.notch.numerator_gain                       # first-sample gain of the filter
    # first tick of an error step: filter output g·kp·FE, then the full deadband, unfiltered
    assert tick(s, 1e-4) == pytest.approx(g * 1.0 + 0.4, abs=1e-12)
    # a large error: whatever the filter transient, the output is clipped at the limit
    s = law(kp=1e6, **regs)
    assert all(abs(tick(s, 1e-3 * (-1) ** k)) <= 10.0 for k in range(50))


def test_reset_and_mode_change_clear_the_state():
    s = law(kp=1e3, ki=1e5)
    for _ in range(5):
        tick(s, 1e-4)
    assert s.integral != 0.0
    s.reset()
    assert (s.integral, s.output, s.saturated, s.integrator_held) == (0.0, 0.0, False, False)
    for _ in range(5):
        tick(s, 1e-4)
    s.configure(LawConfig.of(axis_defaults(AXIS_REGISTERS) | PINNED
                             | dict(mode='position_ipd', ki=1e5)))
    assert s.integral == 0.0
    assert tick(s, 1e-4) == pytest.approx(0.01, abs=1e-12)


# ---------------------------------------------------------------------------------------------
# the register table: every register the servo law reads

def servo_law_registers() -> set:
    """The registers the servo law reads: the fields of its typed configuration."""
    return set(register_fields(LawConfig))


# unit and vendor register of each, from the manuals (PMAC Ixx, RMC, Galil)
EXPECTED = {
    'mode': ('', 'RMC'), 'feedback': ('', 'Galil DV'), 'kp': ('V/m', 'Ixx30'),
    'ki': ('V/(m·s)', 'Ixx33'),
    'kd': ('V·s/m', 'Ixx31'), 'kvff': ('V·s/m', 'Ixx32'), 'kaff': ('V·s²/m', 'Ixx35'),
    'friction_ff': ('V', 'Ixx68'), 'friction_ff_at_rest': ('V', 'Ixx68'), 'bias': ('V', 'Ixx29'),
    'integration_mode': ('', 'Ixx34'),
    'integration_limit': ('V', 'Ixx63'), 'output_limit': ('V', 'Ixx69'),
    'output_deadband': ('V', 'RMC'), 'deadband_tolerance': ('m', 'RMC'),
    'notch_n1': ('', 'Ixx36'), 'notch_n2': ('', 'Ixx37'), 'notch_d1': ('', 'Ixx38'),
    'notch_d2': ('', 'Ixx39'), 'position_error_limit': ('m', 'Ixx67'),
    'following_error_warning': ('m', 'Ixx12'), 'following_error_fatal': ('m', 'Ixx11'),
}


def test_every_servo_register_is_declared_with_unit_vendor_and_range():
    used = servo_law_registers()
    assert used <= set(EXPECTED), f'registers not checked here: {used - set(EXPECTED)}'
    assert used == set(EXPECTED) - {'following_error_warning', 'following_error_fatal'}
    for name, (unit, vendor) in EXPECTED.items():
        reg = CONTROLLER_AXIS.get(name)
        assert reg is not None, f'{name} is not declared in registers.py'
        assert reg.unit == unit, f'{name}: unit {reg.unit!r}, expected {unit!r}'
        assert reg.vendor and vendor in reg.vendor, f'{name}: vendor {reg.vendor!r}'
        assert reg.description
        if reg.type == 'string':
            assert reg.choices, f'{name}: a string register needs its choices'
        else:
            assert reg.type == 'double'
            assert reg.min is not None, f'{name}: no range'
        assert reg.check(reg.default) is None, f'{name}: default refused'
        text = reg.descriptor_text()
        if unit:
            assert f'Unit: {unit}.' in text
        assert vendor in text
    assert set(CONTROLLER_AXIS['mode'].choices) == {'position_pid', 'position_ipd',
                                                    'velocity_pid', 'velocity_ipd'}
    assert set(CONTROLLER_AXIS['integration_mode'].choices) == {'always', 'at_rest'}
    for n in ('notch_n1', 'notch_n2', 'notch_d1', 'notch_d2'):
        assert (CONTROLLER_AXIS[n].min, CONTROLLER_AXIS[n].max) == (-2.0, 2.0)


@pytest.mark.parametrize('name, value', [
    ('deadband_tolerance', -1e-6), ('output_deadband', -0.1), ('integration_limit', -1.0),
    ('position_error_limit', -1e-3), ('following_error_fatal', -1e-3), ('kp', -1.0),
    ('ki', -1.0), ('kd', -1.0), ('output_limit', 10.5), ('friction_ff', 11.0),
    ('kp', math.nan), ('ki', math.inf), ('deadband_tolerance', math.nan), ('bias', -math.inf),
    ('mode', 'position_pi'), ('mode', 'torque'), ('integration_mode', 'sometimes'),
    ('notch_n1', 2.5), ('notch_n2', -2.01), ('notch_d1', 3.0), ('notch_d2', math.nan),
    ('kp', '30000'), ('mode', 1),
])
def test_bad_values_are_refused_with_a_reason_naming_the_register(name, value):
    reason = CONTROLLER_AXIS[name].check(value)
    assert reason is not None and reason.startswith(f'{name}')


def test_an_unstable_notch_within_the_register_range_is_refused_by_consistency():
    # each coefficient within ±2, but 1 + 1.5 z^-1 − 0.6 z^-2 has a root outside |z| < 1
    v = axis_defaults(AXIS_REGISTERS) | dict(notch_d1=1.5, notch_d2=-0.6)
    assert all(CONTROLLER_AXIS[n].check(v[n]) is None for n in ('notch_d1', 'notch_d2'))
    reasons = consistency(v)
    assert any('notch' in r and 'unstable' in r for r in reasons), reasons
    # a designed notch passes
    regs, _ = _notch_registers(200.0)
    assert consistency(axis_defaults(AXIS_REGISTERS) | regs) == []
