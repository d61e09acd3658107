"""The deterministic lockstep simulation: start it, and run a move in it collecting the plant's
ground truth.

Two forms:

* `hardware: sim` (the default here): the controller alone, with the slide simulated inside its
  loop and its own sim clock (`use_sim_time: true`): it ticks back to back as fast as the machine
  allows, up to `sim_speed` times real time (4 unless set; 0: unbounded), and publishes
  `/clock`.
* `hardware: topics`: plant (`lockstep: 1`, the clock) and controller (`use_sim_time: true`,
  ticking on encoder samples) as two processes exchanging `encoders` and `command` over DDS.

The target is stamped with the sim time at which it must start and published well before that
time, so the move begins on the same tick in every run, and the whole run is bit-identical. Used
by the tools' `--lockstep`, the lockstep tests and the benchmark.
"""
from __future__ import annotations

import math
import os
import time

import rclpy
from rclpy.node import Node
from rclpy.qos import QoSProfile, ReliabilityPolicy
from rclpy.serialization import deserialize_message
from rosgraph_msgs.msg import Clock as ClockMsg
from sensor_msgs.msg import JointState

import msg_defs as md
from motion_ctrl.ros import processes, ros_env
from motion_ctrl.ros.processes import NodeProcess, log_file, params_dir


# The lockstep overrides: the plant is the clock, the controller ticks on its sim time; both at
# normal scheduling, since they run flat out (at real-time priority they would starve the rest).
CONTROLLER = {'use_sim_time': 'true', 'realtime_priority': 0}
PLANT = {'lockstep': 1, 'realtime_priority': 0}
# The nodes' environment: no servo bus (ros.servo_bus), which keeps the loop clear of what joins
# the user's domain; in lockstep a stall holds up the sim time, not the loop, and the bridges'
# copies would only slow the run. Each run has a domain of its own: Fast DDS leaves the
# shared-memory port queues of stopped processes in /dev/shm, and a new participant on the same
# domain and port can read an earlier run's last samples from them: a stale /clock would end the
# run at once (doc/design_notes.md, "Shared memory left by killed processes").
NODE_ENV = {'MOTION_CTRL_SERVO_DOMAIN': 'off'}
# With the slide in the controller (sim) its publishers send from Fast DDS's own thread: a
# publish only queues the sample, and the sends (two system calls a datagram, the costliest
# part of a lockstep tick here: ~30 of its ~48 µs to a reliable reader) run on the other core;
# no loop closes over these streams. Not for topics, where each tick waits for the other
# process's answer and the hand-over's latency slows the sim (2.2-2.3x against 2.4-2.7x).
SIM_ENV = {'RMW_FASTRTPS_PUBLICATION_MODE': 'ASYNCHRONOUS'}


def node_env(env: dict | None = None, hardware: str = 'topics') -> dict:
    """`env` (default: this process's) for a lockstep node: off the bus, and announcing
    loopback UDP only (ros_env.loopback_udp: no shared-memory port to leave behind); the
    controller of `hardware` sim publishing asynchronously (SIM_ENV)."""
    env = dict(os.environ if env is None else env) | NODE_ENV | (
        SIM_ENV if hardware == 'sim' else {})
    return env | ros_env.loopback_udp(env)


def client_context(domain: int):
    """An initialised rclpy context on `domain`, for a client of the lockstep nodes."""
    context = rclpy.Context()
    rclpy.init(context=context, domain_id=domain)
    return context


def start_slide(controller_params: dict | None = None, plant_params: dict | None = None,
                log_dir=None, env: dict | None = None, hardware: str = 'sim'):
    """The lockstep simulation's processes, to stop when done: with `hardware` sim the
    controller alone, the clock (processes.start_sim with the lockstep overrides), whose sim
    runs from its start; with topics plant (the clock) and controller (on its sim time)
    (processes.start_slide), whose sim runs as soon as they have found each other (the plant
    resends its sample until answered)."""
    if hardware == 'sim':
        return processes.start_sim((controller_params or {}) | CONTROLLER, plant_params,
                                   log_dir, env=node_env(env, 'sim'))
    return processes.start_slide((controller_params or {}) | CONTROLLER,
                                 (plant_params or {}) | PLANT, log_dir, env=node_env(env))


class _Observer:
    """The lockstep run's observer, the third process on two cores: it must not slow the loop
    it watches. It takes plant_states raw (no Python message per sample) and decodes them after
    the run; progress is read from the newest sample a few times a second. It publishes the
    target and keeps the /clock it hears."""

    def __init__(self, context):
        self.context = context
        self.node = Node('lockstep_observer', context=context)
        self.executor = ros_env.executor(context)
        self.executor.add_node(self.node)
        self.pub_target = self.node.create_publisher(JointState, md.TARGET_POSITION, 10)
        self.raw: list = []          # (wall time of arrival, serialised plant_states)
        self.node.create_subscription(
            JointState, md.PLANT_STATES, lambda b: self.raw.append((time.monotonic(), b)),
            QoSProfile(depth=20000, reliability=ReliabilityPolicy.RELIABLE),
            raw=True)                # deep: a slow reader must not lose samples
        self.clock: list = []
        self.node.create_subscription(ClockMsg, md.CLOCK, lambda m: self.clock.append(m.clock),
                                      10)

    def sim_time(self) -> float:
        """The newest plant_states sample's stamp [s], -1 before the first."""
        if not self.raw:
            return -1.0
        st = deserialize_message(self.raw[-1][1], JointState).header.stamp
        return st.sec + st.nanosec * 1e-9

    def spin_until(self, predicate, seconds) -> bool:
        deadline = time.monotonic() + seconds
        while time.monotonic() < deadline:
            if predicate():
                return True
            next_check = min(deadline, time.monotonic() + 0.05)
            while time.monotonic() < next_check:
                self.executor.spin_once(timeout_sec=0.01)
        return predicate()

    def spin_for(self, seconds) -> None:
        self.spin_until(lambda: False, seconds)     # the time is the point: no condition to meet

    def send_target(self, target: float, start: float, sim: bool) -> float:
        """The target published, stamped with the sim time its move starts at, once the
        controller is there: `start` (topics), or `start` s after the controller's clock as
        first read here, at a whole second (sim). Returns that start [s of sim time]."""
        if not self.spin_until(lambda: self.pub_target.get_subscription_count() > 0, 30.0):
            raise RuntimeError('controller not discovered')
        self.spin_for(0.5)                      # the controller's side of the match, too
        if sim:
            if not self.spin_until(lambda: self.clock, 30.0):
                raise RuntimeError('no /clock from the controller')
            start = math.ceil(self.clock[-1].sec + self.clock[-1].nanosec * 1e-9 + start)
        stamp = JointState().header.stamp
        stamp.sec, stamp.nanosec = int(start), round((start % 1) * 1e9)
        self.pub_target.publish(md.joint_state(stamp, ['x'], [target]))
        self.spin_for(0.2)
        return start

    def close(self) -> None:
        self.executor.shutdown()
        self.node.destroy_node()


def run_lockstep(target: float = 0.0254, start: float = 20.0, duration: float = 2.0,
                 timeout: float = 60.0, log_dir=None, hardware: str = 'topics',
                 sim_speed: float | None = None):
    """A move to `target` in the lockstep simulation. Returns ({ns from the move's start:
    (x_motor, x_load, v_motor, v_load)}, sim seconds per wall second), the slide's truth from
    the move's start to `duration` s after it.

    With `hardware` topics the move starts at sim time `start`: the controller starts first
    and its clock stands at 0 until the plant comes, so the target is stamped `start` (the
    observer may find the plant late, a missed discovery announcement being repeated after
    3 s, ~10 s of sim time: keep `start` well after that). With `hardware` sim the controller
    is the clock and runs from its start: the move starts `start` s of sim time after its clock
    as this observer first reads it, at a whole second. Either way the slide rests until then
    and the move is the same, tick for tick. `sim_speed` (sim): the controller's register.
    """
    d = params_dir()
    domain = ros_env.spare_domain()
    env = node_env(os.environ | {'ROS_DOMAIN_ID': str(domain)}, hardware)
    obs = _Observer(client_context(domain))
    plant = None
    sim = hardware == 'sim'
    controller = NodeProcess('controller_node', [d / 'controller.yaml'] + (
        [d / 'plant.yaml'] if sim else []), CONTROLLER | ({'hardware': 'sim'} if sim else {})
        | ({} if sim_speed is None else {'sim_speed': float(sim_speed)}),
        log_file(log_dir, 'controller'), env=env)
    try:
        start = obs.send_target(target, start, sim)
        if not sim:
            plant = NodeProcess('plant_node', d / 'plant.yaml', PLANT,
                                log_file(log_dir, 'plant'), env=env)
        if not obs.spin_until(lambda: obs.raw, 30.0):
            raise RuntimeError('plant_states not seen')
        end = start + duration
        if not obs.spin_until(lambda: obs.sim_time() >= end, timeout):
            raise RuntimeError(
                f'lockstep did not reach {end} s of sim time: stopped at {obs.sim_time()} s; '
                f'plant exit {None if plant is None else plant.proc.poll()}, controller exit '
                f'{controller.proc.poll()}')
    finally:
        obs.close()
        for n in (controller, plant):
            if n is not None:
                n.stop()
        obs.context.try_shutdown()
    return _truth(obs.raw, start, duration)


def _truth(raw: list, start: float, duration: float):
    """The run's plant_states decoded: ({ns from the move's start: (x_motor, x_load, v_motor,
    v_load)} for `duration` s from `start`, sim seconds per wall second)."""
    truth, moving = {}, []
    start_ns = round(start * 1e9)
    for wall, b in raw:
        msg = deserialize_message(b, JointState)
        t_ns = msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec
        if 0 <= t_ns - start_ns <= duration * 1e9:
            truth[t_ns - start_ns] = tuple(msg.position) + tuple(msg.velocity)
        if t_ns > 0:
            moving.append((wall, t_ns * 1e-9))
    speed = ((moving[-1][1] - moving[0][1]) / (moving[-1][0] - moving[0][0])
             if len(moving) > 1 else float('nan'))
    return truth, speed


def bench_lockstep(hardware: str = 'topics') -> float:
    """Sim seconds per wall second of a lockstep move; with `hardware` sim unbounded
    (`sim_speed` 0)."""
    return run_lockstep(hardware=hardware, sim_speed=0.0 if hardware == 'sim' else None)[1]
