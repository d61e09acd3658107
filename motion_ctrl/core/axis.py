"""One servo axis: the modules a motion engineer names, composed into the per-tick sequence of a
PMAC / Galil / RMC servo interrupt.

Each tick (`update`):
 1. read both encoders, estimate velocities over the real dt (rcl timers skip late ticks);
 2. step the profile (move generator + Galil IT smoothing); a jog is kept inside the soft limits;
 3. backlash / leadscrew compensation (PMAC Ixx85..87, BLCOMP, COMP) on loops that close on the
    motor encoder; hidden from the reported position;
 4. pick the feedback: motor, load, dual (Galil DV: position on the load, damping on the motor)
    or sampled (motor loop + Galil's correction moves on the load encoder after each move);
 5. following-error checks (PMAC Ixx11 / Ixx12); fatal opens the loop;
 6. the servo law (PID / I-PD, notch, deadband, output limit);
 7. settling events (RMP) and the status word.

Commands (`move_to`, `jog`, `stop`, ...) return (accepted, reason): a refused one changes nothing
but the LIMIT bit where SPEC.md says so. The axis starts with the loop closed at the position the
encoders report on the first tick (PMAC Ixx80 = 1, power-on enable).

Motion commands and the status word (RMP semantics, see motion_ctrl.core.settling):

* `move_to(target)`: point-to-point move; during a move it re-plans on the fly from the present
  commanded position, velocity and acceleration (no step in any of them).
* `jog(velocity)`: velocity move, |velocity| <= max_velocity (above it refused); 0 decelerates to
  rest (MOTION_DONE).
* `stop()` / `stop('estop')`: decelerate at stop_deceleration / estop_deceleration; STOPPED /
  ESTOPPED + MOTION_DONE at rest. `abort()`: loop open at once, output 0 from this very moment,
  ENABLED cleared, ABORTED + MOTION_DONE.
* `enable(False)` opens the loop (output 0, MOTION_DONE: nothing is being moved); `enable(True)`
  closes it at the present position; `reset()` clears FOLLOWING_ERROR_FATAL, FEEDBACK_FAULT and
  LIMIT, and on an open loop ABORTED; the loop stays open until `enable(True)`.

Soft limits (soft_limit_min / soft_limit_max, on the commanded position in the user's frame):

* a target outside them is refused with a reason and the LIMIT bit; the axis is not disturbed
  (a move in progress continues to its old target);
* a jog never commands a position past them: while the profile moves toward a limit, each tick
  compares the distance left with the distance needed to stop at max_acceleration (jerk-limited
  if max_jerk > 0); when they meet, the jog becomes a position move to the limit, cruising no
  faster than the jog and braking at max_acceleration, so the command stops exactly at the
  limit (LIMIT raised, then AT_TARGET / IN_FINE_POSITION / MOTION_DONE at the limit as for any
  position move). A jog toward a limit the command already sits on is refused (LIMIT);
* a STOP / ESTOP or jog-to-zero whose deceleration would carry the command past a limit brakes
  to the limit instead (at estop_deceleration if that is what it takes; LIMIT raised).
  Should even estop_deceleration not suffice (limits changed under a moving axis), the command
  passes the limit and comes back to it.

Command precedence (RMP: an E-stop is not undone by a lesser stop): ABORT > ESTOP > STOP > a
move or jog. While a STOP or ESTOP decelerates the axis, a command of a lower level is refused
with the reason (a STOP during an ESTOP, a target or jog during either); a higher one takes over.
STOP, ESTOP, ABORT, disable and a fault cancel what was scheduled for later: they advance
`command_epoch` and say why in `cancelled_by` (the controller node drops scheduled targets of an
older epoch).

Live register changes that bear on a move in progress (`live_change_refusal`): a feedback change,
and soft limits that the planned travel would cross, are refused while the axis moves (stop
first); at rest they apply.

The per-tick path works on values cached at configure time and on plain-int status bits
(IntFlag arithmetic costs ~1 µs an operation); a Status object is built once per distinct word.
"""
from __future__ import annotations

import math
import numbers

from msg_defs.status import Status
from motion_ctrl.core.backlash import BacklashCompensation
from motion_ctrl.core.dual_loop import SampledCorrection, feedback_encoders
from motion_ctrl.core.gather import Gather
from motion_ctrl.core.profile import Profile
from motion_ctrl.core.registers import AXIS_REGISTERS, CONTROLLER_AXIS, axis_defaults, consistency
from motion_ctrl.core.servo_law import ServoLaw
from motion_ctrl.core.settling import Settling, status_word

# Status bits as plain ints for the servo tick.
_ENABLED = int(Status.ENABLED)
_MOVING = int(Status.MOVING)
_IN_FINE = int(Status.IN_FINE_POSITION)
_DONE = int(Status.MOTION_DONE)
_FE_WARNING = int(Status.FOLLOWING_ERROR_WARNING)
_FE_FATAL = int(Status.FOLLOWING_ERROR_FATAL)
_SATURATED = int(Status.OUTPUT_SATURATED)
_INTEGRATOR_HELD = int(Status.INTEGRATOR_HELD)
_BACKLASH = int(Status.BACKLASH_ACTIVE)
_FEEDBACK_FAULT = int(Status.FEEDBACK_FAULT)
_LIMIT = int(Status.LIMIT)
_CORRECTING = int(Status.CORRECTING)
_LATCHED = int(Status.STOPPED | Status.ESTOPPED | Status.ABORTED)

_S_IDLE = SampledCorrection.IDLE
_S_MOVING = SampledCorrection.MOVING
_S_CORRECTING = SampledCorrection.CORRECTING
_S_DONE = SampledCorrection.DONE

# Stop levels of the command precedence (a move or jog is 0, ABORT opens the loop).
_STOP_LEVEL = {'stop': 1, 'estop': 2}
# Status words kept in Axis.events when the caller asks for them (harness, tools): a bound, so a
# long run does not keep every change (~75 bytes each).
EVENTS_KEPT = 100_000

# ruckig's extrema carry float residue; a limit is "passed" only by more than this [m].
_LIMIT_EPS = 1e-9


def _number(x) -> bool:
    return isinstance(x, numbers.Real) and not isinstance(x, bool)


def stopping_distance(speed: float, acceleration: float, max_acceleration: float,
                      max_jerk: float) -> float:
    """Distance [m] to rest from `speed` (>= 0) with `acceleration` along the motion (> 0 =
    speeding up), braking at max_acceleration, jerk-limited at max_jerk (0 = trapezoid).

    Exact for the trapezoid; with a jerk limit an acceleration still speeding up is first
    ramped to 0 (speed + a²/2j, travelled at that speed: an upper bound)."""
    a_max = max_acceleration
    if max_jerk <= 0.0:
        return speed * speed / (2.0 * a_max)
    j = max_jerk
    extra = 0.0
    if acceleration > 0.0:
        ramp = acceleration / j
        speed += acceleration * acceleration / (2.0 * j)
        extra = speed * ramp
    if speed * j >= a_max * a_max:
        return extra + 0.5 * speed * (speed / a_max + a_max / j)
    return extra + speed * math.sqrt(speed / j)


class Axis:
    def __init__(self, name: str, registers: dict | None = None, servo_period: float = 1e-3,
                 record_events: bool = False):
        self.name = name
        self.servo_period = servo_period
        self.servo = ServoLaw()
        self.profile = Profile(0.0)
        self.settling = Settling()
        self.backlash = BacklashCompensation()
        self.sampled = SampledCorrection()
        self.gather: Gather | None = None       # a test signal running (Axis.excite)
        self.r: dict = {}            # the registers applied (set by configure below)
        self.enabled = False
        self.homed = False           # first feedback seen
        self._faults = 0             # FOLLOWING_ERROR_FATAL | FEEDBACK_FAULT (int)
        self._sticky = 0             # LIMIT (int)
        self._motion = 0             # last motion bits (settling + sampled), int
        self._word = 0               # status word as an int; `status` is the Status of it
        self.status = status_word(0)
        self.output = 0.0
        # Encoder state (load units, m) and estimates.
        self.motor_pos = self.load_pos = 0.0
        self.motor_vel = self.load_vel = 0.0
        self.motor_acc = self.load_acc = 0.0
        self.actual_pos = self.actual_vel = 0.0    # what the loop controls, compensation hidden
        self.following_error = 0.0
        self.correction = 0.0        # backlash + leadscrew correction on the motor command
        # Sampled dual loop (Galil): motor target = user target + offset.
        self.target: float | None = None
        self.sampled_offset = 0.0
        self._guard = 0              # jog direction watched against its soft limit (+1/-1/0)
        # (time, Status word) on every change, when asked for (harness, tests, tools)
        self.events: list | None = [] if record_events else None
        self._stopping = 0           # level of the STOP (1) / ESTOP (2) decelerating the axis
        self.command_epoch = 0       # advanced by STOP, ESTOP, ABORT, disable and faults
        self.cancelled_by = ''       # ... and what advanced it last
        self.fault_reason = ''       # why the last fault latched, for the log
        self.time = 0.0
        self.configure(axis_defaults(AXIS_REGISTERS) | (registers or {}))

    # -- configuration --------------------------------------------------------------------------
    def configure(self, values: dict) -> None:
        """Apply a complete, validated register set at a tick boundary (all or nothing)."""
        for name, value in values.items():
            reason = CONTROLLER_AXIS[name].check(value) if name in CONTROLLER_AXIS else \
                f'unknown register {name!r}'
            if reason:
                raise ValueError(f'{self.name}.{reason}')
        reasons = consistency(values)
        if reasons:
            raise ValueError('; '.join(f'{self.name}.{r}' for r in reasons))
        r = dict(values)
        T = self.servo_period
        # Every module validates its own inputs before anything is replaced.
        self.profile.configure(r['max_velocity'], r['max_acceleration'], r['max_jerk'],
                               r['smoothing'], T)
        self.settling.configure(r['fine_position_tolerance'], r['coarse_position_tolerance'],
                                r['velocity_tolerance'], r['settling_time'])
        self.backlash.configure(r['backlash_distance'], r['backlash_takeup_rate'],
                                r['backlash_hysteresis'], r['backlash_table'],
                                r['backlash_table_spacing'], r['leadscrew_table'],
                                r['leadscrew_table_spacing'])
        self.sampled.configure(r['correction_tolerance'], r['correction_max_moves'],
                               r['load_counts_per_m'], r['settling_time'])
        old = self.r
        self.servo.configure(r)
        self.r = r
        # What the servo tick needs, derived once here rather than every tick.
        feedback = r['feedback']
        self._motor_side = feedback_encoders(feedback)[0] == 'motor'
        self._vel_on_load = feedback == 'load'
        self._sampled_fb = feedback == 'sampled'
        self._motor_cpm = r['motor_counts_per_m']
        self._load_cpm = r['load_counts_per_m']
        # RMC: anti-hunting below half a raw count. Inclusive (by a hair): a target halfway
        # between two counts can be held from either, so the integrator must stop there too.
        self._half = 0.5 * (1 + 1e-6) / (self._motor_cpm if self._motor_side else self._load_cpm)
        self._fe_fatal = r['following_error_fatal']
        self._fe_warn = r['following_error_warning']
        self._soft_lo = r['soft_limit_min']
        self._soft_hi = r['soft_limit_max']
        self._max_vel = r['max_velocity']
        self._max_acc = r['max_acceleration']
        self._max_jerk = r['max_jerk']
        self._stop_dec = r['stop_deceleration']
        self._estop_dec = r['estop_deceleration']
        if old and old['feedback'] != feedback and self.homed:
            self._rehome_command()

    # -- derived -------------------------------------------------------------------------------
    @property
    def motor_side_loop(self) -> bool:
        """Position loop closed on the motor encoder: compensation applies there only."""
        return self._motor_side

    @property
    def fault_bits(self) -> int:
        """`faults` as a plain int, for the servo tick."""
        return self._faults

    @property
    def faults(self) -> Status:
        """FOLLOWING_ERROR_FATAL | FEEDBACK_FAULT: the loop is open until reset."""
        return status_word(self._faults)

    @property
    def correcting(self) -> bool:
        return self.sampled.correcting

    @property
    def correction_moves(self) -> int:
        return self.sampled.moves

    @property
    def command_position(self) -> float:
        """Commanded (profile) position as reported: the user's frame, compensation hidden."""
        return self.profile.position - self.sampled_offset

    # -- commands -------------------------------------------------------------------------------
    def _refuse_unless_ready(self):
        if self._faults:
            return f'{self.name}: faulted ({self.faults!r}), call {self.name}/reset'
        if not self.enabled:
            return f'{self.name}: not enabled'
        return None

    def _refuse_limit(self, reason):
        """A soft-limit refusal: LIMIT is raised (and shown at once), nothing else changes."""
        self._sticky |= _LIMIT
        self._recompose()
        return False, f'{self.name}: {reason}'

    @property
    def stopping(self) -> int:
        """Level of the STOP (1) or ESTOP (2) still decelerating the axis; 0 when none is."""
        if self._stopping and not (self.enabled and self.profile.moving):
            self._stopping = 0
        return self._stopping

    def _refuse_below_stop(self, what: str):
        level = self.stopping
        if level:
            kind = 'ESTOP' if level == 2 else 'STOP'
            return f'{self.name}: {what} refused: a {kind} is in progress (wait for MOTION_DONE)'
        return None

    def start_refusal(self, what: str):
        """Why a new motion (`what`: 'target', 'jog', 'trajectory') cannot start now, or None:
        a fault, an open loop, a STOP or ESTOP still decelerating."""
        return self._refuse_unless_ready() or self._refuse_below_stop(what)

    def _cancel(self, why: str) -> None:
        """What was scheduled for later is void (see the module docstring); a test signal
        running ends."""
        self.command_epoch += 1
        self.cancelled_by = why
        if self.gather is not None:
            self.gather.end(why)

    def excite(self, excitation, budget: float):
        """Add `excitation` (motion_ctrl.core.excitation, one value per servo tick) to the servo
        output from the next tick on, recording every tick (motion_ctrl.core.gather, PMAC's gather).
        Only enabled and at rest; `budget` [m] of slide travel around here ends it early."""
        reason = self.start_refusal('excitation')
        if reason:
            return False, reason
        if self.profile.moving or not self.status & _DONE:
            return False, f'{self.name}: excitation refused: the axis moves (wait for MOTION_DONE)'
        if not (_number(budget) and math.isfinite(budget) and budget > 0.0):
            return False, f'{self.name}: excitation travel budget {budget!r} m must be > 0'
        rate = 1.0 / self.servo_period
        if abs(excitation.sample_rate - rate) > 1e-9 * rate:
            return False, (f'{self.name}: excitation at {excitation.sample_rate:g} Hz, the servo '
                           f'loop runs at {rate:g} Hz')
        self.gather = Gather(excitation, budget, self.load_pos, self.r['output_limit'])
        return True, ''

    def live_change_refusal(self, changes: dict):
        """Why register `changes` cannot apply to the move in progress, or None: a feedback
        change (it re-homes the command and would drop the move), and soft limits that the
        planned travel crosses, are refused while the axis moves. (A jog's travel is its
        present segment: a limit ahead of it is watched each tick and braked onto.)"""
        if not (self.enabled and self.profile.moving):
            return None
        fb = changes.get('feedback', self.r['feedback'])
        if fb != self.r['feedback']:
            return (f'{self.name}.feedback: {fb} refused while the axis moves (a feedback change '
                    're-homes the command); stop first or wait for MOTION_DONE')
        lo = changes['soft_limit_min'] if 'soft_limit_min' in changes else self._soft_lo
        hi = changes['soft_limit_max'] if 'soft_limit_max' in changes else self._soft_hi
        if (lo, hi) == (self._soft_lo, self._soft_hi):
            return None
        a, b = self.profile.raw_extrema()
        off = self.sampled_offset
        a, b = a - off, b - off
        if b > hi + _LIMIT_EPS:
            return (f'{self.name}.soft_limit_max: {hi:g} m refused while the axis moves: its '
                    f'move reaches {b:g} m; stop first or wait for MOTION_DONE')
        if a < lo - _LIMIT_EPS:
            return (f'{self.name}.soft_limit_min: {lo:g} m refused while the axis moves: its '
                    f'move reaches {a:g} m; stop first or wait for MOTION_DONE')
        return None

    def move_to(self, target: float):
        if not _number(target) or not math.isfinite(target):
            return False, f'{self.name}: target {target!r} is not a finite number'
        lo, hi = self._soft_lo, self._soft_hi
        if not lo <= target <= hi:
            return self._refuse_limit(f'target {target:g} m outside the soft limits '
                                      f'[{lo:g}, {hi:g}]')
        reason = self._refuse_unless_ready() or self._refuse_below_stop('target')
        if reason:
            return False, reason
        try:
            self._start_move(float(target))
        except ValueError as e:      # ruckig could not plan it; the previous move goes on
            return False, f'{self.name}: {e}'
        self._sticky &= ~_LIMIT
        return True, ''

    def _start_move(self, target: float, max_velocity=None, max_acceleration=None) -> None:
        """Plan the profile to `target` (user frame) and start its settling (and the sampled
        corrections); raises ValueError, changing nothing, if the profile refuses."""
        loop_target = target + self.sampled_offset
        self.profile.move_to(loop_target, max_velocity, max_acceleration)
        if self.gather is not None:
            self.gather.end('a new move')
        self.target = target
        self._guard = 0
        self.settling.start_position_move(loop_target)
        self._start_corrections()

    @property
    def path_state(self) -> tuple[float, float, float]:
        """(position, velocity, acceleration) of the unsmoothed command, user frame: where a
        trajectory starting now starts (its implicit first point)."""
        p = self.profile
        return p.raw_position - self.sampled_offset, p.raw_velocity, p.raw_acceleration

    def follow(self, path):
        """Follow this axis's share of a multi-axis trajectory (PMAC PVT; `Profile.follow`),
        in the user frame. The trajectory was checked as a whole (motion_ctrl.core.trajectory); the
        soft limits are checked here again, as for any target. Settling, corrections, stops and
        faults treat it as a move to its last point."""
        reason = self.start_refusal('trajectory')
        if reason:
            return False, reason
        lo, hi = path.extrema
        if lo < self._soft_lo - _LIMIT_EPS or hi > self._soft_hi + _LIMIT_EPS:
            return self._refuse_limit(f'trajectory reaches [{lo:g}, {hi:g}] m, outside the soft '
                                      f'limits [{self._soft_lo:g}, {self._soft_hi:g}]')
        off = self.sampled_offset
        try:
            self.profile.follow(path, off)
        except ValueError as e:
            return False, f'{self.name}: {e}'
        self.target = float(path.end)
        self._guard = 0
        if self.gather is not None:
            self.gather.end('a trajectory')
        self.settling.start_position_move(self.target + off)
        self._start_corrections()
        self._sticky &= ~_LIMIT
        return True, ''

    def jog(self, velocity: float):
        if not _number(velocity) or not math.isfinite(velocity):
            return False, f'{self.name}: velocity {velocity!r} is not a finite number'
        reason = self._refuse_unless_ready() or self._refuse_below_stop('jog')
        if reason:
            return False, reason
        velocity = float(velocity)
        if abs(velocity) > self._max_vel:
            # Galil refuses an out-of-range SP; a silent clamp (PMAC Ixx16) hid the mistake.
            return False, (f'{self.name}: jog at {velocity:g} m/s refused: above max_velocity '
                           f'{self._max_vel:g} m/s')
        p = self.profile
        off = self.sampled_offset
        if velocity > 0.0 and p.raw_position >= self._soft_hi + off:
            return self._refuse_limit(f'jog at {velocity:g} m/s refused: the command is at the '
                                      f'soft limit {self._soft_hi:g} m')
        if velocity < 0.0 and p.raw_position <= self._soft_lo + off:
            return self._refuse_limit(f'jog at {velocity:g} m/s refused: the command is at the '
                                      f'soft limit {self._soft_lo:g} m')
        try:
            p.jog(velocity)
        except ValueError as e:
            return False, f'{self.name}: {e}'
        self.target = None
        self.sampled.cancel()
        # Settle against the velocity the profile runs.
        self.settling.start_velocity_move(p.target_velocity)
        self._sticky &= ~_LIMIT
        if self.gather is not None:
            self.gather.end('a jog')
        self._guard = (velocity > 0.0) - (velocity < 0.0)
        if not self._brake_within_limits(self._max_acc, stop_kind=None) and self._guard:
            self._guard_tick(self.servo_period)
        return True, ''

    def stop(self, kind: str = 'stop'):
        if kind not in ('stop', 'estop'):
            return False, f"{self.name}: stop kind must be 'stop' or 'estop', got {kind!r}"
        reason = self._refuse_unless_ready()
        if reason:
            return False, reason
        level = _STOP_LEVEL[kind]
        if self.stopping > level:
            return False, f'{self.name}: an ESTOP is in progress; a STOP does not lower it'
        decel = self._stop_dec if kind == 'stop' else self._estop_dec
        try:
            self.profile.stop(decel)
        except ValueError as e:
            return False, f'{self.name}: {e}'
        self.sampled.cancel()
        self.target = None           # abandoned: a later `correct` holds where it stopped
        self._guard = 0
        self.settling.start_stop(kind)
        self._brake_within_limits(decel, stop_kind=kind)
        self._stopping = level
        self._cancel(kind.upper())
        return True, ''

    def abort(self):
        """Open the loop at once, output 0 (RMP ABORT)."""
        self._open_loop()
        self._cancel('ABORT')
        self.settling.abort()
        self._recompose()
        return True, ''

    def enable(self, on: bool):
        if not on:
            self._open_loop()
            self._cancel('disable')
            self.settling.idle()
            self._recompose()
            return True, ''
        if self._faults:
            return False, f'{self.name}: faulted ({self.faults!r}), call {self.name}/reset first'
        if not self.homed:
            return False, f'{self.name}: no encoder feedback yet'
        if not self.enabled:
            self.enabled = True
            self._rehome_command()
        return True, ''

    def reset(self):
        """Clear faults (fatal following error, feedback fault) and LIMIT; on an open loop also
        ABORTED / STOPPED / ESTOPPED. The loop stays open (enable closes it); a closed loop and
        its motion are not touched. A feedback fault whose cause persists comes back at the
        next tick."""
        self._faults = 0
        self._sticky = 0
        if not self.enabled:
            self.settling.idle()
        self._recompose()
        return True, ''

    def correct(self):
        """Run the sampled dual-loop correction now (Galil #CORRECT): with feedback sampled, or
        once on demand with feedback motor. A loop closed on the load encoder (load, dual) has
        nothing to correct: refused."""
        reason = self._refuse_unless_ready()
        if reason:
            return False, reason
        if not self._motor_side:
            return False, (f'{self.name}: feedback {self.r["feedback"]} closes the position '
                           'loop on the load encoder: nothing to correct')
        if self.profile.moving:          # incl. a jog cruising at constant velocity
            return False, f'{self.name}: a move is in progress'
        if self.target is None:
            self.target = self.command_position
        self.sampled.start_now()
        self.settling.start_position_move(self.target + self.sampled_offset)
        return True, ''

    # -- soft limits for jogs and stops -----------------------------------------------------------
    def _brake_within_limits(self, decel: float, stop_kind) -> bool:
        """After a jog / stop plan: if the planned velocity change carries the command past a
        soft limit, brake to the limit instead. Returns True when it did."""
        p = self.profile
        if p.done:
            return False
        lo, hi = p.raw_extrema()
        off = self.sampled_offset
        start = p.raw_position
        hi_p, lo_p = self._soft_hi + off, self._soft_lo + off
        if hi > hi_p + _LIMIT_EPS and start <= hi_p:
            self._stop_at_limit(hi_p, decel, stop_kind)
            return True
        if lo < lo_p - _LIMIT_EPS and start >= lo_p:
            self._stop_at_limit(lo_p, decel, stop_kind)
            return True
        return False

    def _guard_tick(self, dt: float) -> None:
        """A jog toward a soft limit: turn it into a stop at the limit when the distance left is
        down to what braking at max_acceleration needs (plus two ticks of travel)."""
        p = self.profile
        g = self._guard
        v = p.raw_velocity * g
        if v <= 0.0:
            return                   # not (yet) moving toward the watched limit
        if g > 0:
            limit = self._soft_hi + self.sampled_offset
            left = limit - p.raw_position
        else:
            limit = self._soft_lo + self.sampled_offset
            left = p.raw_position - limit
        need = stopping_distance(v, p.raw_acceleration * g, self._max_acc, self._max_jerk)
        if left <= need + 2.0 * v * dt:
            self._stop_at_limit(limit, self._max_acc, None)

    def _stop_at_limit(self, limit: float, decel: float, stop_kind) -> None:
        """Re-plan as a position move to the soft limit `limit` (loop frame): cruise no faster
        than now (or than the jog) and brake at `decel`; if that would pass the limit, at the
        deceleration it takes (about v²/2d), at most estop_deceleration. A jog becomes that
        position move (its settling events); a STOP / ESTOP keeps its own (STOPPED / ESTOPPED
        at rest). LIMIT is raised."""
        p = self.profile
        speed = abs(p.raw_velocity)
        vcap = speed
        if p.target_velocity:
            vcap = max(vcap, abs(p.target_velocity))
        vcap = max(min(vcap, self._max_vel), 1e-9)
        lo_p, hi_p = self._soft_lo + self.sampled_offset, self._soft_hi + self.sampled_offset
        left = abs(limit - p.raw_position)
        hard = max(decel, self._estop_dec)
        tries = [decel]
        needed = speed * speed / (2.0 * left) if left > 0.0 else math.inf
        for factor in (1.02, 1.25):
            if decel < needed * factor < hard:
                tries.append(needed * factor)
        tries.append(hard)
        planned = False
        for a in tries:
            try:
                p.move_to(limit, vcap, a)
            except ValueError:
                continue
            planned = True
            lo, hi = p.raw_extrema()
            if lo >= lo_p - _LIMIT_EPS and hi <= hi_p + _LIMIT_EPS:
                break
        self._guard = 0
        self._sticky |= _LIMIT
        if not planned:              # ruckig refused both: brake as hard as allowed
            p.stop(max(decel, self._estop_dec))
            stop_kind = stop_kind or 'estop'
            self.settling.start_stop(stop_kind)
            self.target = None
            return
        if stop_kind is None:
            self.target = limit - self.sampled_offset
            self.settling.start_position_move(limit)
            self._start_corrections()

    # -- internals ------------------------------------------------------------------------------
    def _start_corrections(self) -> None:
        """A position move began: with feedback sampled, corrections follow its end; otherwise
        a correction left from <axis>/correct is over."""
        if self._sampled_fb:
            self.sampled.start()
        else:
            self.sampled.cancel()

    def _open_loop(self):
        self.enabled = False
        self._stopping = 0
        self.sampled.cancel()
        self.servo.reset()
        self.output = 0.0
        self.target = None
        self._guard = 0

    def _rehome_command(self):
        """Hold the present position without a bump: the command becomes the actual position and
        nothing is pending (a move, its settling or a correction in progress is over)."""
        self.sampled_offset = 0.0
        self.sampled.cancel()
        self.settling.idle()
        if self._motor_side:
            pos = self.motor_pos - self.correction
        else:
            pos = self.load_pos
        self.profile.hold(pos)
        self.servo.reset()
        self.target = None
        self._guard = 0

    def _correct_by(self, v2: float) -> None:
        """A sampled correction move: PR V2 on the motor, relative to its command."""
        assert self.target is not None           # (corrections follow a position move)
        self.sampled_offset += v2
        self.profile.move_to(self.target + self.sampled_offset)
        self.settling.start_position_move(self.target + self.sampled_offset)

    def home(self, motor_counts: int, load_counts: int) -> None:
        """First feedback: take the encoders as they are and close the loop there (unless a
        fault came first: then it stays open until reset and enable)."""
        self.motor_pos = motor_counts / self._motor_cpm
        self.load_pos = load_counts / self._load_cpm
        self.backlash.reset(self.motor_pos)
        self.correction = 0.0
        self.homed = True
        self._rehome_command()
        if not self._faults:
            self.enabled = True

    def feedback_fault(self) -> None:
        if self.enabled or not self._faults & _FEEDBACK_FAULT:
            was_enabled = self.enabled
            self._open_loop()
            self._faults |= _FEEDBACK_FAULT
            self.fault_reason = 'FEEDBACK_FAULT: no new encoder sample within feedback_timeout'
            self._cancel('FEEDBACK_FAULT')
            if was_enabled:
                self.settling.abort()    # the fault action: whatever moved is abandoned
            self._recompose()

    # -- the servo tick -------------------------------------------------------------------------
    def update(self, dt: float, motor_counts, load_counts, sample_dt: float | None = None,
               age: float = 0.0) -> float:
        """One servo tick with the latest encoder counts; returns the amplifier command [V].

        sample_dt: time between this encoder sample and the previous one (from their stamps),
        None = dt (sampled in step with the loop), 0 = no new sample since the last tick (the
        velocity estimates are kept rather than read as a stop, the output is held, and no
        settled time is counted).
        age: how old the sample is at this tick [s]. Over DDS a sample is 0..2 ms old; compared
        with the command of *now* it would read as a following error of velocity × age (at
        0.1 m/s, 1 ms is 40 counts) and jitter the output. So the error is taken against the
        command at the sample's time, cmd − cmd_velocity × age (a PMAC reads its encoders at
        the servo interrupt: age 0).
        """
        self.time += dt
        if not self.homed:
            self.home(motor_counts, load_counts)
        if sample_dt is None:
            sample_dt = dt
        if sample_dt > 0.0:
            motor_pos = motor_counts / self._motor_cpm
            load_pos = load_counts / self._load_cpm
            motor_vel = (motor_pos - self.motor_pos) / sample_dt
            load_vel = (load_pos - self.load_pos) / sample_dt
            self.motor_acc = (motor_vel - self.motor_vel) / sample_dt
            self.load_acc = (load_vel - self.load_vel) / sample_dt
            self.motor_pos = motor_pos
            self.load_pos = load_pos
            self.motor_vel = motor_vel
            self.load_vel = load_vel

        if not self.enabled:
            return self._update_open()

        p = self.profile
        p.step(dt)
        if self._guard:
            self._guard_tick(dt)
        position = p.position
        velocity = p.velocity
        offset = self.sampled_offset
        if self._motor_side:
            correction = self.correction = self.backlash.step(position, dt)
            loop_cmd = position + correction
            loop_pos = self.motor_pos
            actual_pos = loop_pos - correction - offset
        else:
            loop_cmd = position
            loop_pos = actual_pos = self.load_pos
        if self._vel_on_load:
            actual_vel = self.load_vel
            loop_acc = self.load_acc
        else:
            actual_vel = self.motor_vel
            loop_acc = self.motor_acc
        self.actual_pos = actual_pos
        self.actual_vel = actual_vel
        if age > 0.0:
            loop_cmd -= velocity * age
        fe = loop_cmd - loop_pos
        self.following_error = fe
        fatal = self._fe_fatal
        if fatal > 0.0 and abs(fe) > fatal:
            self._open_loop()
            self._faults |= _FE_FATAL
            self.fault_reason = (f'FOLLOWING_ERROR_FATAL: following error {fe * 1e3:+.3f} mm '
                                 f'beyond following_error_fatal {fatal * 1e3:g} mm')
            self._cancel('FOLLOWING_ERROR_FATAL')
            self.settling.abort()
            self._compose(_DONE | (self.settling._bits & _LATCHED))
            return 0.0

        if sample_dt > 0.0:
            # The servo law runs on new samples, over the time they cover.
            out = self.servo.update(
                sample_dt, cmd_pos=loop_cmd, cmd_vel=velocity, cmd_acc=p.acceleration,
                act_pos=loop_pos, act_vel=actual_vel, vel_loop_vel=actual_vel,
                vel_loop_acc=loop_acc, target_stopped=velocity == 0.0 and not p.moving,
                half_count=self._half)
        else:
            # No new sample (feedback held up, within feedback_timeout): hold the output, as a
            # drive holds its command over a missed fieldbus frame. Acting again on the same
            # sample would wind the integrator up against a position that is only old.
            out = self.output
        self.output = out

        # Settled time, and the sampled loop's judgements, advance with the encoder samples: a
        # tick without a new one (the feedback held up, within feedback_timeout) shows nothing
        # new, and a frozen sample must not make a move look settled.
        bits = self.settling.step(sample_dt, position, velocity, p.done,
                                  actual_pos + offset, actual_vel)
        if self.target is not None and self.sampled.phase != _S_IDLE:
            bits = self._sampled_step(sample_dt, motor_counts, bits)
        self._compose(bits)
        if self.gather is not None and self.gather.running:
            return self.gather.inject(out, self)     # (self.output stays the servo law's)
        return out

    def _update_open(self) -> float:
        """Loop open: the command follows the actual position so closing it is bumpless."""
        if self._motor_side:
            self.profile.hold(self.motor_pos - self.correction)
            self.actual_pos = self.motor_pos - self.correction - self.sampled_offset
            self.actual_vel = self.motor_vel
        else:
            self.profile.hold(self.load_pos)
            self.actual_pos = self.load_pos
            self.actual_vel = self.load_vel if self._vel_on_load else self.motor_vel
        self.output = 0.0
        self._compose(_DONE | (self.settling._bits & _LATCHED))
        return 0.0

    def _sampled_step(self, dt, motor_counts, bits: int) -> int:
        """Galil's #CORRECT after each move; MOTION_DONE only when the load is there."""
        s = self.sampled
        assert self.target is not None           # (called only while a target is set)
        load_error = self.target - self.load_pos
        v2 = None if dt <= 0.0 else s.update(
            dt, profile_done=self.profile.done, motor_settled=bool(bits & _DONE),
            motor_counts=int(motor_counts), load_counts=round(self.load_pos * self._load_cpm),
            load_error_counts=round(load_error * self._load_cpm),
            motor_error=self.following_error, load_error=load_error)
        if v2 is not None:
            self._correct_by(v2)
            bits = self.settling._bits
        phase = s.phase
        if phase == _S_MOVING or phase == _S_CORRECTING:
            bits &= ~(_DONE | _IN_FINE)
        elif phase == _S_DONE:
            bits |= _DONE | _IN_FINE
        return bits

    def _recompose(self) -> None:
        """The status word again after a command changed the state between ticks."""
        if self.enabled:
            self._compose(self._motion)
        else:
            self._compose(_DONE | (self.settling._bits & _LATCHED))

    def _compose(self, motion_bits: int) -> None:
        self._motion = motion_bits
        s = motion_bits | self._faults | self._sticky
        if self.enabled:
            s |= _ENABLED
            w = self._fe_warn
            if w > 0.0 and abs(self.following_error) > w:
                s |= _FE_WARNING
            servo = self.servo
            if servo.saturated:
                s |= _SATURATED
            if servo.integrator_held:
                s |= _INTEGRATOR_HELD
            if self.sampled.phase == _S_CORRECTING:
                s |= _CORRECTING | _MOVING
        if self._motor_side and self.backlash.active:
            s |= _BACKLASH
        if s != self._word:
            self._word = s
            word = status_word(s)
            self.status = word
            if self.events is not None:
                self.events.append((self.time, word))
                if len(self.events) > EVENTS_KEPT:
                    del self.events[:len(self.events) - EVENTS_KEPT]
