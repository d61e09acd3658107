"""The commands of one servo axis and their rules (PMAC / Galil / RMP), as methods of
`Axis` (motion_ctrl.core.axis). Each answers a `CommandResult` (accepted, reason): a refused
one changes nothing but the LIMIT bit where doc/interface.md says so. The axis starts with
the loop closed at the position the encoders report on the first tick (PMAC Ixx80 = 1,
power-on enable).

Motion commands and the status word (RMP semantics, see motion_ctrl.core.settling):

* `move_to(target)`: point-to-point move; during a move it re-plans on the fly from the present
  commanded position, velocity and acceleration (no step in any of them).
* `jog(velocity)`: velocity move, |velocity| <= max_velocity (above it refused); 0 decelerates to
  rest (MOTION_DONE).
* `stop()` / `stop('estop')`: decelerate at stop_deceleration / estop_deceleration; STOPPED /
  ESTOPPED + MOTION_DONE at rest. `abort()`: loop open at once, output 0 from this very moment,
  ENABLED cleared, ABORTED + MOTION_DONE.
* `enable(False)` opens the loop (output 0, MOTION_DONE: nothing is being moved); `enable(True)`
  closes it at the present position; `reset()` clears FOLLOWING_ERROR_FATAL, FEEDBACK_FAULT,
  OVERSPEED and LIMIT, and on an open loop ABORTED; the loop stays open until `enable(True)`.
* An amplifier fault (`Axis.drive_fault`, from the hardware) aborts the axis and refuses
  enable and motion with the drive's reason until `reset()`.

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
"""
from __future__ import annotations

from typing import Final, NamedTuple

import math
import numbers

from msg_defs.status import Status
from motion_ctrl.core import soft_limits as limits
from motion_ctrl.core.config import AxisConfig
from motion_ctrl.core.dual_loop import SampledCorrection
from motion_ctrl.core.gather import Gather, base_motion
from motion_ctrl.core.profile import Profile
from motion_ctrl.core.settling import Settling

_DONE: Final = int(Status.MOTION_DONE)
_LIMIT: Final = int(Status.LIMIT)
# Stop levels of the command precedence (a move or jog is 0, ABORT opens the loop).
_STOP_LEVEL: Final = {'stop': 1, 'estop': 2}


def _number(x) -> bool:
    return isinstance(x, numbers.Real) and not isinstance(x, bool)


class CommandResult(NamedTuple):
    """A command's answer: accepted, or refused with the reason (the axis's name first, then
    why, as the service replies and logs quote it). A tuple: `ok, reason = axis.jog(v)`."""
    accepted: bool
    reason: str


#: The answer of an accepted command that has nothing to add.
ACCEPTED: Final = CommandResult(True, '')


def refused(reason: str) -> CommandResult:
    """A refusal: the command changed nothing (but LIMIT where the soft limits say so)."""
    return CommandResult(False, reason)


class AxisCommands:
    """Motion commands, refusals and command precedence of an Axis (mixed into it: they act on
    its profile, settling, sampled correction and status)."""

    # The Axis state the commands act on (set by Axis.__init__ / configure).
    name: str
    servo_period: float
    r: dict
    profile: Profile
    settling: Settling
    sampled: SampledCorrection
    gather: Gather | None
    enabled: bool
    homed: bool
    status: Status
    target: float | None
    sampled_offset: float
    load_pos: float
    command_epoch: int
    cancelled_by: str
    drive_fault_reason: str
    _faults: int
    _sticky: int
    _stopping: int
    _guard: int
    config: AxisConfig

    # ... and what it provides them
    @property
    def faults(self) -> Status:
        raise NotImplementedError

    @property
    def command_position(self) -> float:
        raise NotImplementedError

    def _open_loop(self) -> None:
        raise NotImplementedError

    def _recompose(self) -> None:
        raise NotImplementedError

    def _rehome_command(self) -> None:
        raise NotImplementedError

    def _refuse_unless_ready(self):
        if self._faults:
            return f'{self.name}: faulted ({self.faults!r}), call {self.name}/reset'
        if self.drive_fault_reason:
            return (f'{self.name}: amplifier fault ({self.drive_fault_reason}), call '
                    f'{self.name}/reset')
        if not self.enabled:
            return f'{self.name}: not enabled'
        return None

    def _refuse_limit(self, reason) -> CommandResult:
        """A soft-limit refusal: LIMIT is raised (and shown at once), nothing else changes."""
        self._sticky |= _LIMIT
        self._recompose()
        return refused(f'{self.name}: {reason}')

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
        a fault, an open loop, a STOP or ESTOP still decelerating.

        Parameters
        ----------
        what : str
            The motion, as the reason names it ('target', 'jog', 'trajectory', 'excitation').

        Returns
        -------
        str or None
            The reason, `<axis>: ...`; None when the motion may start.
        """
        return self._refuse_unless_ready() or self._refuse_below_stop(what)

    def _cancel(self, why: str) -> None:
        """What was scheduled for later is void (see the module docstring); a test signal
        running ends."""
        self.command_epoch += 1
        self.cancelled_by = why
        if self.gather is not None:
            self.gather.end(why)

    def excite(self, excitation, budget: float, base_velocity: float = 0.0) -> CommandResult:
        """Add `excitation` (motion_ctrl.core.excitation, one value per servo tick) to the servo
        output from the next tick on, recording every tick (motion_ctrl.core.gather, PMAC's
        gather; Kollmorgen WorkBench's Bode measurement). Only enabled, at rest and with no run
        in progress; `budget` [m] of slide travel around here ends it early.

        `base_velocity` [m/s] (Beckhoff TwinCAT autotuning's base motion): the axis jogs at it
        first and the signal starts once MOTION_AT_VELOCITY; at the end the jog decelerates to
        rest. Refused when its nominal travel (ramps, the settling time and the signal) does
        not fit in the budget or in the soft limits; at run time the budget keeps the braking
        distance in hand.

        Parameters
        ----------
        excitation : core.excitation signal
            One value [V] a servo tick; its sample_rate [Hz] must be the servo rate.
        budget : float
            Slide travel allowed around the start [m], > 0.
        base_velocity : float
            Jog velocity under the signal [m/s]; 0: the signal at rest.

        Returns
        -------
        CommandResult
            Accepted (the signal starts on the next tick, or at velocity), or refused with
            the reason: not ready, moving, a run in progress, a bad budget or rate, no room.
        """
        reason = self.start_refusal('excitation')
        if reason:
            return refused(reason)
        g = self.gather
        if g is not None and g.running:
            return refused(f'{self.name}: excitation refused: a run is in progress')
        if self.profile.moving or not self.status & _DONE:
            return refused(f'{self.name}: excitation refused: the axis moves (wait for '
                           'MOTION_DONE)')
        if not (_number(budget) and math.isfinite(budget) and budget > 0.0):
            return refused(f'{self.name}: excitation travel budget {budget!r} m must be > 0')
        rate = 1.0 / self.servo_period
        if abs(excitation.sample_rate - rate) > 1e-9 * rate:
            return refused(f'{self.name}: excitation at {excitation.sample_rate:g} Hz, the servo '
                           f'loop runs at {rate:g} Hz')
        if not (_number(base_velocity) and math.isfinite(base_velocity)):
            return refused(f'{self.name}: base velocity {base_velocity!r} is not a finite number')
        v = float(base_velocity)
        c = self.config
        reserve, refusal = base_motion(
            v, excitation.duration + self.r['settling_time'], budget, self.command_position,
            (c.soft_limit_min, c.soft_limit_max), c.max_velocity, c.max_acceleration, c.max_jerk,
            self.servo_period)
        if refusal:
            return refused(f'{self.name}: excitation refused: {refusal}')
        if v:
            ok, reason = self.jog(v)
            if not ok:
                return refused(reason)
        self.gather = Gather(excitation, budget, self.load_pos, self.r['output_limit'], v,
                             reserve)
        return ACCEPTED

    def live_change_refusal(self, changes: dict):
        """Why register `changes` cannot apply to the move in progress, or None: a feedback
        change (it re-homes the command and would drop the move), and soft limits that the
        planned travel crosses, are refused while the axis moves. (A jog's travel is its
        present segment: a limit ahead of it is watched each tick and braked onto.)

        Parameters
        ----------
        changes : dict
            The registers about to change {name: value} (SI units; soft limits in m).

        Returns
        -------
        str or None
            The reason, `<axis>.<register>: ...`; None when the changes may apply now.
        """
        if not (self.enabled and self.profile.moving):
            return None
        fb = changes.get('feedback', self.r['feedback'])
        if fb != self.r['feedback']:
            return (f'{self.name}.feedback: {fb} refused while the axis moves (a feedback change '
                    're-homes the command); stop first or wait for MOTION_DONE')
        c = self.config
        lo = changes['soft_limit_min'] if 'soft_limit_min' in changes else c.soft_limit_min
        hi = changes['soft_limit_max'] if 'soft_limit_max' in changes else c.soft_limit_max
        if (lo, hi) == (c.soft_limit_min, c.soft_limit_max):
            return None
        a, b = self.profile.raw_extrema()
        off = self.sampled_offset
        a, b = a - off, b - off
        if b > hi + limits.EPS:
            return (f'{self.name}.soft_limit_max: {hi:g} m refused while the axis moves: its '
                    f'move reaches {b:g} m; stop first or wait for MOTION_DONE')
        if a < lo - limits.EPS:
            return (f'{self.name}.soft_limit_min: {lo:g} m refused while the axis moves: its '
                    f'move reaches {a:g} m; stop first or wait for MOTION_DONE')
        return None

    def move_to(self, target) -> CommandResult:   # (any input: refused unless a number)
        """Point-to-point move to `target` (RMP / PMAC move, Galil PA), time-optimal within
        max_velocity, max_acceleration and max_jerk (Galil SP / AC, PMAC Ixx16..21); during a
        move it re-plans from the present command. Starts the settling of a position move.

        Parameters
        ----------
        target : float
            Position in the user's frame [m], within [soft_limit_min, soft_limit_max]; anything
            but a finite real number is refused.

        Returns
        -------
        CommandResult
            Accepted, or refused with the reason: not a finite number, outside the soft limits
            (LIMIT raised; a move in progress goes on), a fault, an open loop, a STOP / ESTOP
            decelerating, or ruckig's refusal (the previous move goes on).
        """
        if not _number(target) or not math.isfinite(target):
            return refused(f'{self.name}: target {target!r} is not a finite number')
        lo, hi = self.config.soft_limit_min, self.config.soft_limit_max
        if not lo <= target <= hi:
            return self._refuse_limit(f'target {target:g} m outside the soft limits '
                                      f'[{lo:g}, {hi:g}]')
        reason = self._refuse_unless_ready() or self._refuse_below_stop('target')
        if reason:
            return refused(reason)
        try:
            self._start_move(float(target))
        except ValueError as e:      # ruckig could not plan it; the previous move goes on
            return refused(f'{self.name}: {e}')
        self._sticky &= ~_LIMIT
        return ACCEPTED

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

    def follow(self, path) -> CommandResult:
        """Follow this axis's share of a multi-axis trajectory (PMAC PVT; `Profile.follow`),
        in the user frame. The trajectory was checked as a whole (motion_ctrl.core.trajectory); the
        soft limits are checked here again, as for any target. Settling, corrections, stops and
        faults treat it as a move to its last point.

        Parameters
        ----------
        path : core.trajectory.AxisPath
            This axis's share (`at(t)` [m, m/s, m/s²], duration [s], end and extrema [m]), in
            the user's frame, starting at `path_state`.

        Returns
        -------
        CommandResult
            Accepted, or refused with the reason: not ready, a STOP / ESTOP decelerating, the
            path outside the soft limits (LIMIT raised), or the profile's refusal.
        """
        reason = self.start_refusal('trajectory')
        if reason:
            return refused(reason)
        lo, hi = path.extrema
        c = self.config
        if lo < c.soft_limit_min - limits.EPS or hi > c.soft_limit_max + limits.EPS:
            return self._refuse_limit(f'trajectory reaches [{lo:g}, {hi:g}] m, outside the soft '
                                      f'limits [{c.soft_limit_min:g}, {c.soft_limit_max:g}]')
        off = self.sampled_offset
        try:
            self.profile.follow(path, off)
        except ValueError as e:
            return refused(f'{self.name}: {e}')
        self.target = float(path.end)
        self._guard = 0
        if self.gather is not None:
            self.gather.end('a trajectory')
        self.settling.start_position_move(self.target + off)
        self._start_corrections()
        self._sticky &= ~_LIMIT
        return ACCEPTED

    def jog(self, velocity) -> CommandResult:     # (any input, as move_to)
        """Velocity move (Galil JG, PMAC jog) at max_acceleration (jerk-limited if max_jerk >
        0); 0 decelerates to rest (MOTION_DONE). The command stops at a soft limit ahead.

        Parameters
        ----------
        velocity : float
            [m/s], |velocity| <= max_velocity (above it refused, as Galil refuses SP; not
            clamped); anything but a finite real number is refused.

        Returns
        -------
        CommandResult
            Accepted, or refused with the reason: not a finite number, above max_velocity, a
            fault, an open loop, a STOP / ESTOP decelerating, the command at the soft limit it
            heads for (LIMIT raised), or ruckig's refusal.
        """
        if not _number(velocity) or not math.isfinite(velocity):
            return refused(f'{self.name}: velocity {velocity!r} is not a finite number')
        reason = self._refuse_unless_ready() or self._refuse_below_stop('jog')
        if reason:
            return refused(reason)
        velocity = float(velocity)
        if abs(velocity) > self.config.max_velocity:
            # Galil refuses an out-of-range SP; a silent clamp (PMAC Ixx16) hid the mistake.
            return refused(f'{self.name}: jog at {velocity:g} m/s refused: above max_velocity '
                           f'{self.config.max_velocity:g} m/s')
        p = self.profile
        off = self.sampled_offset
        if velocity > 0.0 and p.raw_position >= self.config.soft_limit_max + off:
            return self._refuse_limit(f'jog at {velocity:g} m/s refused: the command is at the '
                                      f'soft limit {self.config.soft_limit_max:g} m')
        if velocity < 0.0 and p.raw_position <= self.config.soft_limit_min + off:
            return self._refuse_limit(f'jog at {velocity:g} m/s refused: the command is at the '
                                      f'soft limit {self.config.soft_limit_min:g} m')
        try:
            p.jog(velocity)
        except ValueError as e:
            return refused(f'{self.name}: {e}')
        self.target = None
        self.sampled.cancel()
        # Settle against the velocity the profile runs.
        self.settling.start_velocity_move(p.target_velocity)
        self._sticky &= ~_LIMIT
        if self.gather is not None:
            self.gather.end('a jog')
        self._guard = (velocity > 0.0) - (velocity < 0.0)
        if not self._brake_within_limits(self.config.max_acceleration, None) and self._guard:
            self._guard_tick(self.servo_period)
        return ACCEPTED

    def stop(self, kind: str = 'stop') -> CommandResult:
        """Decelerate to rest (RMP STOP / E-STOP): STOPPED or ESTOPPED + MOTION_DONE at rest,
        braking onto a soft limit rather than past it; what was scheduled is cancelled.

        Parameters
        ----------
        kind : str
            'stop' at stop_deceleration (jerk-limited by max_jerk), 'estop' on a ramp at
            estop_deceleration [m/s²].

        Returns
        -------
        CommandResult
            Accepted, or refused with the reason: another kind, a fault, an open loop, a STOP
            during an ESTOP (precedence), or ruckig's refusal.
        """
        if kind not in ('stop', 'estop'):
            return refused(f"{self.name}: stop kind must be 'stop' or 'estop', got {kind!r}")
        reason = self._refuse_unless_ready()
        if reason:
            return refused(reason)
        level = _STOP_LEVEL[kind]
        if self.stopping > level:
            return refused(f'{self.name}: an ESTOP is in progress; a STOP does not lower it')
        decel = self.config.stop_deceleration if kind == 'stop' else self.config.estop_deceleration
        try:
            self.profile.stop(decel, jerk_limited=kind == 'stop')
        except ValueError as e:
            return refused(f'{self.name}: {e}')
        self.sampled.cancel()
        self.target = None           # abandoned: a later `correct` holds where it stopped
        self._guard = 0
        self.settling.start_stop(kind)
        self._brake_within_limits(decel, stop_kind=kind)
        self._stopping = level
        self._cancel(kind.upper())
        return ACCEPTED

    def abort(self) -> CommandResult:
        """Open the loop at once, output 0 (RMP ABORT).

        Returns
        -------
        CommandResult
            Always accepted: ABORTED + MOTION_DONE, the loop open until `enable(True)`.
        """
        self._open_loop()
        self._cancel('ABORT')
        self.settling.abort()
        self._recompose()
        return ACCEPTED

    def enable(self, on: bool) -> CommandResult:
        """Close or open the position loop (PMAC amplifier enable, Galil SH / MO).

        Parameters
        ----------
        on : bool
            True closes the loop at the present position (bumpless); False opens it (output
            0, MOTION_DONE) and cancels what was scheduled.

        Returns
        -------
        CommandResult
            Accepted, or (closing only) refused with the reason: a fault or an amplifier
            fault not reset, or no encoder feedback yet.
        """
        if not on:
            self._open_loop()
            self._cancel('disable')
            self.settling.idle()
            self._recompose()
            return ACCEPTED
        if self._faults:
            return refused(f'{self.name}: faulted ({self.faults!r}), call {self.name}/reset first')
        if self.drive_fault_reason:
            return refused(f'{self.name}: amplifier fault ({self.drive_fault_reason}), call '
                           f'{self.name}/reset first')
        if not self.homed:
            return refused(f'{self.name}: no encoder feedback yet')
        if not self.enabled:
            self.enabled = True
            self._rehome_command()
        return ACCEPTED

    def reset(self) -> CommandResult:
        """Clear faults (fatal following error, feedback fault, overspeed, amplifier fault) and
        LIMIT; on an open loop also ABORTED / STOPPED / ESTOPPED. The loop stays open (enable
        closes it); a closed loop and its motion are not touched. A fault whose cause persists
        comes back at the next tick.

        Returns
        -------
        CommandResult
            Always accepted.
        """
        self._faults = 0
        self._sticky = 0
        self.drive_fault_reason = ''
        if not self.enabled:
            self.settling.idle()
        self._recompose()
        return ACCEPTED

    def correct(self) -> CommandResult:
        """Run the sampled dual-loop correction now (Galil #CORRECT): with feedback sampled, or
        once on demand with feedback motor. A loop closed on the load encoder (load, dual) has
        nothing to correct: refused.

        Returns
        -------
        CommandResult
            Accepted (moves until the load error is below correction_tolerance [m], at most
            correction_max_moves), or refused with the reason: not ready, a loop on the load
            encoder, or a move in progress.
        """
        reason = self._refuse_unless_ready()
        if reason:
            return refused(reason)
        if not self.config.motor_side:
            return refused(f'{self.name}: feedback {self.r["feedback"]} closes the position '
                           'loop on the load encoder: nothing to correct')
        if self.profile.moving:          # incl. a jog cruising at constant velocity
            return refused(f'{self.name}: a move is in progress')
        if self.target is None:
            self.target = self.command_position
        self.sampled.start_now()
        self.settling.start_position_move(self.target + self.sampled_offset)
        return ACCEPTED

    # -- soft limits for jogs and stops (planned by core.soft_limits) -------------------------
    def _limits(self) -> tuple[float, float]:
        """The soft limits in the profile's (loop) frame."""
        off = self.sampled_offset
        return self.config.soft_limit_min + off, self.config.soft_limit_max + off

    def _brake_within_limits(self, decel: float, stop_kind) -> bool:
        """After a jog / stop plan: if the planned velocity change carries the command past a
        soft limit, brake to the limit instead. Returns True when it did."""
        limit = limits.crossed(self.profile, *self._limits())
        if limit is None:
            return False
        self._stop_at_limit(limit, decel, stop_kind)
        return True

    def _guard_tick(self, dt: float) -> None:
        """A jog toward a soft limit: a stop at the limit once braking must start."""
        c = self.config
        limit = limits.due(self.profile, self._guard, *self._limits(), dt, c.max_acceleration,
                           c.max_jerk)
        if limit is not None:
            self._stop_at_limit(limit, self.config.max_acceleration, None)

    def _stop_at_limit(self, limit: float, decel: float, stop_kind) -> None:
        """Brake onto the soft limit `limit` (loop frame). A jog becomes a position move to it
        (its settling events); a STOP / ESTOP keeps its own (STOPPED / ESTOPPED at rest).
        LIMIT is raised."""
        c = self.config
        planned = limits.stop_at(self.profile, limit, decel, c.estop_deceleration, c.max_velocity,
                                 *self._limits())
        self._guard = 0
        self._sticky |= _LIMIT
        if self.gather is not None:
            self.gather.end(f'the soft limit {limit - self.sampled_offset:g} m')
        if not planned:              # ruckig refused every plan: brake as hard as allowed
            self.profile.stop(max(decel, self.config.estop_deceleration), jerk_limited=False)
            self.settling.start_stop(stop_kind or 'estop')
            self.target = None
            return
        if stop_kind is None:
            self.target = limit - self.sampled_offset
            self.settling.start_position_move(limit)
            self._start_corrections()

    def _start_corrections(self) -> None:
        """A position move began: with feedback sampled, corrections follow its end; otherwise
        a correction left from <axis>/correct is over."""
        if self.config.sampled:
            self.sampled.start()
        else:
            self.sampled.cancel()
