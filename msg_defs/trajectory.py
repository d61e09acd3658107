"""Build and read trajectory_msgs/JointTrajectory, the carrier of timed multi-axis paths.

Reading only converts the message into plain lists; the whole trajectory is checked by the core
(motion_ctrl.core.trajectory), which says which axis, point and limit a refusal is about.
"""
import struct

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


def trajectory_counts(data: bytes) -> tuple[int, int] | None:
    """(joint names, points) of a serialized JointTrajectory, read from its CDR without decoding
    it (a few header fields and the names' lengths: microseconds for any size), so that an
    oversized one is refused by its counts before rclpy builds a Python object per point. None
    when `data` is not little- or big-endian CDR of that shape (it is then decoded and refused
    as such)."""
    if len(data) < 16 or data[0] != 0 or data[1] not in (0, 1):
        return None
    u32 = struct.Struct('<I' if data[1] == 1 else '>I').unpack_from
    pos = 4 + 8                                  # encapsulation; stamp: sec, nanosec

    def read_u32() -> int:
        nonlocal pos
        pos = 4 + ((pos - 4 + 3) & ~3)           # aligned to 4 from the body's start
        if pos + 4 > len(data):
            raise ValueError
        (v,) = u32(data, pos)
        pos += 4
        return v

    try:
        length = read_u32()                       # frame_id (the length counts its NUL)
        pos += length
        names = read_u32()
        if names > (len(data) - pos) // 4:
            return None
        for _ in range(names):
            length = read_u32()
            pos += length
        points = read_u32()
    except (ValueError, struct.error):
        return None
    return names, points
