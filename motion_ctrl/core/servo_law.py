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
sign of the *commanded* velocity, 0 at rest; once the command has stopped, friction_ff_at_rest
is added by the sign of the position error while that lies outside the anti-hunting window
below (a position mode only, with the position loop on the load encoder: feedback dual or
load): a breakaway aid against stiction, kept below the sliding friction.

The integrator input is off (INTEGRATOR_HELD; its output is held, never zeroed) when
 * integration_mode is `at_rest` (Ixx34 = 1) and the commanded velocity is non-zero (beyond
   REST_VELOCITY, float noise);
 * the output would saturate at output_limit (Ixx69) with this tick's integration: PMAC adds
   nothing to the integrator whenever the total control output saturates. The test is made on
   the final output (after notch and deadband), before committing, so the integrator never
   changes on a tick whose output is at the limit;
 * RMC anti-hunting (position modes; target stopped and |position error| < deadband_tolerance or
   < ½ raw count) would make the integral grow: it may only wind down toward 0 (not past it).
   The flag is raised when the rule actually restricts the integration.
Reaching integration_limit is a clamp of the integrator output, not "input off".
These rules are named as strategies (`AntiWindupStrategy`, control_toolbox's name), and each law
lists those it applies (`PidLaw.ANTI_WINDUP`, `IpdLaw.ANTI_WINDUP`, `ServoLaw.anti_windup`).

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

from enum import Enum
from typing import Final

from motion_ctrl.core import deadband as db
from motion_ctrl.core.notch import Biquad
from motion_ctrl.core.registers import AXIS_REGISTERS, axis_defaults
from motion_ctrl.core.config import LawConfig

#: [m/s] a commanded velocity of at most this is at rest, for Ixx34 and Ixx68's sign. A path
#: evaluates a coordinate that stands still (a side of a square) to ~1e-16 m/s, float noise:
#: taken as motion it held the integrator along the whole side and flipped friction_ff's sign.
#: (1 nm/s: a count of the slide encoder in 40 minutes; PMAC's fixed-point command has no such
#: noise.)
REST_VELOCITY = 1e-9


def _clamp(v: float, lo: float, hi: float) -> float:
    return lo if v < lo else hi if v > hi else v


def _finish(c: LawConfig, v: float, raw_error: float, target_stopped: bool) -> float:
    """The output deadband (with ratioing) on the notch output, when one is set."""
    if c.output_deadband == 0.0:
        return v
    return db.apply_deadband(v, c.output_deadband, raw_error, c.deadband_tolerance,
                             target_stopped, c.position_mode)


class AntiWindupStrategy(Enum):
    """The rules that keep an integrator from winding up while the output cannot follow,
    named as control_toolbox's `AntiWindupStrategy` names its kinds (CONDITIONAL_INTEGRATION),
    with the vendors' others beside it. Fixed by the law's form, not a register: PMAC's PID
    and RMC's I-PD each come with theirs."""
    #: PMAC Ixx69: no integration on a tick whose output, with it, would reach output_limit.
    CONDITIONAL_INTEGRATION = 'conditional_integration'
    #: PMAC Ixx63: the integrator's output clamped at ±integration_limit (its input stays on).
    INTEGRATION_LIMIT = 'integration_limit'
    #: RMC I-PD: the one state CO clamped so that CO + feedforward + deadband stays within
    #: ±output_limit.
    STATE_CLAMP = 'state_clamp'
    #: RMC anti-hunting: at rest inside its window the integral may only wind down toward 0
    #: (deadband.limit_integral_to_wind_down).
    WIND_DOWN_ONLY = 'wind_down_only'


def saturates_with(c: LawConfig, notch: Biquad, total: float, raw: float,
                   stopped: bool) -> bool:
    """CONDITIONAL_INTEGRATION's test: would the output of loop sum `total` reach output_limit
    after the notch and deadband (the notch peeked, not stepped)?"""
    return abs(_finish(c, notch.peek(total), raw, stopped)) >= c.output_limit


def clamp_state(co: float, ff: float, c: LawConfig) -> float:
    """STATE_CLAMP: CO such that CO + ff stays within ±(output_limit − output_deadband)."""
    room = max(c.output_limit - c.output_deadband, 0.0)
    return _clamp(co, -room - ff, room - ff)


class PidLaw:
    """PMAC PID: out = kp·FE + I + ff − kd·AV. The integrator input is off while
    integration_mode is at_rest and the commanded velocity is non-zero (Ixx34), while this
    tick's output would saturate (Ixx69), and anti-hunting lets it only wind down (RMC).

    `update` takes the tick's terms from ServoLaw.update: the loop error (clipped at Ixx67),
    the raw error, the feedforward, the measurement and its rate on the velocity-loop encoder
    (kd's input: velocity in position modes, acceleration in velocity modes)."""

    ANTI_WINDUP: Final = (AntiWindupStrategy.CONDITIONAL_INTEGRATION,
                          AntiWindupStrategy.INTEGRATION_LIMIT, AntiWindupStrategy.WIND_DOWN_ONLY)

    @staticmethod
    def update(law: ServoLaw, dt: float, error: float, raw: float, ff: float, meas: float,
               rate: float, cmd_vel: float, stopped: bool, anti_hunting: bool) -> float:
        c = law.config
        held = c.integrate_at_rest and not -REST_VELOCITY <= cmd_vel <= REST_VELOCITY
        il = c.integration_limit
        # INTEGRATION_LIMIT (written out: a call more each tick, twice)
        i_old = law.integral
        i_old = -il if i_old < -il else il if i_old > il else i_old   # Ixx63 may have dropped
        i_new = i_old
        if not held:
            free = i_old + c.ki * error * dt
            free = -il if free < -il else il if free > il else free
            i_new = free
            if anti_hunting:
                i_new = db.limit_integral_to_wind_down(i_old, free)     # WIND_DOWN_ONLY
                held = i_new != free                  # the rule stopped some growth
        loop = c.kp * error - c.kd * rate
        notch = law.notch
        # Tested with this tick's integration before committing it (when there is one).
        if i_new != i_old and saturates_with(c, notch, loop + i_new + ff, raw, stopped):
            i_new = i_old
            held = True
        law.integral = i_new
        out = _finish(c, notch.step(loop + i_new + ff), raw, stopped)
        law.integrator_held = held or abs(out) >= c.output_limit
        return out


class IpdLaw:
    """Delta RMC I-PD, incremental: CO(n) = CO(n−1) + ki·dt·e − kp·Δact − kd·Δ(act rate). The
    state CO carries I, P and D together and is clamped so that CO + feedforward + deadband
    stays within ±output_limit (anti-windup); anti-hunting restricts only the ki·dt·e term.
    `update` takes the same terms as PidLaw.update."""

    ANTI_WINDUP: Final = (AntiWindupStrategy.STATE_CLAMP, AntiWindupStrategy.WIND_DOWN_ONLY)

    @staticmethod
    def update(law: ServoLaw, dt: float, error: float, raw: float, ff: float, meas: float,
               rate: float, cmd_vel: float, stopped: bool, anti_hunting: bool) -> float:
        c = law.config
        prev = meas if law.prev_act is None else law.prev_act      # first tick: no step
        prev_rate = rate if law.prev_act_vel is None else law.prev_act_vel
        co_old = law.co
        inc_i = c.ki * dt * error
        held = False
        if anti_hunting:
            wound = db.limit_integral_to_wind_down(co_old, co_old + inc_i)  # WIND_DOWN_ONLY
            held = wound != co_old + inc_i
            inc_i = wound - co_old                    # may only wind down
        co = co_old + inc_i - c.kp * (meas - prev) - c.kd * (rate - prev_rate)
        law.prev_act, law.prev_act_vel = meas, rate
        co_clamped = clamp_state(co, ff, c)
        law.co = law.integral = co_clamped
        law.integrator_held = held or co_clamped != co
        return _finish(c, law.notch.step(law.co + ff), raw, stopped)


class ServoLaw:
    """One axis' servo filter: the loop sum by the PID or I-PD law of `config.mode`, then the
    notch, the output deadband and the output limit. `configure(LawConfig)` takes the
    registers (the table's defaults until then); `update(...)` computes one tick's output."""

    def __init__(self, config: LawConfig | None = None):
        self.notch = Biquad()
        self.integral = 0.0          # PID integrator output [V]; I-PD: CO
        self.co = 0.0                # I-PD controller output state [V]
        self.prev_act: float | None = None       # I-PD: previous measurement
        self.prev_act_vel: float | None = None   # I-PD: previous measurement rate
        self.output = 0.0
        self.saturated = False
        self.integrator_held = False
        self.anti_hunting = False
        self.config = config or LawConfig.of(axis_defaults(AXIS_REGISTERS))
        self.configure(self.config)

    def configure(self, config: LawConfig) -> None:
        """New registers from the next tick. The notch keeps its history (unity DC gain before
        and after); a new mode starts its law from rest (bumpless from 0).

        Parameters
        ----------
        config : LawConfig
            The law's registers (PMAC Ixx30..39, 63, 67..69; RMC deadband), validated.
        """
        self.notch.configure(*config.notch)
        if config.mode != self.config.mode:
            self.reset()
        self.config = config

    @property
    def anti_windup(self) -> tuple[AntiWindupStrategy, ...]:
        """The anti-windup strategies of the law `config.mode` names."""
        return PidLaw.ANTI_WINDUP if self.config.pid else IpdLaw.ANTI_WINDUP

    def reset(self) -> None:
        """Open loop / new mode: clear the integrators and filter history."""
        self.integral = 0.0
        self.co = 0.0
        self.prev_act = self.prev_act_vel = None
        self.notch.reset(0.0)
        self.output = 0.0
        self.saturated = self.integrator_held = self.anti_hunting = False

    def update(self, dt: float, cmd_pos: float, cmd_vel: float, cmd_acc: float,
               act_pos: float, act_vel: float, vel_loop_vel: float, vel_loop_acc: float,
               target_stopped: bool, half_count: float, window_shift: float = 0.0) -> float:
        """One servo tick. act_pos/act_vel: the position-loop encoder; vel_loop_vel/acc: the
        velocity-loop encoder (same as act_* unless dual loop). window_shift [m]: taken off the
        position error that the at-rest windows judge (anti-hunting, ratioing, the breakaway
        aid): half a count with window_centre count_middle. Returns the output [V].

        Parameters
        ----------
        dt : float
            Time the encoder sample covers [s] (the integrator's and I-PD's step), > 0.
        cmd_pos, cmd_vel, cmd_acc : float
            The command [m, m/s, m/s²] in the position-loop encoder's frame (screw
            compensation included); cmd_vel, cmd_acc feed kvff, kaff and friction_ff (Ixx68).
        act_pos, act_vel : float
            The position-loop encoder [m, m/s] (FE = cmd_pos − act_pos; velocity modes use
            act_vel).
        vel_loop_vel, vel_loop_acc : float
            The velocity-loop encoder [m/s, m/s²]: kd's input in position / velocity modes.
        target_stopped : bool
            The command is at rest: anti-hunting, deadband ratioing and the breakaway aid apply.
        half_count : float
            Half a count of the position-loop encoder [m] (AxisConfig.half_count): RMC's
            anti-hunting window when deadband_tolerance is smaller.
        window_shift : float
            [m], as above.

        Returns
        -------
        float
            The output [V]: loop sum, notch, output deadband, clipped at ±output_limit (Ixx69).
        """
        c = self.config
        if c.position_mode:
            error = cmd_pos - act_pos
            lim = c.position_error_limit
            if lim > 0.0:                                               # Ixx67
                error = -lim if error < -lim else lim if error > lim else error
            raw = cmd_pos - act_pos - window_shift
            meas, rate = act_pos, vel_loop_vel
            # RMC anti-hunting: target stopped and inside the tolerance (or half a count).
            anti = target_stopped and db.in_anti_hunting_window(
                target_stopped, raw, c.deadband_tolerance, half_count)
        else:
            raw = error = cmd_vel - act_vel
            meas, rate = act_vel, vel_loop_acc
            anti = False
        self.anti_hunting = anti
        # friction_ff by the sign of the commanded velocity (Ixx68); at rest friction_ff_at_rest
        # by the sign of an error outside the anti-hunting window: stiction holds a slide a
        # count or more short, and the integrator alone takes a quarter of a second to creep
        # it in. Below the sliding friction, friction still stops the slide once it is free.
        if cmd_vel > REST_VELOCITY:
            friction = c.friction_ff
        elif cmd_vel < -REST_VELOCITY:
            friction = -c.friction_ff
        elif c.breakaway and c.position_mode and target_stopped and not anti and raw:
            friction = c.breakaway if raw > 0.0 else -c.breakaway
        else:
            friction = 0.0
        ff = c.kvff * cmd_vel + c.kaff * cmd_acc + friction + c.bias
        if c.pid:     # (each law named: compiled, a direct call)
            out = PidLaw.update(self, dt, error, raw, ff, meas, rate, cmd_vel, target_stopped,
                                anti)
        else:
            out = IpdLaw.update(self, dt, error, raw, ff, meas, rate, cmd_vel, target_stopped,
                                anti)
        limit = c.output_limit
        self.saturated = abs(out) >= limit
        out = _clamp(out, -limit, limit)
        self.output = out
        return out
