"""Build and read sensor_msgs/JointState, the carrier of every per-joint stream here."""
import math
import time
from array import array

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


class Stream:
    """A publisher whose refusals are counted and handed to `on_error(topic, exception)`, not
    raised: a servo loop must not die because one observer is slow (Fast DDS refuses a write to
    a reliable reader that is far behind: "cannot publish data"; seen killing the controller in
    its tick)."""

    def __init__(self, publisher, on_error=None, refresh: float = 0.0):
        """`refresh`: how long [s, wall time] `wanted` may answer from its last look at the
        readers (0: it looks every time, ~3 µs)."""
        self.publisher = publisher
        self.on_error = on_error
        self.failures = 0
        self.refresh = refresh
        self._wanted = False
        self._looked = -math.inf

    def wanted(self) -> bool:
        """Whether anybody subscribes: a sample nobody reads need not be built (a volatile
        stream's later reader could not get it anyway)."""
        if self.refresh > 0.0:
            now = time.monotonic()
            if now - self._looked < self.refresh:
                return self._wanted
            self._looked = now
        self._wanted = self.publisher.get_subscription_count() > 0
        return self._wanted

    def send(self, msg) -> bool:
        """Publish `msg`; True when the middleware took it."""
        try:
            self.publisher.publish(msg)
            return True
        except Exception as e:       # rclpy's RCLError from rmw_publish (not importable here)
            self.failures += 1
            if self.on_error is not None:
                self.on_error(self.publisher.topic_name, e)
            return False


class JointStateStream(Stream):
    """Publishes one JointState stream at the servo rate without rebuilding the message.

    A JointState costs ~20 us to construct in rclpy (header, stamp, field checks); at 1 kHz and
    several streams that is a large part of a tick. The message is built once per set of names
    and its fields are replaced by arrays (the setters' fast path). A stream nobody subscribes
    to is neither built nor serialised (`wanted`); `msg` holds the latest sample published.
    """

    def __init__(self, publisher, on_error=None, refresh: float = 0.0):
        super().__init__(publisher, on_error, refresh)
        self.msg = JointState()
        self.names: list | None = None

    def publish(self, stamp, names, position=(), velocity=(), effort=()) -> None:
        if not self.wanted():
            return
        m = self.msg
        if names != self.names:
            self.names = list(names)
            m.name = self.names
        m.header.stamp = stamp
        m.position = array('d', position)
        m.velocity = array('d', velocity)
        m.effort = array('d', effort)
        self.send(m)

