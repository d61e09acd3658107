"""A FollowJointTrajectory goal (control_msgs; ros2_controllers' joint_trajectory_controller,
JTC) on this controller's coordinate system: the checks before it starts, the tolerances it is
judged by, and the state machine the servo tick drives while it runs.

The rules, JTC's (its tolerances.hpp and update loop) unless said otherwise (doc/follow_joint_
trajectory.md lists the differences):

* **Checks** (`check`, before anything moves), each refusal naming the joint, point and limit:
  joint names (not empty, each an axis, none twice; multi-DOF joints: there are none) ->
  INVALID_JOINTS; the tolerances (a joint named in one must be an axis; a value is > 0, 0 for
  the default or -1 for "not checked") and the trajectory as `joint_trajectory` checks it
  (motion_ctrl.core.trajectory: lengths, times, finite numbers, soft limits, max_velocity and
  max_acceleration between the points) -> INVALID_GOAL; a header stamp whose trajectory ended
  already -> OLD_HEADER_TIMESTAMP. JTC rejects such goals (no result); here they are accepted
  and aborted at once, so that the client gets the code and the reason.
* **A first point at t = 0** is where the sender thinks the axis is (MoveIt sends the measured
  state there): within `coarse_position_tolerance` of the commanded position it takes the
  axis's own commanded state (nothing jumps); further away the goal is refused.
* **Tolerances** per axis: path (while the trajectory runs: position = the following error,
  velocity and acceleration errors against the command) and goal (after its end: the position
  error from the last point, the velocity, the acceleration), each 0 = not checked; and
  goal_time, the time after the end the axis may take (0 = no deadline, as JTC). Defaults are
  the axis's registers `trajectory_tolerance`, `goal_tolerance`, `stopped_velocity_tolerance`
  (the goal velocity) and `goal_time` (JTC: constraints.<joint>.trajectory / .goal,
  stopped_velocity_tolerance, goal_time); a goal's JointTolerance entries override them
  (0: keep the default, -1: not checked).
* **While it runs** (`GoalRunner.tick`, once per servo tick, plain comparisons): a path
  tolerance exceeded stops the goal's axes at their STOP deceleration -> PATH_TOLERANCE_VIOLATED;
  after the end, success once every axis is settled (MOTION_DONE, RMP) and within its goal
  tolerance; an axis still outside when its goal_time has passed -> GOAL_TOLERANCE_VIOLATED.
* **What else ends it**, with a result that names the cause: a STOP, ESTOP, ABORT, disable or
  fault of one of its axes (the coordinate system stops the others), another command taking
  one of its axes (a `joint_trajectory`, `target_position` or `target_velocity`), a newer goal
  (it preempts: JTC's INVALID_GOAL "preempted"), a cancel (the axes stop at their STOP
  deceleration; CANCELED once they are at rest, with the positions reached). An aborted goal
  stops those of its axes still on its path: no axis goes on moving that nobody watches.

No ROS here: the action server (motion_ctrl.ros.follow_action) reads the goal message into a
`GoalRequest`, runs `check` off the servo thread, hands the result to `GoalRunner.submit` and
calls `GoalRunner.tick` after each servo tick; goal handles are opaque to this module.
"""
from __future__ import annotations

import bisect
import math
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from typing import Any, NamedTuple

from motion_ctrl.core.axis import Axis
from msg_defs.status import Status

__all__ = ['SUCCESSFUL', 'INVALID_GOAL', 'INVALID_JOINTS', 'OLD_HEADER_TIMESTAMP',
           'PATH_TOLERANCE_VIOLATED', 'GOAL_TOLERANCE_VIOLATED', 'SUCCEEDED', 'ABORTED',
           'CANCELED', 'Tolerance', 'Tolerances', 'GoalRequest', 'Refusal', 'CheckedGoal',
           'Ended', 'Feedback', 'check', 'default_tolerances', 'errors', 'actual_acceleration',
           'GoalRunner']

# control_msgs/action/FollowJointTrajectory Result.error_code (test_ros_follow compares them
# with the message's constants).
SUCCESSFUL = 0
INVALID_GOAL = -1
INVALID_JOINTS = -2
OLD_HEADER_TIMESTAMP = -3
PATH_TOLERANCE_VIOLATED = -4
GOAL_TOLERANCE_VIOLATED = -5

# How a goal ends (action_msgs/GoalStatus terms).
SUCCEEDED, ABORTED, CANCELED = 'succeeded', 'aborted', 'canceled'

ERASE = -1.0        # control_msgs/JointTolerance: -1 removes the default ("not checked")
_DONE = int(Status.MOTION_DONE)
_QUANTITIES = (('position', 'm'), ('velocity', 'm/s'), ('acceleration', 'm/s²'))


class Tolerance(NamedTuple):
    """Largest |error| allowed per quantity (m, m/s, m/s²); 0 = not checked."""
    position: float = 0.0
    velocity: float = 0.0
    acceleration: float = 0.0

    def excess(self, errors: tuple[float, float, float]) -> tuple[str, float, float] | None:
        """The first quantity whose |error| is beyond its tolerance: (name, error, tolerance)."""
        for (what, _), tol, err in zip(_QUANTITIES, self, errors):
            if tol > 0.0 and abs(err) > tol:
                return what, err, tol
        return None


@dataclass(frozen=True)
class Tolerances:
    """One axis's tolerances for one goal: while it runs, at the end, and the time after the
    end it may take to be there (0 = no deadline)."""
    path: Tolerance
    goal: Tolerance
    goal_time: float


def default_tolerances(r: Mapping) -> Tolerances:
    """The axis's defaults, from its registers."""
    return Tolerances(Tolerance(float(r['trajectory_tolerance'])),
                      Tolerance(float(r['goal_tolerance']), float(r['stopped_velocity_tolerance'])),
                      float(r['goal_time']))


@dataclass(frozen=True)
class GoalRequest:
    """What a FollowJointTrajectory goal asks, as plain data (msg_defs.read_follow_goal):
    `trajectory` as msg_defs.read_joint_trajectory gives it; the tolerances as (joint name,
    position, velocity, acceleration); component (multi-DOF) tolerances by joint name."""
    trajectory: dict
    stamp: float = 0.0                     # header.stamp [s]; 0: start now
    multi_dof_names: tuple = ()
    path_tolerance: tuple = ()
    goal_tolerance: tuple = ()
    component_joints: tuple = ()           # joints named in component_*_tolerance
    goal_time_tolerance: float = 0.0       # [s]; 0: the axes' goal_time, -1: no deadline


@dataclass(frozen=True)
class Refusal:
    """A goal that does not start: its result code and why."""
    code: int
    text: str


@dataclass(frozen=True)
class CheckedGoal:
    """A goal that passed the checks: its trajectory built (a Prepared of
    core.coordination), the tolerances per axis, when it starts (None: now, else the stamp [s]),
    and the points' times as sent (the feedback's index counts them)."""
    names: tuple
    job: Any
    tolerances: dict
    start: float | None
    times: tuple


class Ended(NamedTuple):
    """A goal that ended: its handle, how (SUCCEEDED, ABORTED, CANCELED), the result's code
    and text; `last`, a goal that succeeded: its state at the end (its final feedback, past
    the last point)."""
    handle: Any
    outcome: str
    code: int
    text: str
    last: Feedback | None = None


class Feedback(NamedTuple):
    """The running goal now, per axis in `names` order: desired (command) position, velocity,
    acceleration; actual; error (position: the following error, i.e. against the command of the
    encoder sample's own time); `next_point`, the number of the trajectory's points passed
    (the index of the next one: control_msgs' feedback `index`); `time`, seconds since the
    trajectory's start."""
    names: tuple
    desired: tuple
    actual: tuple
    error: tuple
    next_point: int
    time: float


# ------------------------------------------------------------------------------ the checks

def _resolve(default: float, given: float) -> float:
    """JTC's rule for one tolerance value: > 0 given, 0 default, -1 not checked."""
    if not math.isfinite(given):
        raise ValueError(f'{given} is not a finite number')
    if given > 0.0:
        return given
    if abs(given - ERASE) < 1e-7:        # (JTC compares within a float's epsilon)
        return 0.0
    if given < 0.0:
        raise ValueError(f'{given:g}: a tolerance is > 0, 0 (the default) or -1 (not checked)')
    return default


def _tolerances(names, values, request: GoalRequest):
    """{axis: Tolerances} of the goal's axes, or a Refusal."""
    result = {n: default_tolerances(values[n]) for n in names}
    if request.component_joints:
        return Refusal(INVALID_JOINTS, f'component tolerances name {request.component_joints[0]!r}'
                                       ': this controller has no multi-DOF joints')
    g = request.goal_time_tolerance
    for kind in ('path', 'goal'):
        for name, *given in getattr(request, f'{kind}_tolerance'):
            if name not in values:
                return Refusal(INVALID_JOINTS, f'{kind}_tolerance names {name!r}, not an axis of '
                                               f'this controller (axes: {", ".join(values)})')
            if name not in result:
                continue                  # an axis this goal does not move
            old = result[name]
            own = getattr(old, kind)
            resolved = []
            for (what, unit), default, value in zip(_QUANTITIES, own, given):
                try:
                    resolved.append(_resolve(default, float(value)))
                except ValueError as e:
                    return Refusal(INVALID_GOAL, f'{kind}_tolerance of {name}: {what} {e}')
            tol = Tolerance(*resolved)
            result[name] = (Tolerances(tol, old.goal, old.goal_time) if kind == 'path'
                            else Tolerances(old.path, tol, old.goal_time))
    if g:
        try:
            goal_time = _resolve(0.0, g)
        except ValueError as e:
            return Refusal(INVALID_GOAL, f'goal_time_tolerance {e}')
        result = {n: Tolerances(t.path, t.goal, goal_time) for n, t in result.items()}
    return result


def _names_refusal(names, axes) -> Refusal | None:
    if not names:
        return Refusal(INVALID_JOINTS, 'trajectory.joint_names is empty')
    seen: set = set()
    for n in names:
        if n in seen:
            return Refusal(INVALID_JOINTS, f'trajectory.joint_names: {n!r} is given twice')
        seen.add(n)
        if n not in axes:
            return Refusal(INVALID_JOINTS, f'trajectory.joint_names: {n!r} is not an axis of this '
                                           f'controller (axes: {", ".join(axes)})')
    return None


def _from_here(spec: dict, axes: Mapping[str, Axis], values) -> dict | Refusal:
    """A first point at t=0 within coarse_position_tolerance of every axis's commanded position
    takes the axes' commanded state (position, and velocity and acceleration where the points
    carry them): the trajectory starts from it without a jump. Malformed points are left for
    the trajectory check to refuse."""
    times, names = spec['times'], spec['names']
    if not times or times[0] != 0.0 or len(spec['positions'][0]) != len(names):
        return spec
    own = [axes[n].path_state for n in names]
    for name, p, state in zip(names, spec['positions'][0], own):
        tol = float(values[name]['coarse_position_tolerance'])
        if not math.isfinite(p):
            return spec
        if abs(p - state[0]) > tol:
            return Refusal(INVALID_GOAL, (
                f'{name}: point 0 (t=0) is at {p:.9g} m, {abs(p - state[0]):.3g} m from the '
                f'commanded position {state[0]:.9g} m, more than coarse_position_tolerance '
                f'{tol:g} m (a trajectory starts where the axis is)'))
    out = dict(spec)
    for k, key in enumerate(('positions', 'velocities', 'accelerations')):
        rows = spec[key]
        if rows and len(rows[0]) == len(names):
            out[key] = [[state[k] for state in own]] + list(rows[1:])
    return out


def check(request: GoalRequest, axes: Mapping[str, Axis], values: Mapping[str, Mapping],
          prepare: Callable[[dict], Any], now: float,
          max_ahead: float = 60.0) -> CheckedGoal | Refusal:
    """Check a goal as a whole and build its trajectory (`prepare`: ServoLoop.prepare, which
    returns a Prepared or the refusal). `values` are the axes' registers; `now` [s] the clock the
    stamp is read against; a stamp up to `max_ahead` s ahead schedules the start. Reads the axes
    only: may run off the servo thread, as the trajectory's preparation does."""
    spec = request.trajectory
    names = tuple(spec['names'])
    if request.multi_dof_names:
        return Refusal(INVALID_JOINTS, f'multi_dof_trajectory names {request.multi_dof_names[0]!r}'
                                       ': this controller has no multi-DOF joints')
    refusal = _names_refusal(names, axes)
    if refusal:
        return refusal
    tolerances = _tolerances(names, values, request)
    if isinstance(tolerances, Refusal):
        return tolerances
    times = tuple(spec['times'])
    trimmed = _from_here(spec, axes, values)
    if isinstance(trimmed, Refusal):
        return trimmed
    job = prepare(trimmed)
    if isinstance(job, str):
        return Refusal(INVALID_GOAL, job)
    duration = float(job.trajectory.duration)
    stamp = request.stamp
    start = None
    if stamp > now:
        if stamp - now > max_ahead:
            return Refusal(INVALID_GOAL, f'header.stamp is {stamp - now:.3f} s ahead of the '
                                         f'controller\'s clock (at most {max_ahead:g} s)')
        start = stamp
    elif stamp and stamp + duration < now:
        late = now - stamp - duration
        return Refusal(OLD_HEADER_TIMESTAMP, f'header.stamp {stamp:.3f} s: the trajectory '
                                             f'({duration:.3f} s) ended {late:.3f} s ago')
    return CheckedGoal(names, job, tolerances, start, times)


# ------------------------------------------------------------------------- the state machine

WAITING, RUNNING, CANCELING = 'waiting', 'running', 'canceling'


@dataclass
class _Goal:
    handle: Any
    goal: CheckedGoal
    phase: str = WAITING
    t0: float = 0.0                                # servo time of its start [s]
    paths: dict = field(default_factory=dict)      # {axis: the path it follows}
    ends: dict = field(default_factory=dict)       # {axis: its last position}
    epochs: dict = field(default_factory=dict)     # {axis: command_epoch at the start}
    duration: float = 0.0
    cancel: bool = False


def errors(axis: Axis) -> tuple[float, float, float]:
    """Following error (against the command of the sample's time), velocity and acceleration
    errors against the command."""
    p = axis.profile
    return (axis.following_error, p.velocity - axis.actual_vel,
            p.acceleration - actual_acceleration(axis))


def actual_acceleration(axis: Axis) -> float:
    """The acceleration of the encoder the velocity loop reads (as Axis.actual_vel)."""
    return axis.load_acc if axis.r['feedback'] == 'load' else axis.motor_acc


def _gravity(cause: str) -> int:
    """How grave what stopped an axis is (Axis.cancelled_by): faults, ABORT, disable, ESTOP,
    STOP."""
    return {'STOP': 0, 'ESTOP': 1, 'disable': 2, 'ABORT': 3}.get(cause, 4)


class GoalRunner:
    """The goal being executed (one at a time, as JTC). `start(job, now)` starts a checked
    trajectory now (the node: ServoLoop.trajectory) and returns its refusal or None. Every
    method returns the goals that ended, for the action server to report."""

    def __init__(self, axes: Mapping[str, Axis], start: Callable[[Any, float], str | None]):
        self.axes = axes
        self._start = start
        self.active: _Goal | None = None

    # -- inputs -------------------------------------------------------------------------------
    def submit(self, handle, checked: CheckedGoal | Refusal, now: float,
               cancelled: bool = False) -> list[Ended]:
        """A new goal (checked, or its refusal). A refused goal changes nothing: the running one
        goes on. Otherwise it preempts the running goal, whose axes that the new one does not
        take are stopped."""
        if isinstance(checked, Refusal):
            return [Ended(handle, ABORTED, checked.code, checked.text)]
        if cancelled:
            return [Ended(handle, CANCELED, SUCCESSFUL, 'canceled before its start')]
        goal = _Goal(handle, checked)
        if checked.start is None or checked.start <= now:
            refusal = self._begin(goal, now)
            if refusal:
                return [Ended(handle, ABORTED, INVALID_GOAL, refusal)]
        else:
            goal.epochs = {a: self.axes[a].command_epoch for a in checked.names}
        ended = []
        old = self.active
        if old is not None:
            when = ('' if goal.phase == RUNNING else
                    f', which starts at {checked.start:.3f} s')
            outcome = CANCELED if old.cancel else ABORTED
            ended.append(self._end(old, outcome, INVALID_GOAL if outcome == ABORTED
                                   else SUCCESSFUL, f'preempted by a new goal{when}',
                                   keep=set(checked.names)))
        self.active = goal
        return ended

    def cancel(self, handle) -> None:
        """A cancel request for `handle` (accepted): judged at the next tick."""
        g = self.active
        if g is not None and g.handle is handle:
            g.cancel = True

    def abort(self, text: str) -> list[Ended]:
        """End the goal now (the node is stopping), touching no axis."""
        g = self.active
        return [] if g is None else [self._end(g, ABORTED, INVALID_GOAL, text, stop=False)]

    # -- the tick -----------------------------------------------------------------------------
    def tick(self, now: float) -> list[Ended]:
        """After a servo tick at `now` [s]: judge the goal."""
        g = self.active
        if g is None:
            return []
        if g.phase == WAITING:
            return self._waiting(g, now)
        if g.phase == CANCELING:
            if all(not self.axes[a].profile.moving or not self.axes[a].enabled
                   for a in g.goal.names):
                return [self._end(g, CANCELED, SUCCESSFUL, f'canceled: {self._where(g)}',
                                  stop=False)]
            return []
        t = now - g.t0
        when = f'at t={t:.3f} s of {g.duration:.3f} s'
        left = [a for a in g.goal.names if self.axes[a].command_epoch != g.epochs[a]]
        if left:
            # (the coordinate system stops the others of a trajectory one axis left, in the
            # same tick: the gravest cause first)
            left.sort(key=lambda a: -_gravity(self.axes[a].cancelled_by))
            causes = ', '.join(f'{a}: {self.axes[a].cancelled_by}' for a in left)
            return [self._end(g, ABORTED, INVALID_GOAL, f'{causes} ended the goal {when}')]
        for a in g.goal.names:
            if not self._on_path(g, a):
                return [self._end(g, ABORTED, INVALID_GOAL, (
                    f'{a}: another command (joint_trajectory, target_position or '
                    f'target_velocity) took the axis off the goal\'s path {when}'))]
        if g.cancel:
            g.phase = CANCELING
            self._stop(g)
            return self.tick(now)
        if t < g.duration:
            for a in g.goal.names:
                exceeded = g.goal.tolerances[a].path.excess(errors(self.axes[a]))
                if exceeded:
                    what, err, tol = exceeded
                    unit = dict(_QUANTITIES)[what]
                    return [self._end(g, ABORTED, PATH_TOLERANCE_VIOLATED, (
                        f'{a}: {what} error {err:+.4g} {unit} exceeds the path tolerance '
                        f'{tol:g} {unit} by {abs(err) - tol:.3g} {unit} {when}; the axes '
                        'stop'))]
            return []
        return self._judge(g, t)

    def _waiting(self, g: _Goal, now: float) -> list[Ended]:
        start = g.goal.start
        assert start is not None                     # (waiting: a stamp ahead)
        for a in g.goal.names:
            axis = self.axes[a]
            if axis.command_epoch != g.epochs[a]:
                return [self._end(g, ABORTED, INVALID_GOAL,
                                  f'{a}: {axis.cancelled_by} before the goal\'s start '
                                  f'(stamped {start:.3f} s)', stop=False)]
        if g.cancel:
            return [self._end(g, CANCELED, SUCCESSFUL, 'canceled before its start', stop=False)]
        if now + 1e-9 >= start:
            refusal = self._begin(g, now)
            if refusal:
                return [self._end(g, ABORTED, INVALID_GOAL, refusal, stop=False)]
        return []

    def _judge(self, g: _Goal, t: float) -> list[Ended]:
        """After the trajectory's end: every axis settled and within its goal tolerance, or
        one past its goal_time."""
        waiting = False
        for a in g.goal.names:
            axis = self.axes[a]
            error = g.ends[a] - axis.actual_pos
            exceeded = g.goal.tolerances[a].goal.excess(
                (error, axis.actual_vel, actual_acceleration(axis)))
            if axis.word & _DONE and not exceeded:
                continue
            goal_time = g.goal.tolerances[a].goal_time
            if not (goal_time > 0.0 and t - g.duration > goal_time):
                waiting = True                  # still within its time
                continue
            if exceeded:
                what, err, tol = exceeded
                unit = dict(_QUANTITIES)[what]
                text = (f'{a}: {what} error {err:+.4g} {unit} exceeds the goal tolerance '
                        f'{tol:g} {unit} by {abs(err) - tol:.3g} {unit}')
            else:
                text = f'{a}: not settled (MOTION_DONE), position error {error:+.4g} m'
            return [self._end(g, ABORTED, GOAL_TOLERANCE_VIOLATED,
                              f'{text}, {goal_time:g} s (goal_time) after the trajectory\'s end',
                              stop=False)]
        if waiting:
            return []
        where = self._where(g, with_errors=True)
        last = self._state(g, g.t0 + t)
        return [self._end(g, SUCCEEDED, SUCCESSFUL, f'reached at t={t:.3f} s: {where}',
                          stop=False)._replace(last=last)]

    # -- what the action server reads ---------------------------------------------------------
    def feedback(self, now: float) -> Feedback | None:
        """The running goal's state now (None when none runs)."""
        g = self.active
        if g is None or g.phase == WAITING:
            return None
        return self._state(g, now)

    def _state(self, g: _Goal, now: float) -> Feedback:
        desired, actual, error = [], [], []
        for a in g.goal.names:
            axis = self.axes[a]
            p = axis.profile
            desired.append((axis.command_position, p.velocity, p.acceleration))
            actual.append((axis.actual_pos, axis.actual_vel, actual_acceleration(axis)))
            error.append(errors(axis))
        index = bisect.bisect_right(g.goal.times, now - g.t0)
        return Feedback(g.goal.names, tuple(desired), tuple(actual), tuple(error), index,
                        now - g.t0)

    def desired_at(self, when: float) -> tuple[tuple, list] | str:
        """QueryTrajectoryState: (names, [(p, v, a) per axis]) the goal's trajectory commands
        at time `when` [s, the node's clock], or why not."""
        g = self.active
        if g is None:
            return 'no follow_joint_trajectory goal is active'
        start = g.t0 if g.phase != WAITING else g.goal.start
        assert start is not None
        duration = float(g.goal.job.trajectory.duration)
        t = min(max(when - start, 0.0), duration) if -1e-9 <= when - start <= duration + 1e-9 \
            else when - start
        if t < -1e-9:
            return f'{when:.3f} s is before the trajectory\'s start ({start:.3f} s)'
        if t > duration + 1e-9:
            return f'{when:.3f} s is after the trajectory\'s end ({start + duration:.3f} s)'
        if g.phase == WAITING:
            p, v, acc = g.goal.job.trajectory.sample(t)
            return g.goal.names, [(float(p[j]), float(v[j]), float(acc[j]))
                                  for j in range(len(g.goal.names))]
        return g.goal.names, [tuple(g.paths[a].at(t)) for a in g.goal.names]

    # -- internals ----------------------------------------------------------------------------
    def _begin(self, g: _Goal, now: float) -> str | None:
        refusal = self._start(g.goal.job, now)
        if refusal:
            return refusal
        g.phase, g.t0 = RUNNING, now
        for a in g.goal.names:
            axis = self.axes[a]
            path = axis.profile.path
            assert path is not None                 # (started: the axis follows its share)
            g.paths[a] = path
            g.ends[a] = float(path.end)
            g.epochs[a] = axis.command_epoch
        g.duration = max(float(p.duration) for p in g.paths.values())
        return None

    def _on_path(self, g: _Goal, a: str) -> bool:
        """Axis `a` still runs the goal's path, or holds its end (the sampled loop's correction
        moves keep the target but leave the path)."""
        axis = self.axes[a]
        p = axis.profile
        path = g.paths[a]
        return p.following(path) or ((p.path is path or p.path is None)
                                     and axis.target == g.ends[a])

    def _stop(self, g: _Goal, keep=frozenset()) -> None:
        """Stop the goal's axes still on its path (not those in `keep`: a new goal takes them)."""
        for a in g.goal.names:
            if a not in keep and g.phase != WAITING and a in g.paths \
                    and self.axes[a].profile.following(g.paths[a]):
                self.axes[a].stop('stop')

    def _where(self, g: _Goal, with_errors: bool = False) -> str:
        parts = []
        for a in g.goal.names:
            pos = self.axes[a].actual_pos
            text = f'{a} at {pos:.7f} m'
            if with_errors and a in g.ends:
                text += f' (error {(g.ends[a] - pos) * 1e6:+.2f} µm)'
            parts.append(text)
        return ', '.join(parts)

    def _end(self, g: _Goal, outcome: str, code: int, text: str, stop: bool = True,
             keep=frozenset()) -> Ended:
        if stop:
            self._stop(g, keep)
        if self.active is g:
            self.active = None
        return Ended(g.handle, outcome, code, text)
