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
chooses (motion_ctrl.core.hardware): `topics` (ros.hardware_topics: the plant node over the
`command` / `encoders` topics), `sim` (sim.hardware: the slide's physics stepped inside this
loop, configured by the plant's registers declared on this node, published as the plant node
does by ros.plant_states) or `canopen` (canopen.master: CiA 402 drives on a CAN bus, this node
their SYNC producer; real time only).

With `use_sim_time` and `hardware: topics` the servo tick is driven by the encoder samples
instead of a timer (like a drive synchronised to its fieldbus cycle): each new sample, stamped in
sim time, is one tick, and the command carries the sample's stamp. With the plant in lockstep
this makes a scenario deterministic. With `use_sim_time` and `hardware: sim` this node is the
clock: it ticks back to back, as fast as the machine allows up to MAX_SIM_SPEED times real
time, publishes `/clock` and runs the
callbacks that came (targets, services, parameters) between batches of ticks (SIM_BATCH s of
wall time): deterministic for targets stamped ahead. Its /clock is published once a batch.

A target whose header stamp lies up to MAX_SCHEDULE seconds ahead of the node's clock is applied
at the first tick at or after that stamp (a coordinated start of several axes, or a move at an
exact sim time); other targets apply at once. A `joint_trajectory`
(trajectory_msgs/JointTrajectory) is checked as a whole and run on all its axes on one time base
(`ServoLoop.trajectory`, PMAC PVT); its header stamp schedules it the same way.

`<axis>/excite` starts the test signal the axis's excitation_* registers describe
(`ServoLoop.excite`, PMAC gather / WorkBench Bode); when the run ends the whole per-tick record
is published once, latched, on `<axis>/gather` (msg_defs.gather), built and sent on a thread of
its own so the servo tick only hands it over.
"""
from __future__ import annotations

import importlib
import queue
import threading
import sys
import time

from rclpy.serialization import deserialize_message
from sensor_msgs.msg import JointState
from std_msgs.msg import Float64MultiArray, UInt32
from std_srvs.srv import SetBool, Trigger
from trajectory_msgs.msg import JointTrajectory
from diagnostic_msgs.msg import DiagnosticArray

from rosgraph_msgs.msg import Clock as ClockMsg

import msg_defs as md
from motion_ctrl.ros import ros_params
from motion_ctrl.ros.hardware_topics import TopicsHardware, seconds_of, stamp_ns, stamp_of
from motion_ctrl.ros.plant_states import PlantStates
from motion_ctrl.ros.follow_action import FollowJointTrajectoryServer
from motion_ctrl.ros.node_runner import run
from motion_ctrl.ros.refusals import RefusalLog, too_large
from motion_ctrl.core.axis import Axis
from motion_ctrl.core.diagnostics import diagnostics_message
from motion_ctrl.core.feedback_sync import FeedbackSync
from motion_ctrl.core.gather import COLUMNS
from motion_ctrl.core.servo_loop import ServoLoop
from motion_ctrl.core.registers import (AXIS_REGISTERS, CONTROLLER_AXIS, CONTROLLER_GLOBALS,
                                        CONTROLLER_GLOBAL, HARDWARE_REGISTERS, PLANT_AXIS,
                                        consistency, plant_consistency)
from motion_ctrl.sim.hardware import SimHardware

STATUS_PERIOD = 0.1      # the status word is re-published at least at 10 Hz
PRELOAD = ('scipy.interpolate',)     # imported before the loop runs (__init__)
MAX_TARGET_NAMES = 256
# Targets stamped ahead waiting for their time (each tick looks at them all); more are refused.
MAX_SCHEDULED = 256
# A trajectory is checked in the callback, between two ticks: ~16 µs per point with
# accelerations (quintic: its velocity and acceleration extrema are roots of quartics and
# cubics), ~4 µs without (2 axes, this machine). Longer would hold the servo loop past the
# amplifier's 10 ms command watchdog; a longer path is sent in parts, each a new trajectory
# from where the last one is.
MAX_TRAJECTORY_POINTS = {'with accelerations': 400, 'without': 1500}
MAX_TRAJECTORY_BYTES = 1 << 20
MAX_SCHEDULE = 60.0      # s: a target stamped further ahead is not a schedule but another clock
# s of wall time the sim clock (hardware sim, use_sim_time) ticks before it runs the callbacks
SIM_BATCH = 0.001
# sim seconds per wall second at most (hardware sim, use_sim_time): a client reading the streams
# (a tool placing a move's status words among the joint_states samples, a recorder) keeps up;
# unbounded, the clock ran ~14x real time and a tool's readings of a move lagged it by tens to
# hundreds of ms of sim time, and its targets landed at times set by its own lag
MAX_SIM_SPEED = 4.0
# s of wall time a state stream goes on from its last look at its readers (a reader that joins
# misses at most this much; looking costs ~3 µs a stream a tick)
READERS_REFRESH = 0.05


class ControllerNode(ros_params.RegisterNode):
    NODE_NAME = 'controller'

    ALSO_SECTIONS = ('plant',)        # params-file sections read besides its own (sim)

    def __init__(self, params_files=(), **kwargs):
        """`params_files`: those of the command line (run passes them): with `hardware: sim`
        their `plant:` sections configure the simulated slides too."""
        # The worker threads' queues first: destroy_node ends the threads through them, also
        # for a node refused half-made (a bad parameter), which the context's cleanup destroys.
        self.trajectories: queue.SimpleQueue = queue.SimpleQueue()     # raw messages in
        self.prepared: queue.SimpleQueue = queue.SimpleQueue()         # built, to start
        self.gathers: queue.SimpleQueue = queue.SimpleQueue()     # (axis, Gather, meta)
        super().__init__(self.NODE_NAME, **kwargs)
        self.globals_table, self.axis_table = CONTROLLER_GLOBAL, CONTROLLER_AXIS
        self.consistency = consistency
        g = {r.name: ros_params.declare(self, r, r.name) for r in CONTROLLER_GLOBALS}
        self.axis_names = list(g['axes'])
        self.servo_rate = g['servo_rate']
        self.feedback_timeout = g['feedback_timeout']
        self.period = 1.0 / self.servo_rate
        self.axes: dict[str, Axis] = {}
        self.values: dict[str, dict] = {}
        for name in self.axis_names:
            self.values[name] = {r.name: ros_params.declare(self, r, f'{name}.{r.name}')
                                 for r in AXIS_REGISTERS}
        self.hardware_kind = g['hardware']
        hw_values = self._declare_hardware(params_files)
        self.refuse_unknown_overrides()
        for name, values in self.values.items():
            self.axes[name] = Axis(name, values, self.period)   # raises on a bad set: see run()
        self.sim_time = self.get_parameter('use_sim_time').value
        self.hardware = self._make_hardware(hw_values)
        self.hardware.configure()          # raises HardwareError: one line, exit 2 (node_runner)
        self.loop = ServoLoop(self.axes, self.values, self.period, self.feedback_timeout,
                              self.sim_time, self.hardware)
        if self.hardware_kind == 'canopen':
            self.hardware.watch(self.axes)
        self.add_on_set_parameters_callback(self._validate)
        self.add_post_set_parameters_callback(self._stage)

        self.pub_joint = self.stream(JointState, md.JOINT_STATES, refresh=READERS_REFRESH)
        self.pub_reference = self.stream(JointState, md.REFERENCE_STATES,
                                         refresh=READERS_REFRESH)
        self.pub_motor = self.stream(JointState, md.MOTOR_STATES, refresh=READERS_REFRESH)
        self.pub_status = {a: self.stream(UInt32, md.status_topic(a), md.STATUS_QOS)
                           for a in self.axis_names}
        self.pub_diag = self.stream(DiagnosticArray, md.DIAGNOSTICS, 10)
        self.create_subscription(JointState, md.TARGET_POSITION, self._raw_target(
            self._on_target_position, 'target_position'), 10, raw=True)
        self.create_subscription(JointState, md.TARGET_VELOCITY, self._raw_target(
            self._on_target_velocity, 'target_velocity'), 10, raw=True)
        # Trajectories are decoded, checked and built on a thread of their own in real time
        # (rclpy's decoding of 400 points alone takes ~5 ms), and started by the next tick.
        # What they use of scipy is imported now, before the loop runs (~0.7 s of start-up):
        # imported by the first trajectory on that thread, it held the GIL in long C calls for
        # ~0.4 s, and both loops stood still 50-105 ms (the plant "held up" in 15 of 16 `draw`
        # starts at real-time priority, both threads FIFO 30).
        for module in PRELOAD:
            importlib.import_module(module)
        self.create_subscription(JointTrajectory, md.JOINT_TRAJECTORY, self._on_raw_trajectory,
                                 10, raw=True)
        if not self.sim_time:
            threading.Thread(target=self._prepare_loop, name='trajectories', daemon=True).start()
        # Excitation runs: numbered per axis; a finished one's record goes out on a thread.
        self.pub_gather = {a: self.stream(Float64MultiArray, md.gather_topic(a), md.GATHER_QOS)
                           for a in self.axis_names}
        self.runs = {a: 0 for a in self.axis_names}
        self.run_meta: dict[str, dict] = {}
        threading.Thread(target=self._gather_loop, name='gather', daemon=True).start()
        for a in self.axis_names:
            self._make_services(a)
        # follow_joint_trajectory, controller_state, query_state (issue 28)
        self.follow = FollowJointTrajectoryServer(self, MAX_SCHEDULE, MAX_TARGET_NAMES,
                                                  MAX_TRAJECTORY_POINTS)

        # The status words: each on a change, and each again at least every STATUS_PERIOD,
        # a few axes a tick in turn (`_refresh_status`).
        self.status_turn = 0
        self.status_due = 0.0
        self.status_at: float | None = None       # the tick time the refresh last counted from
        self.stats = self.loop.stats
        self.refusals = RefusalLog(self.get_logger().warning)
        # What drives the tick: a timer in real time; in sim time the plant's samples
        # (topics) or this node's own clock (sim: spin_step).
        self.timer = None
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
        if self.sim_clock:
            self._start_sim_clock()
        else:
            self.diag_timer = self.create_timer(1.0, self._publish_diagnostics)
        self.hardware.activate()
        self.get_logger().info(
            f'servo loop at {self.servo_rate:g} Hz for axes {self.axis_names}, hardware '
            f'{self.hardware_kind}' + (' (the clock: sim time)' if self.sim_clock else ''))

    # -- hardware -------------------------------------------------------------------------------
    def _declare_hardware(self, params_files) -> dict:
        """The chosen backend's own registers (registers.HARDWARE_REGISTERS), declared now:
        {None: controller-wide values, axis: that axis's values}. With `hardware: sim` the
        `plant:` sections of the params files give the plant registers' start values (this
        node's own section and -p win); with another backend such a section is refused."""
        kind = self.hardware_kind
        plant_section = ros_params.section_values(params_files, 'plant')
        if plant_section and kind != 'sim':
            raise ValueError(f'hardware: {kind}: a plant: section in the params files '
                             f'configures the controller only with hardware: sim')
        globals_, per_axis = HARDWARE_REGISTERS[kind]
        self.globals_table = CONTROLLER_GLOBAL | {r.name: r for r in globals_}
        self.axis_table = CONTROLLER_AXIS | {r.name: r for r in per_axis}
        values: dict = {None: {r.name: ros_params.declare(self, r, r.name,
                                                          plant_section.get(r.name))
                               for r in globals_}}
        for a in self.axis_names:
            values[a] = {r.name: ros_params.declare(self, r, f'{a}.{r.name}',
                                                    plant_section.get(f'{a}.{r.name}'))
                         for r in per_axis}
        self.hardware_values = values
        return values

    def _make_hardware(self, values: dict):
        if self.hardware_kind == 'sim':
            self.consistency = self._sim_consistency
            hardware = SimHardware(self.axis_names, self.period,
                                   {a: values[a] for a in self.axis_names},
                                   substep_rate=values[None]['substep_rate'])
            self.plant_states = PlantStates(self, self.axis_names, {
                a: values[a]['command_timeout'] for a in self.axis_names}, READERS_REFRESH)
            return hardware
        if self.hardware_kind == 'canopen':
            return self._canopen(values)
        return TopicsHardware(self, self.axis_names, on_sample=self._on_sample)

    def _canopen(self, values: dict):
        from motion_ctrl.canopen.master import AxisNodes, CanopenHardware
        if self.sim_time:
            raise ValueError('hardware: canopen runs in real time: the drives step on its SYNC; '
                             'use_sim_time is for topics or sim')
        g = values[None]
        return CanopenHardware(
            {a: AxisNodes(values[a]['can_node_id'], values[a]['load_encoder_node_id'],
                          values[a]['eds'], values[a]['torque_per_volt'],
                          round(self.values[a]['estop_deceleration']
                                * self.values[a]['motor_counts_per_m'])
                          if values[a]['estop_quick_stop'] else 0)
             for a in self.axis_names}, self.period, g['can_interface'], g['can_channel'],
            g['can_bitrate'], log=self._hardware_log)

    def _hardware_log(self, level: str, text: str) -> None:
        logger = self.get_logger()
        if level == 'error':
            logger.error(text)
        elif level == 'warning':
            logger.warning(text)
        else:
            logger.info(text)

    def _sim_consistency(self, values: dict) -> list[str]:
        """The controller's cross-register rules and the plant's, each on its own registers."""
        plant = {k: v for k, v in values.items() if k in PLANT_AXIS}
        own = {k: v for k, v in values.items() if k not in PLANT_AXIS}
        return consistency(own) + (plant_consistency(plant) if plant else [])

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
        self._flush_inputs()
        return self.validate(params)

    def _stage(self, params) -> None:
        for p in params:
            if p.name == 'feedback_timeout':
                self.loop.feedback_timeout = p.value
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
        logger = self.get_logger()
        for level, text in lines:         # (rclpy: one severity per call site)
            if level == 'error':
                logger.error(text)
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

    def _refused(self, kind: str, text: str) -> None:
        """A refusal, logged at most once a second per kind (ros.refusals)."""
        self.refusals.refused(kind, text)

    def _raw_target(self, callback, what: str):
        def on_raw(data: bytes) -> None:
            if len(data) > md.MAX_TARGET_BYTES:
                self._refused(what + ':size', too_large(what, len(data)))
                return
            try:
                msg = deserialize_message(data, JointState)
            except Exception as e:           # (rclpy raises its own types for a bad CDR)
                self._refused(what, f'{what} refused: not a JointState ({e})')
                return
            callback(msg)
        return on_raw

    def _targets(self, msg, field, what):
        if len(msg.name) > MAX_TARGET_NAMES:
            self._refused(what + ':size', f'{what} refused: {len(msg.name)} names (at most '
                          f'{MAX_TARGET_NAMES})')
            return {}
        try:
            return md.read_joint_state(msg, field, known=self.axes)
        except md.MalformedMessage as e:
            self._refused(what, f'{what} refused: {e}')
            return {}

    def _on_target_position(self, msg: JointState) -> None:
        targets = self._targets(msg, 'position', 'target_position')
        if not targets:
            return
        stamp = msg.header.stamp.sec + msg.header.stamp.nanosec * 1e-9
        if stamp > 0.0 and 0.0 < stamp - self.get_clock().now().nanoseconds * 1e-9 \
                <= MAX_SCHEDULE:
            if len(self.loop.scheduled) + len(targets) > MAX_SCHEDULED:
                self._refused('target_position:scheduled', (
                    f'target_position refused: {len(self.loop.scheduled)} targets scheduled '
                    f'already (at most {MAX_SCHEDULED})'))
                return
            self._flush_inputs()
            for a, t in targets.items():
                self.loop.schedule(stamp, a, t)
            return
        for a, t in targets.items():
            self.loop.post(a, t)

    def _on_target_velocity(self, msg: JointState) -> None:
        for a, v in self._targets(msg, 'velocity', 'target_velocity').items():
            self.loop.post(a, v, jog=True)

    def _flush_inputs(self) -> None:
        """Before another command (a service, a parameter set, a trajectory, a schedule): the
        targets and jogs posted since the last tick start first (ServoLoop.flush), so that
        commands take effect in the order they came."""
        if not self.loop.pending:
            return
        log, refused = self.loop.flush()
        self._log(log)
        self._log_refused(refused)

    def _log_refused(self, refused) -> None:
        for what, a, reason in refused:
            self._refused(f'{what}:{a}', f'{what} refused: {reason}')

    def _on_raw_trajectory(self, data: bytes) -> None:
        if len(data) > MAX_TRAJECTORY_BYTES:
            self._refused('trajectory:size', f'joint_trajectory refused: a {len(data)}-byte '
                          f'message (at most {MAX_TRAJECTORY_BYTES})')
            return
        counts = md.trajectory_counts(data)       # (before decoding: microseconds)
        most = max(MAX_TRAJECTORY_POINTS.values())
        if counts is not None and (counts[1] > most or counts[0] > MAX_TARGET_NAMES):
            self._refused('trajectory:size', f'joint_trajectory refused: {counts[1]} points for '
                          f'{counts[0]} axes (at most {most} points, {MAX_TARGET_NAMES} axes: '
                          'send a longer path in parts)')
            return
        if self.sim_time:                   # deterministic: prepared and started at once
            job = self._prepare(data)
            if job is not None:
                self._start_trajectory(*job)
            return
        self.trajectories.put(data)

    def _prepare_loop(self) -> None:
        while (data := self.trajectories.get()) is not None:       # (None: the node goes)
            job = self._prepare(data)
            if job is not None:
                self.prepared.put(job)

    def _prepare(self, data: bytes):
        """(prepared or refusal, stamp [s]) of a raw JointTrajectory, or None when it was
        refused already (logged)."""
        try:
            msg = deserialize_message(data, JointTrajectory)
        except Exception as e:               # (rclpy raises its own types for a bad CDR)
            self._refused('trajectory', f'joint_trajectory refused: not a JointTrajectory ({e})')
            return None
        kind = 'with accelerations' if any(p.accelerations for p in msg.points) else 'without'
        most = MAX_TRAJECTORY_POINTS[kind]
        if len(msg.points) > most or len(msg.joint_names) > MAX_TARGET_NAMES:
            self._refused('trajectory:size', f'joint_trajectory refused: {len(msg.points)} '
                          f'points for {len(msg.joint_names)} axes (at most {most} points '
                          f'{kind}: send a longer path in parts)')
            return None
        spec = md.read_joint_trajectory(msg)
        stamp = msg.header.stamp.sec + msg.header.stamp.nanosec * 1e-9
        return self.loop.prepare(spec), stamp

    def _start_trajectory(self, job, stamp: float) -> None:
        """On the servo thread: start (or schedule) a prepared trajectory."""
        self._flush_inputs()
        if isinstance(job, str):
            self._refused('trajectory', f'joint_trajectory refused: {job}')
            return
        now = self.get_clock().now().nanoseconds * 1e-9
        known = [a for a in job.spec['names'] if a in self.axes]
        self._log(self.loop.unschedule(known, 'a trajectory'))
        reason = self.loop.trajectory(job, stamp if 0.0 < stamp - now <= MAX_SCHEDULE else None,
                                      now)
        if reason:
            self._refused('trajectory', f'joint_trajectory refused: {reason}')

    def _make_services(self, a: str) -> None:
        axis = self.axes[a]

        def trigger(fn):
            def cb(request, response):
                self._flush_inputs()
                response.success, response.message = fn()
                return response
            return cb

        def enable(request, response):
            self._flush_inputs()
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
                            trigger(lambda: self._excite(a)))

    def _excite(self, a: str):
        """<axis>/excite: start a run; the answer names it (its number is in the record)."""
        ok, reason = self.loop.excite(a)
        if not ok:
            return False, reason
        self.runs[a] += 1
        g = self.axes[a].gather
        assert g is not None                     # (accepted: the run is there)
        e, r = g.excitation, self.loop.values[a]
        meta = dict(run=self.runs[a], signal=r['excitation_signal'], amplitude=e.amplitude,
                    band=[float(e.band[0]), float(e.band[1])], duration=e.duration,
                    velocity=g.base_velocity, budget=g.budget, rate=e.sample_rate)
        self.run_meta[a] = meta
        text = (f'{a}: run {meta["run"]}: {meta["signal"]} {e.amplitude:g} V, {e.band[0]:g}-'
                f'{e.band[1]:g} Hz, {e.ticks} ticks, base velocity {g.base_velocity:g} m/s, '
                f'budget {g.budget:g} m; the record comes on {md.gather_topic(a)}')
        self.get_logger().info(text)
        return True, text

    def _gather_loop(self) -> None:
        while (item := self.gathers.get()) is not None:            # (None: the node goes)
            a, g, meta = item
            rec = g.records[:g.tick]
            msg = md.gather_message(rec, COLUMNS, meta | dict(ended=g.ended, ticks=int(g.tick)))
            self.pub_gather[a].send(msg)
            self.get_logger().info(f'{a}: run {meta["run"]} ended ({g.ended}): {g.tick} ticks '
                                   f'published on {md.gather_topic(a)}')

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
        while not self.prepared.empty():
            self._start_trajectory(*self.prepared.get_nowait())
        if self.hardware_kind == 'topics':
            self.hardware.stamp_tick(stamp, now)
        tick = self.loop.cycle(now)
        if tick is None:
            return                       # sim time paused or stepped back
        if tick.log:
            self._log(tick.log)
        if tick.refused:
            self._log_refused(tick.refused)
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
        for a in list(self.run_meta):
            g = self.axes[a].gather
            if g is not None and g.ended is not None:
                self.gathers.put((a, g, self.run_meta.pop(a)))    # published off the tick
        for a in tick.changed:
            self.pub_status[a].send(UInt32(data=self.axes[a].word))
        self._refresh_status(now)
        self.follow.tick(now)            # the trajectory goal, after the outputs (never waits)
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

    # -- the sim clock (hardware sim, use_sim_time) ---------------------------------------------
    def _start_sim_clock(self) -> None:
        """This node is the clock: it publishes /clock and sets its own clock to the servo
        ticks' time (it does not read /clock, which it would only hear from itself)."""
        self.pub_clock = self.create_publisher(ClockMsg, md.CLOCK, 10)
        self.sim_ns = 0
        self.sim_wall_start = time.perf_counter()
        self.next_diagnostics_ns = 1_000_000_000
        self._time_source.detach_node()
        self._time_source.clock_callback(ClockMsg())

    def spin_step(self, executor) -> None:
        """What `spin` runs over and over: in real time, the executor (timer, callbacks); with
        the sim clock, servo ticks back to back for SIM_BATCH s of wall time (none while the
        sim time is ahead of MAX_SIM_SPEED x the wall time since the start), then /clock (the
        time of the last tick: ~1 kHz of wall time, as a simulator publishes it; one message
        per tick would cost every reader of /clock more than the tick itself) and the
        callbacks that came meanwhile."""
        if not self.sim_clock:
            executor.spin_once(timeout_sec=0.05)
            return
        ahead = self.sim_ns * 1e-9 / MAX_SIM_SPEED - (time.perf_counter() - self.sim_wall_start)
        if ahead > 0.0:                 # (at MAX_SIM_SPEED: callbacks only, until it is time)
            executor.spin_once(timeout_sec=min(ahead, SIM_BATCH))
            return
        if ahead < -SIM_BATCH:          # behind (a busy machine): on from now, not in a burst
            self.sim_wall_start = time.perf_counter() - self.sim_ns * 1e-9 / MAX_SIM_SPEED
        end = time.perf_counter() + SIM_BATCH
        while True:
            self._tick(stamp_of(self.sim_ns * 1e-9))
            if self.sim_ns >= self.next_diagnostics_ns:
                self.next_diagnostics_ns += 1_000_000_000
                self._publish_diagnostics()
            self.sim_ns += self.period_ns
            if time.perf_counter() >= end:
                break
        clock = ClockMsg(clock=stamp_of((self.sim_ns - self.period_ns) * 1e-9))
        self.pub_clock.publish(clock)
        self._time_source.clock_callback(clock)
        executor.spin_once(timeout_sec=0.0)

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
        # interpreter's exit outlives the extension modules (nanobind listed ruckig's objects
        # as ~30 lines of "leaked" on every stop).
        self.trajectories.put(None)
        self.gathers.put(None)
        if hasattr(self, 'follow'):      # (a node refused half-made has none)
            self.follow.destroy()
        super().destroy_node()

    def _publish_diagnostics(self) -> None:
        extra = {} if self.sync is None else {'timer_phase_shifts': self.sync.shifts}
        figures = getattr(self.hardware, 'figures', None)
        if figures is not None:
            extra |= figures()
        self.pub_diag.send(diagnostics_message(
            self.get_clock().now().to_msg(), self.get_name(), self.stats, self.axes, extra))
        self.stats.reset_window()


def main(args=None):
    sys.exit(run(ControllerNode, args))


if __name__ == '__main__':
    main()
