"""The `plant` node: the backlash slide simulated in real time (or lockstep sim time).

Subscribes `command` (amplifier volts per axis), integrates `motion_ctrl.sim.plant.SlidePlant` over
the real elapsed time on every tick of its own timer, and publishes `encoders` (raw counts) and
`plant_states` (ground truth). Each axis' amplifier has a command watchdog
(`SlidePlant.advance`): after `<axis>.command_timeout` of plant time without a command its output
is 0 V and its dynamic brake closes; `<axis>/amplifier_fault` (std_msgs/Bool, latched) says so,
and the log says it once on the trip and once when commands come again. `amplifier_states` carries
the output each amplifier applied (effort [V]) (motion_ctrl.ros.plant_states, shared with a
controller that runs the slide in its own loop, `hardware: sim`).

Lockstep (`lockstep: 1`): the plant is the clock. It publishes `/clock`, `encoders` and
`plant_states` at sim time t, waits for the controller's command stamped t (the controller,
with use_sim_time, ticks on each encoder sample), integrates exactly one period with it, and
repeats: a scenario gives bit-identical results run after run, as fast as the two processes can
exchange messages. Whenever no answer has come for LOCKSTEP_RESEND seconds of wall time (the
controller not there yet, or a command sent before discovery had matched it to this reader),
the current sample is sent again; the controller answers a repeated sample with the command it
already computed for it, so nothing is computed twice and the run stays deterministic.
"""
from __future__ import annotations

import sys

from rclpy.clock import Clock, ClockType
from rclpy.time import Time
from rosgraph_msgs.msg import Clock as ClockMsg
from sensor_msgs.msg import JointState

import msg_defs as md
from motion_ctrl.ros import ros_params
from motion_ctrl.ros.node_runner import run
from motion_ctrl.ros.plant_states import PlantStates
from motion_ctrl.sim.plant import SlidePlant
from motion_ctrl.core.registers import (PLANT_AXIS, PLANT_GLOBALS, PLANT_PARAMETERS,
                                        plant_consistency)

LOCKSTEP_RESEND = 0.05   # s of wall time without progress before the sample is sent again


class PlantNode(ros_params.RegisterNode):
    NODE_NAME = 'plant'

    def __init__(self, **kwargs):
        super().__init__(self.NODE_NAME, **kwargs)
        self.globals_table, self.axis_table = {r.name: r for r in PLANT_GLOBALS}, PLANT_AXIS
        self.consistency = plant_consistency
        g = {r.name: ros_params.declare(self, r, r.name) for r in PLANT_GLOBALS}
        self.axis_names = list(g['axes'])
        self.period = 1.0 / g['publish_rate']
        self.lockstep = g['lockstep'] == 1
        self.plants: dict[str, SlidePlant] = {}
        values = {a: {r.name: ros_params.declare(self, r, f'{a}.{r.name}')
                      for r in PLANT_PARAMETERS} for a in self.axis_names}
        self.refuse_unknown_overrides()
        for a in self.axis_names:
            self.plants[a] = SlidePlant(substep_rate=g['substep_rate'], **values[a])
        self.add_on_set_parameters_callback(self.validate)
        self.add_post_set_parameters_callback(self._apply)
        self.pub_enc = self.stream(JointState, md.ENCODERS)
        self.states = PlantStates(self, self.axis_names, {
            a: p.params['command_timeout'] for a, p in self.plants.items()})
        self.create_subscription(JointState, md.COMMAND, self._on_command, md.SERVO_READ_QOS)
        self.last = None
        if self.lockstep:
            self.period_ns = round(self.period * 1e9)
            self.sim_ns = 0
            self.pub_clock = self.create_publisher(ClockMsg, md.CLOCK, 10)
            self.resent_at_ns = None
            self.timer = self.create_timer(LOCKSTEP_RESEND, self._lockstep_resend,
                                           clock=Clock(clock_type=ClockType.STEADY_TIME))
        else:
            self.timer = self.create_timer(self.period, self._tick)
        p = next(iter(self.plants.values()))
        self.get_logger().info(
            f'backlash slide for axes {self.axis_names}: resonance {p.resonance_hz:.0f} Hz, '
            f'backlash {p.params["backlash"] * 1e6:.1f} um, publishing at '
            f'{1 / self.period:g} Hz')

    def current(self, axis: str) -> dict:
        return self.plants[axis].params

    def _apply(self, params):
        for axis, ch in self.axis_changes(params).items():
            self.plants[axis].configure(**ch)
            self.states.command_timeout[axis] = self.plants[axis].params['command_timeout']

    def _on_command(self, msg: JointState) -> None:
        try:
            volts = md.read_joint_state(msg, 'effort', known=self.plants)
        except md.MalformedMessage as e:
            self.get_logger().warning(f'command ignored: {e}', throttle_duration_sec=1.0)
            return
        if self.lockstep:
            stamp_ns = msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec
            if stamp_ns != self.sim_ns:
                return                      # an answer to an older sample
            for a, v in volts.items():
                self.plants[a].command(v)
            for plant in self.plants.values():
                plant.advance(self.period_ns * 1e-9)
            self.sim_ns += self.period_ns
            self._lockstep_publish()
            return
        for a, v in volts.items():
            self.plants[a].command(v)       # held, and the watchdog re-armed

    def _lockstep_resend(self) -> None:
        if self.resent_at_ns == self.sim_ns:      # no progress since the last check
            self._lockstep_publish()
        self.resent_at_ns = self.sim_ns

    def _lockstep_publish(self) -> None:
        stamp = Time(nanoseconds=self.sim_ns).to_msg()
        self.publish(stamp, then=lambda: self.pub_clock.publish(ClockMsg(clock=stamp)))

    def _tick(self) -> None:
        now_msg = self.get_clock().now()
        now = now_msg.nanoseconds * 1e-9
        dt = self.period if self.last is None else now - self.last
        self.last = now
        if dt <= 0.0:
            return
        if dt > 20 * self.period:     # the simulation fell behind real time: say so
            self.get_logger().warning(f'plant held up {dt * 1e3:.0f} ms (integrated as one '
                                      f'step of at most 100 ms)', throttle_duration_sec=1.0)
        dt = min(dt, 0.1)             # a stalled process does not integrate a huge step
        for plant in self.plants.values():
            plant.advance(dt, self.period)
        self.publish(now_msg.to_msg())

    def publish(self, stamp, then=None) -> None:
        """encoders first (the controller's next tick waits on them), then `then()` and the
        ground truth."""
        names, counts = [], []
        for a, plant in self.plants.items():
            m, l = plant.encoder_counts()
            names += [md.motor_joint(a), md.load_joint(a)]
            counts += [m, l]
        self.pub_enc.publish(stamp, names, counts)
        if then is not None:
            then()
        self.states.publish(stamp, self)

    # -- what PlantStates publishes ------------------------------------------------------------
    def truth(self) -> tuple[list[float], list[float]]:
        pos, vel = [], []
        for plant in self.plants.values():
            pos += [plant.x_m, plant.x_l]
            vel += [plant.v_m, plant.v_l]
        return pos, vel

    def applied(self) -> list[float]:
        return [plant.volts for plant in self.plants.values()]

    def tripped(self) -> list[bool]:
        return [plant.tripped for plant in self.plants.values()]


def main(args=None):
    sys.exit(run(PlantNode, args))


if __name__ == '__main__':
    main()
