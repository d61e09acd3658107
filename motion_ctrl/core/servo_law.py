"""The servo filter of one axis: PMAC PID and Delta RMC I-PD, position and velocity forms.

PMAC PID (Turbo PMAC User Manual, "Actual PID algorithm"), restated in SI units so the gains do
not change with the servo period:

    out = kp·FE + I + kvff·CV + kaff·CA − kd·AV + friction_ff·sgn(CV) + bias
    I  += ki·FE·dt   (Ixx33) while the integrator input is on, |I| <= integration_limit (Ixx63)

FE = commanded − actual position of the position-loop encoder, clipped at ±position_error_limit
(Ixx67, 0 = off) before it reaches kp and the integrator; CV, CA = commanded velocity and
acceleration; AV = actual velocity of the velocity-loop encoder, which may be another encoder
(PMAC Ixx04 / Galil DV: that is the dual loop). Kd acts on the actual velocity, not on the error,
as PMAC does: set kvff = kd for a derivative of the error. friction_ff (Ixx68) is added by the
sign of the *commanded* velocity, 0 at rest.

The integrator input is off (INTEGRATOR_HELD; its output is held, never zeroed) when
 * integration_mode is `at_rest` (Ixx34 = 1) and the commanded velocity is non-zero;
 * the output would saturate at output_limit (Ixx69) with this tick's integration: PMAC adds
   nothing to the integrator whenever the total control output saturates. The test is made on
   the final output (after notch and deadband), before committing, so the integrator never
   changes on a tick whose output is at the limit;
 * RMC anti-hunting (position modes; target stopped and |position error| < deadband_tolerance or
   < ½ raw count) would make the integral grow: it may only wind down toward 0 (not past it).
   The flag is raised when the rule actually restricts the integration.
Reaching integration_limit is a clamp of the integrator output, not "input off".

Delta RMC I-PD, incremental form (P and D act on the measurement only, so a target step moves the
axis through the integral alone, without a proportional kick or overshoot):

    CO(n) = CO(n−1) + ki·dt·(target − act) − kp·Δact − kd·Δ(act velocity)

The state CO is the one integrator of this form (`integral` reports it). It is clamped so that
CO + feedforward + output deadband stays within ±output_limit: a saturated output does not wind
it up. Anti-hunting restricts the ki·dt·e increment so that CO may only move toward 0; the P and
D increments are never restricted. integration_mode (Ixx34) and integration_limit (Ixx63) are
PMAC PID registers and do not apply to I-PD (its integral is its only driving term).
Velocity I-PD is the same one derivative up (target/actual velocity, kd on Δ acceleration of the
velocity-loop encoder). Velocity PID acts on the velocity error with the same registers
(kp V·s/m, ki V/m, kd V·s²/m on the velocity-loop acceleration); integration_mode applies to it
as written (input off while the commanded velocity is non-zero). Anti-hunting and deadband
ratioing are position-mode rules (RMC); in velocity modes a non-zero deadband_tolerance turns the
deadband off while the target velocity is zero (motion_ctrl.core.deadband).

Order, as in PMAC + RMC: loop sum → notch (Ixx36..39, unity DC gain) → output deadband (with
ratioing) → output limit.
"""
from __future__ import annotations

from motion_ctrl.core import deadband as db
from motion_ctrl.core.notch import Biquad


def _sign(v: float) -> float:
    return (v > 0.0) - (v < 0.0)


def _clamp(v: float, lo: float, hi: float) -> float:
    return lo if v < lo else hi if v > hi else v


class ServoLaw:
    """One axis' servo filter. `configure(values)` takes the register values (a dict with the
    keys of registers.AXIS_REGISTERS); `update(...)` computes one tick's output in volts."""

    def __init__(self):
        self.notch = Biquad()
        # Last two inputs / outputs fed to / returned by the notch, to predict its next output
        # (`_notch_peek`) without stepping it: the saturation test needs the output first.
        self._hist = (0.0, 0.0, 0.0, 0.0)
        self._nc = (1.0, 0.0, 0.0, 0.0, 0.0)
        self.integral = 0.0          # PID integrator output [V]; I-PD: CO
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
        n1, n2, d1, d2 = self.notch.coefficients
        g = self.notch.numerator_gain
        self._nc = (g, g * n1, g * n2, d1, d2)
        if self.r is not None and r['mode'] != self.r['mode']:
            self.reset()             # a new control law starts from rest (bumpless from 0)
        self.r = r

    def reset(self) -> None:
        """Open loop / new mode: clear the integrators and filter history."""
        self.integral = 0.0
        self.co = 0.0
        self.prev_act = self.prev_act_vel = None
        self.notch.reset(0.0)
        self._hist = (0.0, 0.0, 0.0, 0.0)
        self.output = 0.0
        self.saturated = self.integrator_held = self.anti_hunting = False

    # -- notch with look-ahead ----------------------------------------------------------------
    def _notch_peek(self, x: float) -> float:
        """What `self.notch.step(x)` would return, without advancing it (same difference
        equation, from the history this object fed it)."""
        g, b1, b2, a1, a2 = self._nc
        x1, x2, y1, y2 = self._hist
        return g * x + b1 * x1 + b2 * x2 - a1 * y1 - a2 * y2

    def _notch_step(self, x: float) -> float:
        y = self.notch.step(x)
        x1, _, y1, _ = self._hist
        self._hist = (x, x1, y, y1)
        return y

    # -- the tick -----------------------------------------------------------------------------
    def update(self, dt: float, *, cmd_pos: float, cmd_vel: float, cmd_acc: float,
               act_pos: float, act_vel: float, vel_loop_vel: float, vel_loop_acc: float,
               target_stopped: bool, half_count: float) -> float:
        """One servo tick. act_pos/act_vel: the position-loop encoder; vel_loop_vel/acc: the
        velocity-loop encoder (same as act_* unless dual loop). Returns the output [V]."""
        r = self.r
        mode = r['mode']
        position_mode = mode.startswith('position')
        if position_mode:
            raw_error = cmd_pos - act_pos
            lim = r['position_error_limit']
            error = _clamp(raw_error, -lim, lim) if lim > 0.0 else raw_error
        else:
            raw_error = error = cmd_vel - act_vel
        # RMC anti-hunting: target stopped and inside the tolerance (or half a raw count).
        self.anti_hunting = position_mode and db.in_anti_hunting_window(
            target_stopped, raw_error, r['deadband_tolerance'], half_count)
        feedforward = (r['kvff'] * cmd_vel + r['kaff'] * cmd_acc
                       + r['friction_ff'] * _sign(cmd_vel) + r['bias'])
        limit = r['output_limit']
        deadband, tolerance = r['output_deadband'], r['deadband_tolerance']

        def finish(v):
            """Output deadband (with ratioing) on the notch output."""
            return db.apply_deadband(v, deadband, raw_error, tolerance, target_stopped,
                                     position_mode)

        if mode.endswith('pid'):
            held = r['integration_mode'] == 'at_rest' and cmd_vel != 0.0
            il = r['integration_limit']
            i_old = _clamp(self.integral, -il, il)       # Ixx63 may have been lowered
            i_new = i_old
            if not held:
                free = _clamp(i_old + r['ki'] * error * dt, -il, il)
                i_new = free
                if self.anti_hunting:
                    i_new = db.limit_integral_to_wind_down(i_old, free)
                    held = i_new != free                 # the rule stopped some growth
            if position_mode:
                loop = r['kp'] * error - r['kd'] * vel_loop_vel
            else:
                loop = r['kp'] * error - r['kd'] * vel_loop_acc
            # No integration while the output saturates (PMAC Ixx69): test this tick's output
            # with the integration before committing it (when there is one to test).
            if i_new != i_old and abs(finish(self._notch_peek(loop + i_new + feedforward))) \
                    >= limit:
                i_new = i_old
                held = True
            self.integral = i_new
            out = finish(self._notch_step(loop + i_new + feedforward))
            self.integrator_held = held or abs(out) >= limit
        else:
            # I-PD, incremental: the state CO carries I, P and D together.
            meas = act_pos if position_mode else act_vel
            meas_rate = vel_loop_vel if position_mode else vel_loop_acc
            if self.prev_act is None:
                self.prev_act, self.prev_act_vel = meas, meas_rate
            co_old = self.co
            inc_i = r['ki'] * dt * error
            held = False
            if self.anti_hunting:
                wound = db.limit_integral_to_wind_down(co_old, co_old + inc_i)
                held = wound != co_old + inc_i
                inc_i = wound - co_old                  # may only wind down
            co = (co_old + inc_i - r['kp'] * (meas - self.prev_act)
                  - r['kd'] * (meas_rate - self.prev_act_vel))
            self.prev_act, self.prev_act_vel = meas, meas_rate
            # Output clamp on the state (anti-windup): CO + ff + deadband within ±limit.
            room = max(limit - deadband, 0.0)
            hi, lo = room - feedforward, -room - feedforward
            co_clamped = _clamp(co, lo, hi)
            if co_clamped != co:
                held = True
            self.co = self.integral = co_clamped
            self.integrator_held = held
            out = finish(self._notch_step(self.co + feedforward))

        self.saturated = abs(out) >= limit
        out = _clamp(out, -limit, limit)
        self.output = out
        return out
