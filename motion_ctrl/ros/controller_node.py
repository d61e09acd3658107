"""The `controller` node: a timer-driven servo loop for one or more axes.

A thin shell: parameters, topics, services and the timer are translated into calls on
`motion_ctrl.core.servo_loop.ServoLoop` (the tick: register sets, scheduled targets, feedback
watchdog, each `Axis`) and its axes. Parameter sets are validated in the on-set callback (a refusal
names the parameter and changes nothing) and staged in the post-set callback; the next servo tick
applies everything staged at once, so several parameters set in one call take effect together.
Parameter services and the timer share the node's default callback group: they never run
concurrently, no lock is needed. In real time the timer's phase is moved, once, to just after the
encoder samples arrive (`motion_ctrl.core.feedback_sync`), so a sample does not wait up to a
period.

The servo cycle's I/O goes through the hardware interface the read-only parameter `hardware`
chooses: `topics`, `sim` or `canopen` (ros.controller_hardware).

With `use_sim_time` and `hardware: topics` the servo tick is driven by the encoder samples
instead of a timer (like a drive synchronised to its fieldbus cycle): each new sample, stamped in
sim time, is one tick, and the command carries the sample's stamp. With the plant in lockstep
this makes a scenario deterministic. With `use_sim_time` and `hardware: sim` this node is the
clock (ros.sim_clock).

The node by concern: the hardware's choice and registers (ros.controller_hardware), the target
topics (ros.targets), the excitation runs (ros.excitation_runs), the FollowJointTrajectory
action (ros.follow_action), the sim clock (ros.sim_clock); here the parameters, the services,
the servo tick with what it publishes, and /diagnostics.
"""
from __future__ import annotations

import sys
import time
from typing import Any

from sensor_msgs.msg import JointState
from std_msgs.msg import UInt32
from std_srvs.srv import SetBool, Trigger
from diagnostic_msgs.msg import DiagnosticArray

import msg_defs as md
from motion_ctrl.ros import ros_params
from motion_ctrl.ros.controller_hardware import declare_hardware, make_hardware
from motion_ctrl.ros.excitation_runs import ExcitationRuns
from motion_ctrl.ros.hardware_topics import seconds_of, stamp_ns, stamp_of
from motion_ctrl.ros.follow_action import FollowJointTrajectoryServer
from motion_ctrl.ros.node_runner import run
from motion_ctrl.ros.plant_states import PlantStates
from motion_ctrl.ros.sim_clock import SimClock
from motion_ctrl.ros.targets import (MAX_SCHEDULE, MAX_TARGET_NAMES, MAX_TRAJECTORY_POINTS,
                                     TargetInputs)
from motion_ctrl.core.axis import Axis
from motion_ctrl.ros.diagnostics import Diagnostics
from motion_ctrl.core.feedback_sync import FeedbackSync
from motion_ctrl.core.servo_loop import ServoLoop
from motion_ctrl.core.registers import (AXIS_REGISTERS, CONTROLLER_AXIS, CONTROLLER_GLOBALS,
                                        CONTROLLER_GLOBAL, consistency)

STATUS_PERIOD = 0.1      # the status word is re-published at least at 10 Hz
# s of wall time a state stream goes on from its last look at its readers (a reader that joins
# misses at most this much; looking costs ~3 µs a stream a tick)
READERS_REFRESH = 0.05


class ControllerNode(ros_params.RegisterNode):
    NODE_NAME = 'controller'

    ALSO_SECTIONS = ('plant',)        # params-file sections read besides its own (sim)
    # hardware sim: what the slides do, published as the plant node does (make_hardware)
    plant_states: PlantStates

    def __init__(self, params_files=(), **kwargs):
        """`params_files`: those of the command line (run passes them): with `hardware: sim`
        their `plant:` sections configure the simulated slides too. The setup in order:
        parameters, the servo loop and its hardware, the parameter callbacks, the publishers,
        the inputs (targets, services, the action), what drives the tick, then the hardware
        activated."""
        super().__init__(self.NODE_NAME, **kwargs)
        self.globals_table, self.axis_table = CONTROLLER_GLOBAL, CONTROLLER_AXIS
        self.consistency = consistency
        self._declare_parameters(params_files)
        self._make_loop()
        self.add_on_set_parameters_callback(self._validate)
        self.add_post_set_parameters_callback(self._stage)
        self._make_publishers()
        self._make_inputs()
        self._make_tick_drivers()
        self.hardware.activate()
        self.get_logger().info(
            f'servo loop at {self.servo_rate:g} Hz for axes {self.axis_names}, hardware '
            f'{self.hardware_kind}' + (' (the clock: sim time)' if self.sim_clock else ''))

    def _declare_parameters(self, params_files) -> None:
        """Every register declared from the table (the globals, then each axis's), then the
        hardware's; an override the node does not know is refused."""
        g = {r.name: ros_params.declare(self, r, r.name) for r in CONTROLLER_GLOBALS}
        self.axis_names = list(g['axes'])
        self.servo_rate = g['servo_rate']
        self.feedback_timeout = g['feedback_timeout']
        self.period = 1.0 / self.servo_rate
        self.values: dict[str, dict] = {}
        for name in self.axis_names:
            self.values[name] = {r.name: ros_params.declare(self, r, f'{name}.{r.name}')
                                 for r in AXIS_REGISTERS}
        self.hardware_kind = g['hardware']
        self.hardware_values = declare_hardware(self, params_files)
        self.refuse_unknown_overrides()

    def _make_loop(self) -> None:
        """The axes, the hardware interface (configured) and the ServoLoop that ticks them."""
        self.axes: dict[str, Axis] = {}
        for name, values in self.values.items():
            self.axes[name] = Axis(name, values, self.period)   # raises on a bad set: see run()
        self.sim_time = self.get_parameter('use_sim_time').value
        self.hardware = make_hardware(self, self.hardware_values, READERS_REFRESH)
        self.hardware.configure()          # raises HardwareError: one line, exit 2 (node_runner)
        self.loop = ServoLoop(self.axes, self.values, self.period, self.feedback_timeout,
                              self.sim_time, self.hardware)
        if self.hardware_kind == 'canopen':
            self.hardware.watch(self.axes)

    def _make_publishers(self) -> None:
        """The state streams, each axis's status word and /diagnostics."""
        self.pub_joint = self.stream(JointState, md.JOINT_STATES, refresh=READERS_REFRESH)
        self.pub_reference = self.stream(JointState, md.REFERENCE_STATES,
                                         refresh=READERS_REFRESH)
        self.pub_motor = self.stream(JointState, md.MOTOR_STATES, refresh=READERS_REFRESH)
        self.pub_status = {a: self.stream(UInt32, md.status_topic(a), md.STATUS_QOS)
                           for a in self.axis_names}
        self.diagnostics = Diagnostics(self.stream(DiagnosticArray, md.DIAGNOSTICS, 10),
                                       self.get_name(), self.axes)

    def _make_inputs(self) -> None:
        """The target topics, the excitation runs, each axis's services and the
        FollowJointTrajectory action."""
        self.inputs = TargetInputs(self, self.loop, self.sim_time)
        self.excitation = ExcitationRuns(self, self.loop)
        for a in self.axis_names:
            self._make_services(a)
        # follow_joint_trajectory, controller_state, query_state (issue 28)
        self.follow = FollowJointTrajectoryServer(self, MAX_SCHEDULE, MAX_TARGET_NAMES,
                                                  MAX_TRAJECTORY_POINTS)

    def _make_tick_drivers(self) -> None:
        """The status refresh's counters, then what drives the tick and /diagnostics: a timer
        in real time (its phase following the encoder samples with hardware topics); in sim
        time the plant's samples (topics) or this node's own clock (sim: spin_step)."""
        # The status words: each on a change, and each again at least every STATUS_PERIOD,
        # a few axes a tick in turn (`_refresh_status`).
        self.status_turn = 0
        self.status_due = 0.0
        self.status_at: float | None = None       # the tick time the refresh last counted from
        self.stats = self.loop.stats
        self.timer: Any = None         # real time: the servo timer (its period moves with sync)
        self.sync = None
        self.period_ns = round(self.period * 1e9)
        self.grid_ns: int | None = None           # the servo grid's last tick (hardware sim)
        self.sim_clock = self.sim_time and self.hardware_kind == 'sim'
        # hardware canopen: the bus is the clock. The drives take each SYNC as one period
        # (1006h), so the loop's time is the SYNC count: a tick that comes late stretches the
        # wall time of a cycle, not the cycle (a PLC motion task's time base); how late the
        # SYNCs really go out is in /diagnostics (can_sync_interval_*). The messages it
        # publishes keep the wall clock's stamps.
        self.bus_ns: int | None = None
        if not self.sim_time:
            # (a lambda: rclpy hands a TimerInfo to a callback that takes an argument)
            self.timer = self.create_timer(self.period, lambda: self._tick())
        if not self.sim_time and self.hardware_kind == 'topics':
            # Real time: the servo ticks are moved to just after the encoder samples arrive.
            self.sync = FeedbackSync(self.period)
        self.own_clock: SimClock | None = None
        if self.sim_clock:
            self.own_clock = SimClock(self, self.period_ns, self._tick, self._publish_diagnostics,
                                      self.get_parameter('sim_speed').value)
        else:
            self.diag_timer = self.create_timer(1.0, self._publish_diagnostics)

    # -- parameters -----------------------------------------------------------------------------
    def current(self, axis: str) -> dict:
        own = self.loop.current(axis)
        if self.hardware_kind == 'sim':
            return own | self.hardware.plants[axis].params
        return own | self.hardware_values[axis]

    def live_refusal(self, axis: str, changes: dict):
        return self.axes[axis].live_change_refusal(
            {k: v for k, v in changes.items() if k not in self.hardware_values[axis]})

    def _validate(self, params):
        self.inputs.flush()
        return self.validate(params)

    def _stage(self, params) -> None:
        for p in params:
            if p.name == 'feedback_timeout':
                self.loop.feedback_timeout = p.value
            if p.name == 'sim_speed' and self.own_clock is not None:
                self.own_clock.set_speed(p.value)
        for axis, changes in self.axis_changes(params).items():
            own = self.hardware_values[axis]
            hw = {k: v for k, v in changes.items() if k in own}
            if hw and self.hardware_kind == 'sim':   # (validated above, applied between ticks)
                self.hardware.configure_plant(axis, hw)
                self.plant_states.command_timeout[axis] = \
                    self.hardware.plants[axis].params['command_timeout']
            elif hw:
                self.hardware.configure_axis(axis, hw)
            own.update(hw)
            changes = {k: v for k, v in changes.items() if k not in own}
            if changes:
                self.loop.stage(axis, changes)

    def _log(self, lines) -> None:
        """(level, text) lines of the core and the hardware: 'error', 'info', else warning."""
        logger = self.get_logger()
        for level, text in lines:         # (rclpy: one severity per call site)
            if level == 'error':
                logger.error(text)
            elif level == 'info':
                logger.info(text)
            else:
                logger.warning(text)

    # -- inputs ---------------------------------------------------------------------------------
    def _on_sample(self, stamp) -> None:
        """An encoder message was taken (hardware topics): the servo timer's phase follows the
        arrivals (real time); in sim time each new sample is one tick, and a sample sent again
        (the lockstep plant did not get our answer) is answered again."""
        if self.sync is not None:
            self.sync.arrived(time.perf_counter())     # ready for a tick from now on
        if not self.sim_time:
            return
        last = self.loop.last_tick
        now = seconds_of(stamp)
        if last is None or now > last:
            self._tick(stamp)
        elif now == last:
            self.hardware.resend()

    def _make_services(self, a: str) -> None:
        axis = self.axes[a]

        def trigger(fn):
            def cb(request, response):
                self.inputs.flush()
                response.success, response.message = fn()
                return response
            return cb

        def enable(request, response):
            self.inputs.flush()
            response.success, response.message = axis.enable(request.data)
            return response
        self.create_service(SetBool, md.service_name(a, 'enable'), enable)
        self.create_service(Trigger, md.service_name(a, 'stop'), trigger(lambda: axis.stop('stop')))
        self.create_service(Trigger, md.service_name(a, 'estop'),
                            trigger(lambda: axis.stop('estop')))
        self.create_service(Trigger, md.service_name(a, 'abort'), trigger(axis.abort))
        self.create_service(Trigger, md.service_name(a, 'reset'),
                            trigger(lambda: self.loop.reset(a)))
        self.create_service(Trigger, md.service_name(a, 'correct'), trigger(axis.correct))
        self.create_service(Trigger, md.service_name(a, 'excite'),
                            trigger(lambda: self.excitation.excite(a)))

    # -- the servo tick -------------------------------------------------------------------------
    def _tick(self, stamp_msg=None) -> None:
        """One servo cycle: at the timer (real time), at an encoder sample (sim time, topics)
        or at this node's own sim clock (sim time, sim)."""
        t_start = time.perf_counter()
        if stamp_msg is None and self.hardware_kind == 'sim':
            stamp = self._on_servo_grid()
        elif stamp_msg is None:
            stamp = self.get_clock().now().to_msg()
            if self.sync is not None:
                period = self.sync.tick(t_start)
                if period is not None:
                    self.timer.timer_period_ns = round(period * 1e9)
        else:
            stamp = stamp_msg
        now = seconds_of(stamp)
        if self.hardware_kind == 'canopen':
            # (the messages keep the wall clock's stamp: they line up with plant_states)
            self.bus_ns = (round(now * 1e9) if self.bus_ns is None
                           else self.bus_ns + self.period_ns)
            now = self.bus_ns * 1e-9
        self.inputs.start_prepared()
        if self.hardware_kind == 'topics':
            self.hardware.stamp_tick(stamp, now)
        tick = self.loop.cycle(now)
        if tick is None:
            return                       # sim time paused or stepped back
        if tick.log:
            self._log(tick.log)
        if tick.refused:
            self.inputs.log_refused(tick.refused)
        names, outputs = tick.names, tick.outputs
        if names and (self.pub_joint.wanted() or self.pub_reference.wanted()
                      or self.pub_motor.wanted()):
            ax = [self.axes[a] for a in names]
            if self.pub_joint.wanted():
                self.pub_joint.publish(stamp, names, [x.load_pos for x in ax],
                                       [x.load_vel for x in ax], outputs)
            if self.pub_reference.wanted():
                self.pub_reference.publish(stamp, names, [x.command_position for x in ax],
                                           [x.profile.velocity for x in ax])
            if self.pub_motor.wanted():
                self.pub_motor.publish(stamp, names, [x.motor_pos for x in ax],
                                       [x.motor_vel for x in ax])
        if self.hardware_kind == 'sim':
            self.plant_states.publish(stamp_of(self.hardware.time), self.hardware)
        self.excitation.collect()        # a run that ended is published off the tick
        for a in tick.changed:
            self.pub_status[a].send(UInt32(data=self.axes[a].word))
        self._refresh_status(now)
        self.follow.tick(now)            # the trajectory goal, after the outputs (never waits)
        self.diagnostics.tick(stamp)     # the next part of the axes' statuses, if any
        self.stats.work(time.perf_counter() - t_start)

    def _refresh_status(self, now: float) -> None:
        """Every axis's status word again every STATUS_PERIOD of the tick's clock, spread over
        the ticks: a few axes a tick, in turn, instead of all of them in one. Counted from the
        clock, not the ticks, so that ticks skipped under load do not stretch the period."""
        names = self.axis_names
        elapsed = self.period if self.status_at is None else min(max(now - self.status_at, 0.0),
                                                                  STATUS_PERIOD)
        self.status_at = now
        self.status_due += len(names) * elapsed / STATUS_PERIOD
        while self.status_due >= 1.0:
            self.status_due -= 1.0
            a = names[self.status_turn]
            self.status_turn = (self.status_turn + 1) % len(names)
            self.pub_status[a].send(UInt32(data=self.axes[a].word))

    def _on_servo_grid(self):
        """The stamp of a real-time tick with the slides in the loop (hardware sim): the clock's
        time on the servo grid, whole periods after the first tick (PMAC's servo interrupt), so
        that each period of the loop is one period of the simulated slides however the timer
        jitters (sim.hardware); a tick after skipped ones is as many periods later."""
        ns = self.get_clock().now().nanoseconds
        if self.grid_ns is None:
            self.grid_ns = ns
        else:
            self.grid_ns += max(1, round((ns - self.grid_ns) / self.period_ns)) * self.period_ns
        return stamp_ns(self.grid_ns)

    def spin_step(self, executor) -> None:
        """What `spin` runs over and over: in real time, the executor (timer, callbacks); with
        the sim clock, its batch of ticks and then the callbacks (ros.sim_clock)."""
        if self.own_clock is None:
            executor.spin_once(timeout_sec=0.05)
        else:
            self.own_clock.spin_step(executor)

    def shutdown_outputs(self) -> None:
        """Before the node goes (SIGINT, SIGTERM, launch's Ctrl-C): every loop opened and 0 V
        commanded on every axis, as a PMAC or Galil kills its motors (amplifier disabled, output
        0) when it stops, instead of leaving the amplifier on its last command until the
        amplifier's own watchdog trips (the hardware's `deactivate`)."""
        for axis in self.axes.values():
            axis.enable(False)
        self.hardware.deactivate()
        for a, axis in self.axes.items():
            self.pub_status[a].send(UInt32(data=int(axis.status)))
        self.get_logger().info(f'stopped: loops opened, 0 V commanded on {self.axis_names}')

    def destroy_node(self) -> None:
        # The worker threads end first: they hold the node, and a node alive at the
        # interpreter's exit outlives the extension modules (nanobind then reports ruckig's
        # objects as leaked, ~30 lines on every stop).
        for part in ('inputs', 'excitation'):     # (a node refused half-made lacks some)
            if hasattr(self, part):
                getattr(self, part).close()
        if hasattr(self, 'follow'):
            self.follow.destroy()
        super().destroy_node()

    def _publish_diagnostics(self) -> None:
        extra = {} if self.sync is None else {'timer_phase_shifts': self.sync.shifts}
        figures = getattr(self.hardware, 'figures', None)
        if figures is not None:
            extra |= figures()
        self.diagnostics.start(self.get_clock().now().to_msg(), self.stats, extra)
        self.stats.reset_window()


def main(args=None):
    sys.exit(run(ControllerNode, args))


if __name__ == '__main__':
    main()
