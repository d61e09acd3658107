"""What a simulated slide tells the world, the same from the plant node and from a controller
with `hardware: sim`: `plant_states` (ground truth: `<axis>_motor`, `<axis>_load` positions [m]
and velocities), `amplifier_states` (effort = the output each amplifier applied [V]) and
`<axis>/amplifier_fault` (std_msgs/Bool, latched: true while the command watchdog holds the
output at 0 V), the last on every change (latched: a late reader gets the current value at
once; a periodic copy of every axis's fault would cost the loop a publish per axis every
period, the largest part of a many-axis tick after the status words), with a log line on a
trip and on the recovery (not at start-up: the first sample says how the amplifiers start)."""
from __future__ import annotations

from sensor_msgs.msg import JointState
from std_msgs.msg import Bool

import msg_defs as md


class PlantStates:
    def __init__(self, node, axes, command_timeout: dict[str, float],
                 refresh: float = 0.0) -> None:
        """`command_timeout`: per axis, the watchdog's time [s] (for the log line); kept up to
        date by the caller. `refresh`: the streams' look at their readers (msg_defs.Stream)."""
        self.node = node
        self.axes = list(axes)
        self.names = [n for a in self.axes for n in (md.motor_joint(a), md.load_joint(a))]
        self.command_timeout = command_timeout
        self.pub_truth = node.stream(JointState, md.PLANT_STATES, refresh=refresh)
        self.pub_amp = node.stream(JointState, md.AMPLIFIER_STATES, refresh=refresh)
        self.pub_fault = {a: node.stream(Bool, md.amplifier_fault_topic(a), md.LATCHED_QOS)
                          for a in self.axes}
        self.fault: list[bool] | None = None      # per axis, as last published

    def publish(self, stamp, slides) -> None:
        """One sample of every slide at `stamp` (a ROS time message). `slides` has `truth()`
        (positions and velocities, motor then load per axis), `applied()` (volts per axis) and
        `tripped()` (per axis), asked for only what somebody reads. The faults: each on a
        change."""
        if self.pub_truth.wanted():
            self.pub_truth.publish(stamp, self.names, *slides.truth())
        if self.pub_amp.wanted():
            self.pub_amp.publish(stamp, self.axes, effort=slides.applied())
        tripped = slides.tripped()
        last = self.fault
        if last is None:
            for a, trip in zip(self.axes, tripped):
                self.pub_fault[a].send(Bool(data=bool(trip)))
        elif tripped != last:
            for a, trip, was in zip(self.axes, tripped, last):
                if trip != was:
                    self._changed(a, trip)
        self.fault = tripped

    def _changed(self, a: str, trip: bool) -> None:
        if trip:
            self.node.get_logger().warning(
                f'{a}: amplifier fault: no command for {self.command_timeout[a] * 1e3:g} ms '
                f'(command_timeout): output 0 V, dynamic brake on')
        else:
            self.node.get_logger().info(f'{a}: amplifier: commands arriving, output on')
        self.pub_fault[a].send(Bool(data=bool(trip)))
