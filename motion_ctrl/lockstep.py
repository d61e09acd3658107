"""Run a move in the deterministic lockstep simulation and collect the plant's ground truth.

Plant (`lockstep: 1`, the clock) and controller (`use_sim_time: true`, ticking on encoder
samples) as two processes. The target is stamped with the sim time at which it must start and
published before the plant starts, so the move begins on the same tick in every run, and the
whole run is bit-identical. Used by the lockstep test and the benchmark.
"""
from __future__ import annotations

import itertools
import os
import pathlib
import time

from rclpy.qos import QoSProfile, ReliabilityPolicy
from rosgraph_msgs.msg import Clock
from sensor_msgs.msg import JointState

import msg_defs as md
from motion_ctrl.client import SlideClient
from motion_ctrl.processes import NodeProcess, params_dir


_runs = itertools.count()


def _private_domain() -> int:
    """A ROS domain for one run, other than this process's, so runs don't meet each other."""
    base = int(os.environ.get('ROS_DOMAIN_ID', '1'))
    return (base + 50 + next(_runs)) % 101 + 1


def run_lockstep(target: float = 0.0254, start: float = 8.0, end: float = 10.0,
                 timeout: float = 60.0, log_dir=None):
    """Returns ({stamp_ns: (x_motor, x_load, v_motor, v_load)}, sim seconds per wall second)."""
    import pathlib
    import rclpy
    d = params_dir()
    log = (lambda n: pathlib.Path(log_dir) / f'{n}.log') if log_dir else (lambda n: None)
    domain = _private_domain()
    # Loopback UDP, not shared memory: Fast DDS leaves the shared-memory port queues of
    # stopped processes in /dev/shm, and a new participant on the same domain and port was
    # seen reading an earlier run's last samples from them (a stale /clock ended a run at
    # once). Lost UDP datagrams cost nothing here: the plant resends a sample without answer.
    udp = {'FASTDDS_BUILTIN_TRANSPORTS': 'UDPv4'}
    env = os.environ | {'ROS_DOMAIN_ID': str(domain)} | udp
    context = rclpy.Context()
    saved = {k: os.environ.get(k) for k in udp}
    os.environ.update(udp)               # read when the participant is created
    try:
        rclpy.init(context=context, domain_id=domain)
    finally:
        for k, v in saved.items():
            if v is None:
                os.environ.pop(k, None)
            else:
                os.environ[k] = v
    client = SlideClient(name='lockstep_client', context=context)
    truth, clock = {}, []
    # Depth for a whole run: a slow reader must not lose samples.
    deep = QoSProfile(depth=20000, reliability=ReliabilityPolicy.RELIABLE)

    def on_truth(msg):
        stamp = msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec
        truth[stamp] = tuple(msg.position) + tuple(msg.velocity)

    def on_clock(msg):
        clock.append((time.monotonic(), msg.clock.sec + msg.clock.nanosec * 1e-9))
    client.create_subscription(JointState, md.PLANT_STATES, on_truth, deep)
    client.create_subscription(Clock, md.CLOCK, on_clock, deep)
    controller = None
    # The plant first: it holds t = 0 (resending it) until a controller answers, so this
    # client sees the run from its first sample. Then the controller: the sim runs as soon as
    # it finds the plant, and it gets the target (stamped `start`, up to 10 s ahead) when this
    # client has found it, which takes a second or two: `start` leaves room for that.
    plant = NodeProcess('plant_node', d / 'plant.yaml', {'lockstep': 1}, log('plant'),
                        env=_with_path(env))
    try:
        if not client.spin_until(lambda: clock and truth, 30.0):
            raise RuntimeError('lockstep plant not discovered')
        controller = NodeProcess('controller_node', d / 'controller.yaml',
                                 {'use_sim_time': 'true'}, log('controller'),
                                 env=_with_path(env))
        if not client.spin_until(lambda: client.pub_target.get_subscription_count() > 0, 30.0):
            raise RuntimeError('controller not discovered')
        stamp = JointState().header.stamp
        stamp.sec, stamp.nanosec = int(start), round((start % 1) * 1e9)
        sent_at = clock[-1][1]
        client.pub_target.publish(md.joint_state(stamp, ['x'], [target]))
        if sent_at > start - 1.0:
            raise RuntimeError(f'the target was sent at sim time {sent_at:.3f} s, too close '
                               f'to its start at {start} s to be sure it arrived before')
        if not client.spin_until(lambda: clock[-1][1] >= end, timeout):
            raise RuntimeError(
                f'lockstep did not reach {end} s of sim time: stopped at {clock[-1][1]} s; '
                f'plant exit {plant.proc.poll()}, controller exit {controller.proc.poll()}')
    finally:
        client.destroy_node()
        for n in (plant, controller):
            if n is not None:
                n.stop()
        context.try_shutdown()
    moving = [(w, t) for w, t in clock if t > 0.0]
    speed = ((moving[-1][1] - moving[0][1]) / (moving[-1][0] - moving[0][0])
             if len(moving) > 1 else float('nan'))
    return truth, speed


def _with_path(env: dict) -> dict:
    root = str(pathlib.Path(__file__).resolve().parent.parent)
    return env | {'PYTHONPATH': os.pathsep.join(p for p in (root, env.get('PYTHONPATH')) if p)}


def bench_lockstep() -> float:
    return run_lockstep()[1]
