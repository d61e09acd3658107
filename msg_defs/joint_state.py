"""Build and read sensor_msgs/JointState, the carrier of every per-joint stream here."""
import math

from sensor_msgs.msg import JointState


class MalformedMessage(ValueError):
    """A message the receiver refuses: wrong array lengths, unknown names, non-finite values."""


def joint_state(stamp, names, position=(), velocity=(), effort=()) -> JointState:
    msg = JointState()
    msg.header.stamp = stamp
    msg.name = list(names)
    msg.position = [float(v) for v in position]
    msg.velocity = [float(v) for v in velocity]
    msg.effort = [float(v) for v in effort]
    return msg


def read_joint_state(msg, field: str, known=None, allow_nonfinite=False) -> dict:
    """Return {name: value} of one field ('position', 'velocity' or 'effort').

    Refuses (MalformedMessage, with a reason) a field whose length differs from `name`, a name
    outside `known` (when given), duplicated names and NaN/inf values. Nothing is returned partly:
    one bad entry refuses the whole message, so a target set is applied to all axes or none.
    """
    names = list(msg.name)
    values = list(getattr(msg, field))
    if not names:
        raise MalformedMessage('no joint names')
    if len(values) != len(names):
        raise MalformedMessage(
            f'{field} has {len(values)} entries for {len(names)} names {names}')
    if len(set(names)) != len(names):
        raise MalformedMessage(f'duplicate joint names {names}')
    if known is not None:
        unknown = [n for n in names if n not in known]
        if unknown:
            raise MalformedMessage(f'unknown axis {unknown}, known: {sorted(known)}')
    if not allow_nonfinite:
        bad = [n for n, v in zip(names, values) if not math.isfinite(v)]
        if bad:
            raise MalformedMessage(f'non-finite {field} for {bad}')
    return dict(zip(names, values))
