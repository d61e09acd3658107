"""The `plant` node: the backlash slide simulated in real time (or lockstep sim time).

Subscribes `command` (amplifier volts per axis), integrates `motion_ctrl.plant.SlidePlant` over
the real elapsed time on every tick of its own timer, and publishes `encoders` (raw counts) and
`plant_states` (ground truth). Like an amplifier behind a PMAC watchdog, a command older than
COMMAND_TIMEOUT is treated as 0 V.
"""
from __future__ import annotations

import sys

from rclpy.node import Node
from rcl_interfaces.msg import SetParametersResult
from sensor_msgs.msg import JointState

import msg_defs as md
from motion_ctrl import ros_params
from motion_ctrl.controller_node import run
from motion_ctrl.plant import SlidePlant
from motion_ctrl.registers import PLANT_AXIS, PLANT_GLOBALS, PLANT_PARAMETERS, plant_consistency

COMMAND_TIMEOUT = 0.1    # s


class PlantNode(Node):
    def __init__(self, **kwargs):
        super().__init__('plant', **kwargs)
        g = {r.name: ros_params.declare(self, r, r.name) for r in PLANT_GLOBALS}
        self.axis_names = list(g['axes'])
        self.period = 1.0 / g['publish_rate']
        self.plants: dict[str, SlidePlant] = {}
        for a in self.axis_names:
            values = {r.name: ros_params.declare(self, r, f'{a}.{r.name}')
                      for r in PLANT_PARAMETERS}
            self.plants[a] = SlidePlant(substep_rate=g['substep_rate'], **values)
        self.volts = {a: 0.0 for a in self.axis_names}
        self.command_time = None
        self.add_on_set_parameters_callback(self._validate)
        self.add_post_set_parameters_callback(self._apply)
        self.pub_enc = md.JointStateStream(
            self.create_publisher(JointState, md.ENCODERS, md.SERVO_QOS))
        self.pub_truth = md.JointStateStream(
            self.create_publisher(JointState, md.PLANT_STATES, md.SERVO_QOS))
        self.create_subscription(JointState, md.COMMAND, self._on_command, md.COMMAND_QOS)
        self.last = None
        self.timer = self.create_timer(self.period, self._tick)
        p = next(iter(self.plants.values()))
        self.get_logger().info(
            f'backlash slide for axes {self.axis_names}: resonance {p.resonance_hz:.0f} Hz, '
            f'backlash {p.params["backlash"] * 1e6:.1f} um, publishing at '
            f'{1 / self.period:g} Hz')

    def _split(self, name):
        axis, _, reg = name.partition('.')
        return (axis, reg) if axis in self.plants and reg in PLANT_AXIS else (None, None)

    def _validate(self, params):
        changes = {}
        for p in params:
            axis, reg = self._split(p.name)
            if axis is None:
                continue
            value = ros_params.plain(p.value)
            reason = PLANT_AXIS[reg].check(value)
            if reason:
                return SetParametersResult(successful=False, reason=f'{axis}.{reason}')
            changes.setdefault(axis, {})[reg] = value
        for axis, ch in changes.items():
            reasons = plant_consistency(self.plants[axis].params | ch)
            if reasons:
                return SetParametersResult(successful=False,
                                           reason='; '.join(f'{axis}.{r}' for r in reasons))
        return SetParametersResult(successful=True)

    def _apply(self, params):
        changes = {}
        for p in params:
            axis, reg = self._split(p.name)
            if axis is not None:
                changes.setdefault(axis, {})[reg] = ros_params.plain(p.value)
        for axis, ch in changes.items():
            self.plants[axis].configure(**ch)

    def _on_command(self, msg: JointState) -> None:
        try:
            volts = md.read_joint_state(msg, 'effort', known=self.plants)
        except md.MalformedMessage as e:
            self.get_logger().warning(f'command ignored: {e}', throttle_duration_sec=1.0)
            return
        self.volts.update(volts)
        self.command_time = self.get_clock().now().nanoseconds * 1e-9

    def _tick(self) -> None:
        now_msg = self.get_clock().now()
        now = now_msg.nanoseconds * 1e-9
        dt = self.period if self.last is None else now - self.last
        self.last = now
        if dt <= 0.0:
            return
        dt = min(dt, 0.1)             # a stalled process does not integrate a huge step
        stale = self.command_time is None or now - self.command_time > COMMAND_TIMEOUT
        for a, plant in self.plants.items():
            plant.step(0.0 if stale else self.volts[a], dt)
        self.publish(now_msg.to_msg())

    def publish(self, stamp) -> None:
        names, counts, tnames, tpos, tvel = [], [], [], [], []
        for a, plant in self.plants.items():
            m, l = plant.encoder_counts()
            names += [md.motor_joint(a), md.load_joint(a)]
            counts += [m, l]
            tpos += [plant.x_m, plant.x_l]
            tvel += [plant.v_m, plant.v_l]
        self.pub_enc.publish(stamp, names, counts)
        self.pub_truth.publish(stamp, names, tpos, tvel)


def main(args=None):
    sys.exit(run(PlantNode, args))


if __name__ == '__main__':
    main()
