"""Read and build the control_msgs messages of the trajectory action (doc/interface.md, "The
trajectory action and state"): a FollowJointTrajectory goal as plain data, its feedback,
JointTrajectoryControllerState and the QueryTrajectoryState answer. control_msgs is imported here
only (scripts/bootstrap builds it into .venv; a ROS install has its own).

The values are the core's (motion_ctrl.core.follow_goal): per axis (position, velocity,
acceleration) triples, SI units.
"""
from builtin_interfaces.msg import Duration
from control_msgs.action import FollowJointTrajectory
from control_msgs.msg import JointTrajectoryControllerState
from trajectory_msgs.msg import JointTrajectoryPoint

from msg_defs.trajectory import read_joint_trajectory


def _seconds(t) -> float:
    return t.sec + t.nanosec * 1e-9


def read_follow_goal(goal) -> dict:
    """The keyword arguments of motion_ctrl.core.follow_goal.GoalRequest, from a
    FollowJointTrajectory.Goal."""
    return {
        'trajectory': read_joint_trajectory(goal.trajectory),
        'stamp': _seconds(goal.trajectory.header.stamp),
        'multi_dof_names': tuple(goal.multi_dof_trajectory.joint_names),
        'path_tolerance': tuple((t.name, t.position, t.velocity, t.acceleration)
                                for t in goal.path_tolerance),
        'goal_tolerance': tuple((t.name, t.position, t.velocity, t.acceleration)
                                for t in goal.goal_tolerance),
        'component_joints': tuple(t.joint_name for t in (*goal.component_path_tolerance,
                                                         *goal.component_goal_tolerance)),
        'goal_time_tolerance': _seconds(goal.goal_time_tolerance),
    }


def _point(states, time_from_start: float | None = None, effort=None) -> JointTrajectoryPoint:
    """A JointTrajectoryPoint of (position, velocity, acceleration) per joint."""
    point = JointTrajectoryPoint()
    point.positions = [float(s[0]) for s in states]
    point.velocities = [float(s[1]) for s in states]
    point.accelerations = [float(s[2]) for s in states]
    if effort is not None:
        point.effort = [float(v) for v in effort]
    if time_from_start is not None:
        ns = max(round(time_from_start * 1e9), 0)
        point.time_from_start = Duration(sec=ns // 1_000_000_000, nanosec=ns % 1_000_000_000)
    return point


def feedback(stamp, names, desired, actual, error, index: int, t: float):
    """FollowJointTrajectory.Feedback; `t` [s] is the time from the trajectory's start."""
    msg = FollowJointTrajectory.Feedback()
    msg.header.stamp = stamp
    msg.joint_names = list(names)
    msg.desired = _point(desired, t)
    msg.actual = _point(actual, t)
    msg.error = _point(error, t)
    msg.index = int(index)
    return msg


def result(code: int, text: str):
    return FollowJointTrajectory.Result(error_code=int(code), error_string=text)


def controller_state(stamp, names, reference, feedback, error, output_volts):
    """JointTrajectoryControllerState: `output` carries the amplifier command [V] as effort
    (what this controller outputs)."""
    msg = JointTrajectoryControllerState()
    msg.header.stamp = stamp
    msg.joint_names = list(names)
    msg.reference = _point(reference)
    msg.feedback = _point(feedback)
    msg.error = _point(error)
    msg.output = JointTrajectoryPoint(effort=[float(v) for v in output_volts])
    msg.speed_scaling_factor = 1.0
    return msg


def query_answer(response, names, states, message: str = ''):
    """Fill a QueryTrajectoryState response: success with the states, or not with `message`."""
    response.success = states is not None
    response.message = message
    response.name = list(names)
    if states is not None:
        response.position = [float(s[0]) for s in states]
        response.velocity = [float(s[1]) for s in states]
        response.acceleration = [float(s[2]) for s in states]
    return response
