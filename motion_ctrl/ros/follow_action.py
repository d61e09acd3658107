"""The controller node's trajectory action and state, as ros2_controllers'
joint_trajectory_controller offers them (doc/interface.md, "The trajectory action"; the rules are
motion_ctrl.core.follow_goal's, the user documentation doc/follow_joint_trajectory.md):

* `<node>/follow_joint_trajectory` (control_msgs/action/FollowJointTrajectory): every goal is
  accepted; its checks run on a thread of their own in real time (a 400-point trajectory takes
  milliseconds, as on `joint_trajectory`), or at once in sim time; the next servo tick hands the
  outcome to the GoalRunner, which starts it or ends it with the refusal's code. After each servo
  tick the runner judges the goal (plain comparisons) and the goals it ended get their result;
  the execute callback only awaits that. Feedback at `action_monitor_rate`, and a last one
  as a goal succeeds: its state at the end, `index` past the last point.
* `<node>/controller_state` (control_msgs/msg/JointTrajectoryControllerState) of every axis at
  `state_publish_rate` (reference = the command, feedback = the actual position, error = the
  following error, output.effort = the amplifier command in volts), built only while somebody
  subscribes.
* `<node>/query_state` (control_msgs/srv/QueryTrajectoryState): the running goal's desired state
  at a time.

The node calls `tick(now)` after each servo tick; nothing here waits. Without control_msgs (a
build that has none) the node runs without them and says so once.
"""
from __future__ import annotations

import queue
import threading

from rclpy.action import ActionServer, CancelResponse, GoalResponse
from rclpy.task import Future

import msg_defs as md
from motion_ctrl.core import follow_goal as fg

try:
    from control_msgs.action import FollowJointTrajectory
    from control_msgs.msg import JointTrajectoryControllerState
    from control_msgs.srv import QueryTrajectoryState

    import msg_defs.follow as mf
except ImportError as e:             # (a build without control_msgs: the server says so)
    _NO_CONTROL_MSGS: ImportError | None = e
else:
    _NO_CONTROL_MSGS = None


class FollowJointTrajectoryServer:
    """On `node` (a ControllerNode), with the node's limits on a trajectory: how far ahead a
    stamp may schedule it [s], most joint names, most points ({'with accelerations': n,
    'without': n})."""

    def __init__(self, node, max_ahead: float, max_names: int, max_points: dict):
        self.node = node
        self.limits = max_ahead, max_names, max_points
        self.runner: fg.GoalRunner | None = None
        if _NO_CONTROL_MSGS is not None:
            node.get_logger().warning(
                f'control_msgs is not installed ({_NO_CONTROL_MSGS}): follow_joint_trajectory, '
                'controller_state and query_state are not offered (scripts/bootstrap builds it; a '
                'ROS install: apt install ros-$ROS_DISTRO-control-msgs)')
            return
        self.mf = mf
        self.runner = fg.GoalRunner(node.axes, self._start)
        self.to_check: queue.SimpleQueue = queue.SimpleQueue()     # _Goal to check
        self.checked: queue.SimpleQueue = queue.SimpleQueue()      # (_Goal, outcome) to submit
        self.server = ActionServer(node, FollowJointTrajectory, md.FOLLOW_JOINT_TRAJECTORY,
                                   execute_callback=self._execute,
                                   goal_callback=lambda goal: GoalResponse.ACCEPT,
                                   cancel_callback=self._cancel_callback)
        self.cancel_ok = CancelResponse.ACCEPT
        rate = node.get_parameter('action_monitor_rate').value
        self.feedback_every = max(1, round(node.servo_rate / rate))
        self.ticks = 0
        self.query = node.create_service(QueryTrajectoryState, md.QUERY_STATE, self._query)
        state_rate = node.get_parameter('state_publish_rate').value
        self.state = None
        if state_rate > 0:
            self.state = node.stream(JointTrajectoryControllerState, md.CONTROLLER_STATE, 10)
            node.create_timer(1.0 / state_rate, self._publish_state)
        if not node.sim_time:
            threading.Thread(target=self._check_loop, name='trajectory goals',
                             daemon=True).start()

    # -- goals -------------------------------------------------------------------------------
    async def _execute(self, handle):
        """Every goal: checked (off the servo thread in real time), then started and judged by
        the servo tick, which sets its end; this only awaits the result."""
        goal = _Goal(handle, Future())
        if self.node.sim_time:              # deterministic: checked at once
            self.checked.put((goal, self._check(handle.request)))
        else:
            self.to_check.put(goal)
        return await goal.done

    def _cancel_callback(self, handle):
        active = self.runner.active
        if active is not None and active.handle.handle is handle:
            self.runner.cancel(active.handle)          # (judged at the next tick)
        return self.cancel_ok

    def _check_loop(self) -> None:
        while (goal := self.to_check.get()) is not None:             # (None: the node goes)
            self.checked.put((goal, self._check(goal.handle.request)))

    def _check(self, goal) -> fg.CheckedGoal | fg.Refusal:
        max_ahead, max_names, max_points = self.limits
        points = goal.trajectory.points
        kind = 'with accelerations' if any(p.accelerations for p in points) else 'without'
        if len(points) > max_points[kind] or len(goal.trajectory.joint_names) > max_names:
            return fg.Refusal(fg.INVALID_GOAL, f'{len(points)} points for '
                                               f'{len(goal.trajectory.joint_names)} joints (at '
                                               f'most {max_points[kind]} points {kind}: send a '
                                               'longer path in parts)')
        loop = self.node.loop
        try:
            request = fg.GoalRequest(**self.mf.read_follow_goal(goal))
        except (TypeError, ValueError) as e:
            return fg.Refusal(fg.INVALID_GOAL, f'not a readable goal: {e}')
        return fg.check(request, self.node.axes, loop.values, loop.prepare, self._now(),
                        max_ahead)

    def _start(self, job, now: float):
        """Start a checked goal's trajectory now (as a joint_trajectory starts)."""
        loop = self.node.loop
        self.node._log(loop.unschedule(list(job.spec['names']), 'a follow_joint_trajectory goal'))
        return loop.trajectory(job, None, now)

    def tick(self, now: float) -> None:
        """After each servo tick: goals checked since are submitted, the goal is judged, and
        every action_monitor_rate its feedback goes out."""
        runner = self.runner
        if runner is None:
            return
        while not self.checked.empty():
            goal, outcome = self.checked.get_nowait()
            self._report(runner.submit(goal, outcome, now, goal.handle.is_cancel_requested))
        if runner.active is None:
            return
        self._report(runner.tick(now))
        self.ticks += 1
        if self.ticks % self.feedback_every == 0:
            g = runner.active
            fb = runner.feedback(now)
            if g is not None and fb is not None:
                self._send_feedback(g.handle.handle, fb)

    def _send_feedback(self, handle, fb: fg.Feedback) -> None:
        handle.publish_feedback(self.mf.feedback(
            self.node.get_clock().now().to_msg(), fb.names, fb.desired, fb.actual, fb.error,
            fb.next_point, fb.time))

    def _report(self, ended: list[fg.Ended]) -> None:
        log = self.node.get_logger()
        for e in ended:
            handle = e.handle.handle
            try:
                if e.last is not None:          # (the last feedback: the goal at its end)
                    self._send_feedback(handle, e.last)
                if e.outcome == fg.SUCCEEDED:
                    handle.succeed()
                elif e.outcome == fg.CANCELED and handle.is_cancel_requested:
                    handle.canceled()
                else:
                    handle.abort()
            except Exception as err:     # (rclpy: the goal's state did not allow it)
                log.error(f'follow_joint_trajectory: goal state not set ({err!r})')
            e.handle.done.set_result(self.mf.result(e.code, e.text))
            text = f'follow_joint_trajectory goal {_short(handle)} {e.outcome} ({e.code}): {e.text}'
            if e.outcome == fg.SUCCEEDED:
                log.info(text)
            else:
                log.warning(text)

    # -- state and query ---------------------------------------------------------------------
    def _publish_state(self) -> None:
        state = self.state
        if state is None or not state.publisher.get_subscription_count():
            return
        axes = self.node.axes
        reference, actual, error, output = [], [], [], []
        for axis in axes.values():
            p = axis.profile
            acc = fg.actual_acceleration(axis)
            reference.append((axis.command_position, p.velocity, p.acceleration))
            actual.append((axis.actual_pos, axis.actual_vel, acc))
            error.append(fg.errors(axis))
            output.append(axis.output)
        state.send(self.mf.controller_state(self.node.get_clock().now().to_msg(), list(axes),
                                            reference, actual, error, output))

    def _query(self, request, response):
        when = request.time.sec + request.time.nanosec * 1e-9
        desired = self.runner.desired_at(when) if self.runner else 'no goal'
        if isinstance(desired, str):
            return self.mf.query_answer(response, list(self.node.axes), None, desired)
        names, states = desired
        return self.mf.query_answer(response, names, states)

    def _now(self) -> float:
        return self.node.get_clock().now().nanoseconds * 1e-9

    def destroy(self) -> None:
        """The node goes: the check thread ends, a running goal is aborted (its axes are the
        node's to stop)."""
        self.to_check.put(None)
        if self.runner is not None:
            self._report(self.runner.abort('the controller is stopping'))


class _Goal:
    """A goal as the runner knows it: rclpy's goal handle and the Future its execute awaits."""
    __slots__ = ('handle', 'done')

    def __init__(self, handle, done):
        self.handle, self.done = handle, done


def _short(handle) -> str:
    """The first 8 hex digits of a goal's UUID, for the log."""
    try:
        return bytes(handle.goal_id.uuid).hex()[:8]
    except (AttributeError, TypeError):
        return '?'
