"""Build and read trajectory_msgs/JointTrajectory, the carrier of timed multi-axis paths.

Reading only converts the message into plain lists; the whole trajectory is checked by the core
(motion_ctrl.core.trajectory), which says which axis, point and limit a refusal is about.
"""
from trajectory_msgs.msg import JointTrajectory, JointTrajectoryPoint


def joint_trajectory(stamp, names, times, positions, velocities=None,
                     accelerations=None) -> JointTrajectory:
    """A JointTrajectory: `times` [s from start], `positions[i]` one value per name (and
    velocities / accelerations likewise, or None to leave them out)."""
    msg = JointTrajectory()
    msg.header.stamp = stamp
    msg.joint_names = list(names)
    for i, t in enumerate(times):
        point = JointTrajectoryPoint()
        point.positions = [float(v) for v in positions[i]]
        if velocities is not None:
            point.velocities = [float(v) for v in velocities[i]]
        if accelerations is not None:
            point.accelerations = [float(v) for v in accelerations[i]]
        ns = round(float(t) * 1e9)
        point.time_from_start.sec, point.time_from_start.nanosec = divmod(ns, 1_000_000_000)
        msg.points.append(point)
    return msg


def read_joint_trajectory(msg) -> dict:
    """{'names', 'times' [s], 'positions', 'velocities', 'accelerations'} as plain lists, one
    list per point (an empty list where a point leaves a field out)."""
    points = list(msg.points)
    return {
        'names': list(msg.joint_names),
        'times': [p.time_from_start.sec + p.time_from_start.nanosec * 1e-9 for p in points],
        'positions': [list(p.positions) for p in points],
        'velocities': [list(p.velocities) for p in points],
        'accelerations': [list(p.accelerations) for p in points],
    }
