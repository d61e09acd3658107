"""What a simulated slide tells the world, the same from the plant node and from a controller
with `hardware: sim`: `plant_states` (ground truth: `<axis>_motor`, `<axis>_load` positions [m]
and velocities), `amplifier_states` (effort = the output each amplifier applied [V]) and
`<axis>/amplifier_fault` (std_msgs/Bool, latched: true while the command watchdog holds the
output at 0 V), the last on every change and at least every FAULT_PERIOD, with a log line on a
trip and on the recovery (not at start-up, before the first command)."""
from __future__ import annotations

from sensor_msgs.msg import JointState
from std_msgs.msg import Bool

import msg_defs as md

FAULT_PERIOD = 0.1       # s: amplifier_fault is re-published at least at 10 Hz (as status words)


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
        self.pub_fault = {a: node.stream(Bool, md.amplifier_fault_topic(a), md.STATUS_QOS)
                          for a in self.axes}
        self.fault: dict[str, bool | None] = {a: None for a in self.axes}   # last published
        self.fault_time = {a: -1.0 for a in self.axes}
        self.next_fault_check = -1.0

    def publish(self, stamp, slides) -> None:
        """One sample of every slide at `stamp` (a ROS time message). `slides` has `truth()`
        (positions and velocities, motor then load per axis), `applied()` (volts per axis) and
        `tripped()` (per axis), asked for only what somebody reads."""
        if self.pub_truth.wanted():
            self.pub_truth.publish(stamp, self.names, *slides.truth())
        if self.pub_amp.wanted():
            self.pub_amp.publish(stamp, self.axes, effort=slides.applied())
        now = stamp.sec + stamp.nanosec * 1e-9
        if now < self.next_fault_check and self.next_fault_check - now < 1.0:
            return               # (a changed fault waits at most FAULT_PERIOD / 10)
        self.next_fault_check = now + FAULT_PERIOD / 10
        for a, trip in zip(self.axes, slides.tripped()):
            last = self.fault[a]
            if trip == last and now - self.fault_time[a] < FAULT_PERIOD:
                continue
            if last is not None and trip != last:
                if trip:
                    self.node.get_logger().warning(
                        f'{a}: amplifier fault: no command for '
                        f'{self.command_timeout[a] * 1e3:g} ms (command_timeout): output 0 V, '
                        f'dynamic brake on')
                else:
                    self.node.get_logger().info(f'{a}: amplifier: commands arriving, output on')
            self.pub_fault[a].send(Bool(data=bool(trip)))
            self.fault[a], self.fault_time[a] = trip, now
