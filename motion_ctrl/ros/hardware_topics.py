"""`hardware: topics`: the servo loop's I/O over the `command` / `encoders` topics (the plant node,
or a drive bridge of another make that speaks them), behind the loop's hardware interface
(motion_ctrl.core.hardware).

* The encoder samples arrive on the `encoders` subscription between ticks and go into the axes'
  AxisIO as they come (the newest by stamp: a sample that comes twice or late is dropped). With
  `use_sim_time` each new sample is one tick (the node's `on_sample` runs the cycle at the
  sample's stamp, as a drive synchronised to its fieldbus cycle), and a sample sent again (the
  lockstep plant resends until answered) is answered with the command already computed for it.
* `write` publishes `command` (effort = volts) stamped with the tick's time: the ROS stamp the
  node gave it (`stamp_tick`), to the nanosecond, as its other streams of the tick are (seconds
  since 1970 in a float are good to a quarter of a microsecond only).
* `deactivate` commands 0 V on every axis and waits (bounded) for the reliable readers'
  acknowledgement, so that the message has left before the process does; the plant's amplifier
  watchdog disables the amplifiers once commands stop.
"""
from __future__ import annotations

import math
from collections.abc import Callable

from builtin_interfaces.msg import Time
from rclpy.duration import Duration
from sensor_msgs.msg import JointState

import msg_defs as md
from motion_ctrl.core.hardware import HardwareInterface

# s: the longest a stopping controller waits for its last command (0 V) to be acknowledged
SHUTDOWN_ACK_WAIT = 0.2


def stamp_of(seconds: float) -> Time:
    """A ROS stamp from seconds (whole nanoseconds, as every stamp here is)."""
    return stamp_ns(round(seconds * 1e9))


def stamp_ns(ns: int) -> Time:
    """A ROS stamp from integer nanoseconds, exactly."""
    return Time(sec=ns // 1_000_000_000, nanosec=ns % 1_000_000_000)


def seconds_of(stamp) -> float:
    return stamp.sec + stamp.nanosec * 1e-9


class TopicsHardware(HardwareInterface):
    kind = 'topics'

    def __init__(self, node, axes, on_sample: Callable | None = None) -> None:
        """`on_sample(stamp msg)`, if given, runs after every encoder message is taken (the node
        ticks on it in sim time, or moves its timer's phase in real time)."""
        super().__init__(axes)
        self.node = node
        self.on_sample = on_sample
        self.joints = [(self.io[a], md.motor_joint(a), md.load_joint(a)) for a in self.axes]
        self.pub_command: md.JointStateStream | None = None
        self._stamp = None                  # the tick's ROS stamp, for `now` = _stamp_now
        self._stamp_now = math.nan

    def on_configure(self) -> None:
        self.pub_command = self.node.stream(JointState, md.COMMAND)
        self.node.create_subscription(JointState, md.ENCODERS, self._on_encoders,
                                      md.SERVO_READ_QOS)

    def on_deactivate(self) -> None:
        pub = self.pub_command
        assert pub is not None                   # (configured)
        pub.publish(self.node.get_clock().now().to_msg(), self.axes,
                    effort=[0.0] * len(self.axes))
        pub.publisher.wait_for_all_acked(Duration(seconds=SHUTDOWN_ACK_WAIT))

    def _on_encoders(self, msg: JointState) -> None:
        try:
            counts = md.read_joint_state(msg, 'position')
        except md.MalformedMessage as e:
            self.node.get_logger().warning(f'encoders ignored: {e}', throttle_duration_sec=1.0)
            return
        stamp = seconds_of(msg.header.stamp)
        used = False
        for io, motor, load in self.joints:
            m, l = counts.get(motor), counts.get(load)
            if m is not None and l is not None:
                io.sample(int(m), int(l), stamp)
                used = True
        # (a message with no whole sample of ours is not a sample: it neither ticks the loop
        # in sim time nor moves the timer's phase)
        if used and self.on_sample is not None:
            self.on_sample(msg.header.stamp)

    def stamp_tick(self, stamp, now: float) -> None:
        """The ROS stamp (a builtin_interfaces/Time) of the tick at `now` [s]."""
        self._stamp, self._stamp_now = stamp, now

    def resend(self) -> None:
        """The last command again (a lockstep plant that sent its sample twice did not get it)."""
        if self.pub_command is not None and self.pub_command.names:
            self.pub_command.send(self.pub_command.msg)

    # -- the cycle ----------------------------------------------------------------------------
    def read(self, now: float) -> None:
        pass                  # (the samples went into the AxisIO as they came)

    def write(self, now: float) -> None:
        ios = [io for io in self.io.values() if io.commanded]
        if ios and self.pub_command is not None:
            stamp = self._stamp if now == self._stamp_now else stamp_of(now)
            self.pub_command.publish(stamp, [io.name for io in ios],
                                     effort=[io.output for io in ios])
