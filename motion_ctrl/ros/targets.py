"""The controller's target inputs: `target_position` and `target_velocity` (sensor_msgs/JointState)
and `joint_trajectory` (trajectory_msgs/JointTrajectory), read raw so that an oversized message
is refused by its size before it is decoded, each refusal logged with its reason at most once a
second per kind (ros.refusals; doc/input_limits.md).

A target whose header stamp lies up to MAX_SCHEDULE seconds ahead of the node's clock is applied
at the first tick at or after that stamp (a coordinated start of several axes, or a move at an
exact sim time); other targets are posted for the next tick, the latest of each axis winning
(`ServoLoop.post`). A trajectory is checked as a whole and run on all its axes on one time base
(`ServoLoop.trajectory`, PMAC PVT); its header stamp schedules it the same way. In real time it
is decoded, checked and built on a thread of its own and started by the next tick; in sim time
at once (deterministic).

Commands take effect in the order they came: before any other command (a service, a parameter
set, a trajectory, a schedule) the targets posted since the last tick start (`flush`).
"""
from __future__ import annotations

import importlib
import queue
import threading

from rclpy.serialization import deserialize_message
from sensor_msgs.msg import JointState
from trajectory_msgs.msg import JointTrajectory

import msg_defs as md
from motion_ctrl.ros.hardware_topics import seconds_of
from motion_ctrl.ros.refusals import RefusalLog, too_large

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
# What a trajectory uses of scipy, imported before the loop runs (~0.7 s of start-up): imported
# on the trajectories thread, it would hold the GIL in long C calls for ~0.4 s and stall both
# loops (doc/design_notes.md, "Python's own pauses in the servo thread").
PRELOAD = ('scipy.interpolate',)


class TargetInputs:
    """The target topics of `node` (the controller), fed to its servo loop `loop`."""

    def __init__(self, node, loop, sim_time: bool) -> None:
        self.node = node
        self.loop = loop
        self.axes = loop.axes
        self.sim_time = sim_time
        self.refusals = RefusalLog(node.get_logger().warning)
        self.trajectories: queue.SimpleQueue = queue.SimpleQueue()     # raw messages in
        self.prepared: queue.SimpleQueue = queue.SimpleQueue()         # built, to start
        node.create_subscription(JointState, md.TARGET_POSITION, self._raw_target(
            self._on_target_position, 'target_position'), 10, raw=True)
        node.create_subscription(JointState, md.TARGET_VELOCITY, self._raw_target(
            self._on_target_velocity, 'target_velocity'), 10, raw=True)
        for module in PRELOAD:
            importlib.import_module(module)
        node.create_subscription(JointTrajectory, md.JOINT_TRAJECTORY, self._on_raw_trajectory,
                                 10, raw=True)
        if not sim_time:
            threading.Thread(target=self._prepare_loop, name='trajectories', daemon=True).start()

    def close(self) -> None:
        """The trajectory thread ends (it holds the node)."""
        self.trajectories.put(None)

    # -- on the servo thread --------------------------------------------------------------------
    def flush(self) -> None:
        """Before another command: the targets and jogs posted since the last tick start first
        (ServoLoop.flush), so that commands take effect in the order they came."""
        if not self.loop.pending:
            return
        log, refused = self.loop.flush()
        self.node._log(log)
        self.log_refused(refused)

    def start_prepared(self) -> None:
        """The trajectories built since the last tick start (or are scheduled)."""
        while not self.prepared.empty():
            self._start_trajectory(*self.prepared.get_nowait())

    def log_refused(self, refused) -> None:
        for what, a, reason in refused:
            self.refused(f'{what}:{a}', f'{what} refused: {reason}')

    def refused(self, kind: str, text: str) -> None:
        """A refusal, logged at most once a second per kind (ros.refusals)."""
        self.refusals.refused(kind, text)

    # -- target_position, target_velocity -------------------------------------------------------
    def _raw_target(self, callback, what: str):
        def on_raw(data: bytes) -> None:
            if len(data) > md.MAX_TARGET_BYTES:
                self.refused(what + ':size', too_large(what, len(data)))
                return
            try:
                msg = deserialize_message(data, JointState)
            except Exception as e:           # (rclpy raises its own types for a bad CDR)
                self.refused(what, f'{what} refused: not a JointState ({e})')
                return
            callback(msg)
        return on_raw

    def _targets(self, msg, field, what):
        if len(msg.name) > MAX_TARGET_NAMES:
            self.refused(what + ':size', f'{what} refused: {len(msg.name)} names (at most '
                         f'{MAX_TARGET_NAMES})')
            return {}
        try:
            return md.read_joint_state(msg, field, known=self.axes)
        except md.MalformedMessage as e:
            self.refused(what, f'{what} refused: {e}')
            return {}

    def _on_target_position(self, msg: JointState) -> None:
        targets = self._targets(msg, 'position', 'target_position')
        if not targets:
            return
        stamp = seconds_of(msg.header.stamp)
        if stamp > 0.0 and 0.0 < stamp - self.node.get_clock().now().nanoseconds * 1e-9 \
                <= MAX_SCHEDULE:
            if len(self.loop.scheduled) + len(targets) > MAX_SCHEDULED:
                self.refused('target_position:scheduled', (
                    f'target_position refused: {len(self.loop.scheduled)} targets scheduled '
                    f'already (at most {MAX_SCHEDULED})'))
                return
            self.flush()
            for a, t in targets.items():
                self.loop.schedule(stamp, a, t)
            return
        for a, t in targets.items():
            self.loop.post(a, t)

    def _on_target_velocity(self, msg: JointState) -> None:
        for a, v in self._targets(msg, 'velocity', 'target_velocity').items():
            self.loop.post(a, v, jog=True)

    # -- joint_trajectory -----------------------------------------------------------------------
    def _on_raw_trajectory(self, data: bytes) -> None:
        if len(data) > MAX_TRAJECTORY_BYTES:
            self.refused('trajectory:size', f'joint_trajectory refused: a {len(data)}-byte '
                         f'message (at most {MAX_TRAJECTORY_BYTES})')
            return
        counts = md.trajectory_counts(data)       # (before decoding: microseconds)
        most = max(MAX_TRAJECTORY_POINTS.values())
        if counts is not None and (counts[1] > most or counts[0] > MAX_TARGET_NAMES):
            self.refused('trajectory:size', f'joint_trajectory refused: {counts[1]} points for '
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
            self.refused('trajectory', f'joint_trajectory refused: not a JointTrajectory ({e})')
            return None
        kind = 'with accelerations' if any(p.accelerations for p in msg.points) else 'without'
        most = MAX_TRAJECTORY_POINTS[kind]
        if len(msg.points) > most or len(msg.joint_names) > MAX_TARGET_NAMES:
            self.refused('trajectory:size', f'joint_trajectory refused: {len(msg.points)} '
                         f'points for {len(msg.joint_names)} axes (at most {most} points '
                         f'{kind}: send a longer path in parts)')
            return None
        spec = md.read_joint_trajectory(msg)
        stamp = seconds_of(msg.header.stamp)
        return self.loop.prepare(spec), stamp

    def _start_trajectory(self, job, stamp: float) -> None:
        """On the servo thread: start (or schedule) a prepared trajectory."""
        self.flush()
        if isinstance(job, str):
            self.refused('trajectory', f'joint_trajectory refused: {job}')
            return
        now = self.node.get_clock().now().nanoseconds * 1e-9
        known = [a for a in job.spec['names'] if a in self.axes]
        self.node._log(self.loop.unschedule(known, 'a trajectory'))
        reason = self.loop.trajectory(job, stamp if 0.0 < stamp - now <= MAX_SCHEDULE else None,
                                      now)
        if reason:
            self.refused('trajectory', f'joint_trajectory refused: {reason}')
