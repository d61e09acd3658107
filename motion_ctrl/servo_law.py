"""The servo filter of one axis: PMAC PID and Delta RMC I-PD, position and velocity forms.

PMAC PID (Turbo PMAC User Manual, "Actual PID algorithm"), restated in SI units so the gains do
not change with the servo period:

    out = kp·FE + I + kvff·CV + kaff·CA − kd·AV + friction_ff·sgn(CV) + bias
    I  += ki·FE·dt   (Ixx33) while integration is active, |I| <= integration_limit (Ixx63)

FE = commanded − actual position of the position-loop encoder, clipped at position_error_limit
(Ixx67); CV, CA = commanded velocity, acceleration; AV = actual velocity of the velocity-loop
encoder, which may be another encoder (PMAC Ixx04 / Galil DV: that is the dual loop). Kd on the
actual velocity, not the error, as PMAC does: set kvff = kd for a derivative on the error.

Integration (Ixx34): `always`, or `at_rest` — the integrator *input* is off while the commanded
velocity is non-zero, so its output is held, not zeroed. Independently, nothing is added while the
output is saturated at output_limit (Ixx69), and with the RMC anti-hunting rule active the
integral term may only wind down.

Delta RMC I-PD, incremental form (P and D act on the measurement only, so a target step moves the
axis through the integral alone, without overshoot, and a saturated output does not disturb it):

    CO(n) = CO(n−1) + ki·dt·(target − act) − kp·Δact − kd·Δ(act velocity)

and the same one derivative up for velocity I-PD. Velocity PID acts on the velocity error with the
same registers (kp V·s/m, ki V/m, kd V·s²/m).

The notch (Ixx36..39) filters the loop output before the deadband and the output limit, as in PMAC.
"""
from __future__ import annotations

import math

from motion_ctrl import deadband as db
from motion_ctrl.notch import Biquad


def _sign(v: float) -> float:
    return (v > 0.0) - (v < 0.0)


class ServoLaw:
    """One axis' servo filter. `configure(values)` takes the register values (a dict with the
    keys of registers.AXIS_REGISTERS); `update(...)` computes one tick's output in volts."""

    def __init__(self):
        self.notch = Biquad()
        self.integral = 0.0          # PID integrator output [V]
        self.co = 0.0                # I-PD controller output state [V]
        self.prev_act = None         # I-PD: previous actual position (or velocity)
        self.prev_act_vel = None     # I-PD: previous actual velocity (or acceleration)
        self.output = 0.0
        self.saturated = False
        self.integrator_held = False
        self.anti_hunting = False
        self.r = None

    def configure(self, r: dict) -> None:
        self.notch.configure(r['notch_n1'], r['notch_n2'], r['notch_d1'], r['notch_d2'])
        if self.r is not None and r['mode'] != self.r['mode']:
            self.reset()             # a new control law starts from rest (bumpless from 0)
        self.r = r

    def reset(self) -> None:
        """Open loop / new mode: clear the integrators and filter history."""
        self.integral = 0.0
        self.co = 0.0
        self.prev_act = self.prev_act_vel = None
        self.notch.reset(0.0)
        self.output = 0.0
        self.saturated = self.integrator_held = self.anti_hunting = False

    def update(self, dt: float, *, cmd_pos: float, cmd_vel: float, cmd_acc: float,
               act_pos: float, act_vel: float, vel_loop_vel: float, vel_loop_acc: float,
               target_stopped: bool, half_count: float) -> float:
        """One servo tick. act_pos/act_vel: the position-loop encoder; vel_loop_vel/acc: the
        velocity-loop encoder (same as act_* unless dual loop). Returns the output [V]."""
        r = self.r
        mode = r['mode']
        position_mode = mode.startswith('position')
        if position_mode:
            error = cmd_pos - act_pos
            lim = r['position_error_limit']
            if lim > 0.0:
                error = max(-lim, min(lim, error))
        else:
            error = cmd_vel - act_vel
        # RMC anti-hunting: target stopped and inside the tolerance (or half a raw count).
        self.anti_hunting = position_mode and db.anti_hunting(
            target_stopped, cmd_pos - act_pos, r['deadband_tolerance'], half_count)
        feedforward = (r['kvff'] * cmd_vel + r['kaff'] * cmd_acc
                       + r['friction_ff'] * _sign(cmd_vel) + r['bias'])
        limit = r['output_limit']

        if mode.endswith('pid'):
            integrate = not (r['integration_mode'] == 'at_rest' and cmd_vel != 0.0)
            proposed = self.integral + r['ki'] * error * dt if integrate else self.integral
            il = r['integration_limit']
            proposed = max(-il, min(il, proposed))
            if self.anti_hunting:
                proposed = db.limit_integral_to_wind_down(self.integral, proposed)
            if position_mode:
                loop = r['kp'] * error - r['kd'] * vel_loop_vel
            else:
                loop = r['kp'] * error - r['kd'] * vel_loop_acc
            # No integration while the output is saturated (PMAC: whenever it saturates at Ixx69).
            saturating = abs(loop + proposed + feedforward) >= limit
            if saturating:
                proposed = self.integral
            self.integrator_held = not integrate or saturating or (
                self.anti_hunting and proposed != self.integral + r['ki'] * error * dt)
            self.integral = proposed
            out = self.notch.step(loop + self.integral + feedforward)
        else:
            # I-PD, incremental: the state CO carries I, P and D together.
            meas = act_pos if position_mode else act_vel
            meas_rate = vel_loop_vel if position_mode else vel_loop_acc
            if self.prev_act is None:
                self.prev_act, self.prev_act_vel = meas, meas_rate
            inc_i = r['ki'] * dt * error
            if self.anti_hunting and _sign(inc_i) == _sign(self.co):
                inc_i = 0.0                 # may only wind down
            co = (self.co + inc_i - r['kp'] * (meas - self.prev_act)
                  - r['kd'] * (meas_rate - self.prev_act_vel))
            self.prev_act, self.prev_act_vel = meas, meas_rate
            room = limit - abs(feedforward)
            co_clamped = max(-max(room, 0.0), min(max(room, 0.0), co))
            self.integrator_held = co_clamped != co
            self.co = co_clamped
            out = self.notch.step(self.co + feedforward)

        # RMC output deadband (with ratioing inside the deadband tolerance).
        out = db.output_deadband(out, r['output_deadband'], cmd_pos - act_pos if position_mode
                                 else error, r['deadband_tolerance'], target_stopped,
                                 position_mode)
        self.saturated = abs(out) >= limit
        out = max(-limit, min(limit, out))
        self.output = out
        return out
