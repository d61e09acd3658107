"""Move generator (profiler) of one servo axis.

Point-to-point and velocity (jog) profiles are time-optimal and planned with
ruckig (L. Berscheid & T. Kroeger, "Jerk-limited Real-time Trajectory
Generation with Arbitrary Target States", RSS 2021) within max_velocity,
max_acceleration and max_jerk. max_jerk = 0 selects a trapezoidal
(acceleration-limited) profile, which is ruckig with max_jerk = inf.

ruckig is used offline: each re-plan (move_to / jog / stop) computes a whole
trajectory once from the current unfiltered state, and every step() samples
it at the segment time t. Sampling instead of ruckig's fixed-delta online
update lets the caller step with whatever dt actually elapsed.

On top of the profile sits Galil's IT ("independent time smoothing"): a
first-order filter whose pole per servo sample T is (1 - IT), i.e. a
continuous lag with tau = -T / ln(1 - IT). It is integrated exactly for the
real dt of every step (first-order hold of the input), so it equals Galil's
filter at dt = T and still behaves when a tick is late. Position, velocity
and acceleration go through the same filter, so the commanded state stays
continuous even where a trapezoid steps its acceleration.

A third kind of segment is a path given from outside (`follow`): one axis's share of a timed
multi-axis trajectory (PMAC PVT mode, motion_ctrl.core.trajectory), sampled at the same segment time
as a ruckig plan, so every axis stepped with the same dt stays on one time base. Stops re-plan
from the path's state with ruckig as from any move.

Plain Python, no rclpy, deterministic: the only clock is the dt passed in.
"""

import math
from typing import Final, Protocol

from ruckig import (ControlInterface, InputParameter, Result, Ruckig,
                    RuckigError, Trajectory)

from motion_ctrl.core.config import ProfileConfig, defaults

__all__ = ['Path', 'Profile']


class Path(Protocol):
    """One axis's share of a timed trajectory, as `Profile.follow` samples it."""
    duration: float                      # s
    end: float                           # final position (m), reached at rest
    extrema: tuple[float, float]         # (min, max) position over the path (m)

    def at(self, t: float) -> tuple[float, float, float]:
        """(position, velocity, acceleration) at t seconds from the start."""
        ...

_INF: Final = math.inf

# Residual tolerances for declaring the smoothed state equal to the raw one.
# The exponential tail never reaches the raw value by itself; snapping only
# below these keeps the final step invisible (far below any encoder count).
_SNAP_POSITION: Final = 1e-12   # m
_SNAP_VELOCITY: Final = 1e-9    # m/s
_SNAP_ACCELERATION: Final = 1e-6  # m/s^2

_OK_RESULTS: Final = (Result.Working, Result.Finished)
# Bisection steps for a re-plan's start velocity (rebase): its share known to 2^-12.
_SHARE_STEPS: Final = 12


def _finite(x):
    try:
        return math.isfinite(x)
    except TypeError:
        return False


def _override(name, value, configured):
    """A per-move limit: `configured` when None, else a finite value > 0 (ValueError)."""
    if value is None:
        return configured
    if not (_finite(value) and value > 0):
        raise ValueError(f'{name} override must be finite and > 0, got {value!r}')
    return float(value)


class Profile:
    """Move generator of one axis; see the module docstring.

    State after step():
      position, velocity, acceleration              commanded (smoothed)
      raw_position, raw_velocity, raw_acceleration  unfiltered profile
      kind             'idle' | 'position' | 'velocity' | 'stop' | 'path'
      target           final position of the current/last position move
      target_velocity  velocity of the current velocity move, else None
      done, at_target, moving  (properties)
      duration         planned duration of the current ruckig segment (s)

    Positions are in the caller's frame (an axis's loop frame, m); velocities m/s,
    accelerations m/s², times s.

    Parameters
    ----------
    position : float
        Where the profile starts, at rest [m].
    config : ProfileConfig, optional
        Limits and smoothing (Galil SP / AC / IT); None: the register table's defaults.
    servo_period : float
        The servo period T [s] that Galil IT's pole is per.
    """
    # (set by _reset, which __init__ calls)
    raw_position: float
    raw_velocity: float
    raw_acceleration: float
    position: float
    velocity: float
    acceleration: float
    kind: str
    duration: float
    _t: float
    _raw_done: bool
    _settled: bool
    _seg_velocity: float
    _path: Path | None
    _offset: float

    def __init__(self, position: float = 0.0, config: ProfileConfig | None = None,
                 servo_period: float = 1e-3):
        if not _finite(position):
            raise ValueError(f'initial position must be finite, got {position!r}')
        position = float(position)

        self.max_velocity = self.max_acceleration = self.max_jerk = 0.0
        self.smoothing = 1.0
        self.servo_period = servo_period
        self._tau = 0.0
        self._f_dt: float | None = None
        self.configure(config or defaults(ProfileConfig), servo_period)

        # Allocated once; re-plans reuse them, steps never allocate ruckig objects.
        self._ruckig = Ruckig(1)
        self._inp = InputParameter(1)
        self._traj = Trajectory(1)
        self._spare = Trajectory(1)   # planned into first, so a failure keeps _traj

        # Cache of the filter coefficients for the last dt (dt is usually constant).
        self._f_dt = None
        self._f_e = 0.0
        self._f_c = 0.0

        self.target: float | None = None
        self.target_velocity: float | None = None
        self._reset(position)

    # ------------------------------------------------------------------ config
    def configure(self, config: ProfileConfig, servo_period: float) -> None:
        """Set limits and IT smoothing (validated by the register table) for a servo period.

        New limits apply from the next re-plan (move_to/jog/stop): a move in
        progress is not re-planned behind the caller's back. The smoothing
        time constant applies from the next step.

        Parameters
        ----------
        config : ProfileConfig
            max_velocity [m/s], max_acceleration [m/s²], max_jerk [m/s³] (0: trapezoidal),
            smoothing (Galil IT, 0.004..1; 1 = off).
        servo_period : float
            The servo period T [s], finite and > 0.

        Raises
        ------
        ValueError
            servo_period not finite and > 0.
        """
        if not (_finite(servo_period) and servo_period > 0):
            raise ValueError(f'servo_period must be finite and > 0, got {servo_period!r}')
        self.max_velocity = config.max_velocity
        self.max_acceleration = config.max_acceleration
        self.max_jerk = config.max_jerk
        self.smoothing = config.smoothing
        self.servo_period = float(servo_period)
        # IT is a per-sample pole; as a continuous lag that is tau = -T/ln(1-IT).
        if self.smoothing >= 1.0:
            self._tau = 0.0
        else:
            self._tau = -self.servo_period / math.log1p(-self.smoothing)
        self._f_dt = None

    # ---------------------------------------------------------------- commands
    def move_to(self, target: float, max_velocity=None, max_acceleration=None) -> None:
        """Point-to-point move to `target`, planned from the current raw state.

        max_velocity / max_acceleration override the configured limits for this move only
        (the axis uses them to turn a jog into a stop at a soft limit: cruise no faster than
        the jog, brake at the deceleration available). On a refusal nothing changes.

        Parameters
        ----------
        target : float
            The position to stop at [m].
        max_velocity, max_acceleration : float, optional
            This move's limits [m/s, m/s²], finite and > 0; None: the configured ones.

        Raises
        ------
        ValueError
            A non-finite target or limit, or ruckig's refusal (the previous move kept).
        """
        if not _finite(target):
            raise ValueError(f'move target must be finite, got {target!r}')
        vmax = _override('max_velocity', max_velocity, self.max_velocity)
        amax = _override('max_acceleration', max_acceleration, self.max_acceleration)
        target = float(target)
        self._plan(ControlInterface.Position, target, 0.0, amax, vmax)
        self.kind = 'position'
        self.target = target
        self.target_velocity = None

    def follow(self, path: Path, offset: float = 0.0) -> None:
        """Follow `path` (its `at(t) -> (p, v, a)` from t = 0 to `path.duration`, ending at rest
        at `path.end`; `path.extrema` its (min, max) position), shifted by `offset` (the loop's
        frame). The caller starts it from the present state (`at(0)` is the raw state now:
        the trajectory's implicit first point), so nothing jumps.

        Parameters
        ----------
        path : Path
            The path [m, m/s, m/s² against s]; duration [s] finite and > 0.
        offset : float
            Added to the path's positions [m] (the loop frame's offset).

        Raises
        ------
        ValueError
            A duration not finite and > 0.
        """
        duration = float(path.duration)
        if not (_finite(duration) and duration > 0):
            raise ValueError(f'path duration must be finite and > 0, got {duration!r}')
        self._path = path
        self._offset = float(offset)
        self.duration = duration
        self._t = 0.0
        self._raw_done = False
        self._settled = False
        self._seg_velocity = 0.0
        self.kind = 'path'
        self.target = float(path.end) + self._offset
        self.target_velocity = None

    def following(self, path: Path) -> bool:
        """`path` is the segment running now (not yet ended, stopped or replaced).

        Parameters
        ----------
        path : Path
            A path given to `follow`.

        Returns
        -------
        bool
        """
        return self._path is path and not self._raw_done

    @property
    def path(self) -> Path | None:
        """The path of the present segment, running or ended (None once another command
        replaced it): what a trajectory's watcher compares with the path it started."""
        return self._path

    def jog(self, velocity: float) -> None:
        """Velocity move; 0 decelerates to rest.

        The velocity is clamped to +-max_velocity (ruckig's velocity interface
        does not enforce max_velocity on the target itself).

        Parameters
        ----------
        velocity : float
            The velocity to reach [m/s], at max_acceleration (jerk-limited if max_jerk > 0).

        Raises
        ------
        ValueError
            A non-finite velocity, or ruckig's refusal (the previous move kept).
        """
        if not _finite(velocity):
            raise ValueError(f'jog velocity must be finite, got {velocity!r}')
        vmax = self.max_velocity
        velocity = min(max(float(velocity), -vmax), vmax)
        self._plan(ControlInterface.Velocity, 0.0, velocity,
                   self.max_acceleration)
        self.kind = 'velocity'
        self.target_velocity = velocity

    def stop(self, deceleration: float, jerk_limited: bool = True) -> None:
        """Decelerate to rest at `deceleration`: jerk-limited if max_jerk > 0 and
        `jerk_limited` (a STOP), else on a ramp (an ESTOP, as PMAC's abort at the
        Ixx15 rate: the shortest stop the rate allows, whatever the S-curve).

        Needs no configure(): without it the stop is trapezoidal. kind is 'stop'
        until at rest, then 'idle'.

        Parameters
        ----------
        deceleration : float
            [m/s²], finite and > 0 (stop_deceleration, estop_deceleration).
        jerk_limited : bool
            Shape the stop with max_jerk (False: a ramp at `deceleration`).

        Raises
        ------
        ValueError
            A deceleration not finite and > 0, or ruckig's refusal.
        """
        if not (_finite(deceleration) and deceleration > 0):
            raise ValueError(f'stop deceleration must be finite and > 0, got {deceleration!r}')
        if (self._raw_done and self._settled and self.raw_velocity == 0.0):
            self.kind = 'idle'   # already at rest: nothing to decelerate
            self.target_velocity = None
            return
        self._plan(ControlInterface.Velocity, 0.0, 0.0, float(deceleration),
                   max_jerk=None if jerk_limited else _INF)
        self.kind = 'stop'
        self.target_velocity = None

    def hold(self, position: float) -> None:
        """Reset to rest at `position` without motion (abort, enable, fault).

        Parameters
        ----------
        position : float
            [m], finite (else ValueError).
        """
        if not _finite(position):
            raise ValueError(f'hold position must be finite, got {position!r}')
        self._reset(float(position))

    def rebase(self, position: float, velocity: float) -> bool:
        """After a stall of the servo loop: the present segment planned again, to the same goal
        under the same limits, from the measured state (`position`, `velocity`, acceleration
        0), so that the command neither jumps ahead by the time lost nor asks for speed to
        win it back (the catch-up rule, core.axis STALL_PERIODS). A move never passes its
        target for it: a start speed towards the target that cannot stop there is cut to one
        that can. A move, jog or stop only; a path keeps its time base (the caller holds its
        time instead). Returns False, with nothing changed, when there is nothing to re-plan or
        ruckig refuses the new start.

        Parameters
        ----------
        position, velocity : float
            The measured state to start from [m, m/s], in the profile's frame.

        Returns
        -------
        bool
            True when the segment was planned again.
        """
        if self.kind not in ('position', 'velocity', 'stop') or not (
                _finite(position) and _finite(velocity)):
            return False
        inp = self._inp
        raw = (self.raw_position, self.raw_velocity, self.raw_acceleration)
        goal = (inp.control_interface, inp.target_position[0], inp.target_velocity[0],
                inp.max_acceleration[0], inp.max_velocity[0], inp.max_jerk[0])
        self.raw_position, self.raw_velocity, self.raw_acceleration = position, velocity, 0.0
        try:
            self._plan(*goal)
            if self.kind == 'position' and self._passes_target(position, velocity):
                self._plan_short_of_target(goal, velocity)
        except ValueError:
            self.raw_position, self.raw_velocity, self.raw_acceleration = raw
            return False
        self.position, self.velocity, self.acceleration = position, self.raw_velocity, 0.0
        return True

    def _passes_target(self, position: float, velocity: float) -> bool:
        """The segment just planned, from `position` moving at `velocity` towards its target,
        goes beyond the target before it comes back."""
        d = self._inp.target_position[0] - position
        if d * velocity <= 0.0:
            return False              # at it, moving away, or still: nothing to overrun
        ext = self._traj.position_extrema[0]
        beyond = ext.max - position - d if d > 0.0 else position + d - ext.min
        return beyond > _SNAP_POSITION

    def _plan_short_of_target(self, goal: tuple, velocity: float) -> None:
        """Plan a re-based move again with the fastest start towards the target, at most the
        measured velocity, from which it stops at the target without passing it (a stall's
        re-plan must not overrun the target because the measured speed was a little high:
        speed from counts over a late sample, a slide that lags its command). At rest it never
        passes: bisection on the start velocity's share."""
        lo, hi = 0.0, 1.0
        for _ in range(_SHARE_STEPS):
            mid = 0.5 * (lo + hi)
            self.raw_velocity = velocity * mid
            self._plan(*goal)
            if self._passes_target(self.raw_position, self.raw_velocity):
                hi = mid
            else:
                lo = mid
        self.raw_velocity = velocity * lo
        self._plan(*goal)

    # -------------------------------------------------------------------- step
    def step(self, dt: float) -> None:
        """Advance the profile by dt seconds (dt may differ from tick to tick).

        Parameters
        ----------
        dt : float
            [s], finite and >= 0 (else ValueError); 0 changes nothing.
        """
        if not 0.0 <= dt < _INF:
            raise ValueError(f'dt must be finite and >= 0, got {dt!r}')
        if dt == 0.0:
            return
        x0p = self.raw_position
        x0v = self.raw_velocity
        x0a = self.raw_acceleration
        if not self._raw_done:
            self._step_raw(self._t + dt)
        elif x0v != 0.0:
            # Finished velocity move: constant speed, no need to ask ruckig.
            self.raw_position = x0p + x0v * dt
        elif self._settled:
            return   # at rest and fully settled: nothing to do
        if self._tau == 0.0:
            self.position = self.raw_position
            self.velocity = self.raw_velocity
            self.acceleration = self.raw_acceleration
            self._settled = True
        else:
            self._smooth(dt, x0p, x0v, x0a)
        if self.kind == 'stop' and self._raw_done and self._settled:
            self.kind = 'idle'

    def _step_raw(self, t: float) -> None:
        """The unsmoothed command at segment time `t`: ruckig's trajectory or the path."""
        self._t = t
        if t >= self.duration:
            self._finish_segment(t)
        elif self._path is not None:
            p, v, a = self._path.at(t)
            self.raw_position = p + self._offset
            self.raw_velocity = v
            self.raw_acceleration = a
        else:
            ps, vs, accs = self._traj.at_time(t)     # (lists: one degree of freedom)
            self.raw_position = ps[0]
            self.raw_velocity = vs[0]
            self.raw_acceleration = accs[0]

    def _smooth(self, dt: float, x0p: float, x0v: float, x0a: float) -> None:
        """Galil IT: the exact solution of tau·y' = x − y over the step, x linear from its
        value at the start of the step (x0) to the new raw command."""
        if dt != self._f_dt:
            r = dt / self._tau
            self._f_e = math.exp(-r)
            self._f_c = -math.expm1(-r) / r   # = tau/dt * (1 - e), safe for tiny r
            self._f_dt = dt
        e = self._f_e
        c = self._f_c
        x1 = self.raw_position
        self.position = x1 + (self.position - x0p) * e - (x1 - x0p) * c
        x1 = self.raw_velocity
        self.velocity = x1 + (self.velocity - x0v) * e - (x1 - x0v) * c
        x1 = self.raw_acceleration
        self.acceleration = x1 + (self.acceleration - x0a) * e - (x1 - x0a) * c
        if self._raw_done:
            self._try_snap()
        else:
            self._settled = False

    def raw_extrema(self):
        """(min, max) raw position over the current segment, from the state it was planned
        in to its end (ruckig's exact extrema); a jog cruises on beyond its segment.

        Returns
        -------
        tuple[float, float]
            (min, max) [m].
        """
        if self._raw_done:
            return self.raw_position, self.raw_position
        if self._path is not None:
            lo, hi = self._path.extrema
            return lo + self._offset, hi + self._offset
        ext = self._traj.position_extrema[0]
        return ext.min, ext.max

    # -------------------------------------------------------------- properties
    @property
    def done(self) -> bool:
        """The unfiltered profile has finished (target / rest / constant velocity)."""
        return self._raw_done

    @property
    def at_target(self) -> bool:
        return self.kind in ('position', 'path') and self.raw_position == self.target

    @property
    def moving(self) -> bool:
        """Profile generator active.

        True while the raw profile runs, while the smoothed command has not
        caught up with it, and during a constant-speed jog (the axis moves
        although the velocity profile is 'done').
        """
        return (not self._raw_done or not self._settled
                or self.raw_velocity != 0.0)

    # ---------------------------------------------------------------- internal
    def _reset(self, position: float) -> None:
        self.raw_position = position
        self.raw_velocity = 0.0
        self.raw_acceleration = 0.0
        self.position = position
        self.velocity = 0.0
        self.acceleration = 0.0
        self.kind = 'idle'
        self.target_velocity = None
        self.duration = 0.0
        self._t = 0.0
        self._raw_done = True
        self._settled = True
        self._seg_velocity = 0.0
        self._path = None
        self._offset = 0.0

    def _plan(self, interface, target_position, target_velocity, max_acceleration,
              max_velocity=None, max_jerk=None):
        """Plan a new segment from the current raw state (`max_jerk` None: the profile's);
        on error change nothing."""
        inp = self._inp
        inp.control_interface = interface
        inp.current_position = [self.raw_position]
        inp.current_velocity = [self.raw_velocity]
        inp.current_acceleration = [self.raw_acceleration]
        inp.target_position = [target_position]
        inp.target_velocity = [target_velocity]
        inp.target_acceleration = [0.0]
        # Velocity moves ignore max_velocity; a placeholder keeps stop() usable unconfigured.
        if max_velocity is None:
            max_velocity = (self.max_velocity if self.max_velocity is not None
                            else abs(self.raw_velocity) + 1.0)
        inp.max_velocity = [max_velocity]
        inp.max_acceleration = [max_acceleration]
        # ruckig rejects jerk 0 ("zero limits conflict"); inf is its trapezoid.
        jerk = self.max_jerk if max_jerk is None else max_jerk
        inp.max_jerk = [jerk if jerk > 0.0 else _INF]

        traj = self._spare
        try:
            result = self._ruckig.calculate(inp, traj)
            reason = None if result in _OK_RESULTS else str(result)
        except RuckigError as exc:
            # ruckig's message is a multi-line dump of the input; keep its headline.
            lines = [ln.strip() for ln in str(exc).splitlines() if ln.strip()]
            reason = lines[0].removesuffix(' input:') if lines else 'RuckigError'
        if reason is None and not math.isfinite(traj.duration):
            reason = f'non-finite duration {traj.duration}'
        if reason is not None:
            goal = (f'velocity {target_velocity:g} m/s'
                    if interface == ControlInterface.Velocity
                    else f'position {target_position:g} m')
            raise ValueError(
                f'ruckig could not plan a move to {goal} from p={self.raw_position:g} m, '
                f'v={self.raw_velocity:g} m/s, a={self.raw_acceleration:g} m/s^2 with '
                f'v_max={inp.max_velocity[0]:g}, a_max={max_acceleration:g}, '
                f'j_max={inp.max_jerk[0]:g}: {reason}; previous move kept')
        duration = traj.duration

        self._spare = self._traj
        self._traj = traj
        self.duration = duration
        self._t = 0.0
        self._raw_done = False
        self._settled = False
        self._seg_velocity = target_velocity
        self._path = None

    def _finish_segment(self, t):
        duration = self.duration
        if self.kind in ('position', 'path'):
            # Exactly the target: ruckig's end sample carries float residue.
            assert self.target is not None      # (a position move or path has one)
            self.raw_position = self.target
        else:
            p = self._traj.at_time(duration)[0][0]
            v = self._seg_velocity
            self.raw_position = p + v * (t - duration)
        self.raw_velocity = self._seg_velocity
        self.raw_acceleration = 0.0
        self._raw_done = True

    def _try_snap(self):
        rp = self.raw_position
        tol = max(_SNAP_POSITION, 4.0 * math.ulp(rp))
        if (abs(self.position - rp) < tol
                and abs(self.velocity - self.raw_velocity) < _SNAP_VELOCITY
                and abs(self.acceleration - self.raw_acceleration) < _SNAP_ACCELERATION):
            self.position = rp
            self.velocity = self.raw_velocity
            self.acceleration = self.raw_acceleration
            self._settled = True
        else:
            self._settled = False
