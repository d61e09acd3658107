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
    """A ROS domain for one run, other than this process's: a run never meets the samples of
    an earlier run's nodes (Fast DDS was seen handing a new reader the last samples of a plant
    that had exited, over shared memory)."""
    base = int(os.environ.get('ROS_DOMAIN_ID', '1'))
    return (base + 50 + next(_runs)) % 101 + 1


def run_lockstep(target: float = 0.0254, start: float = 1.0, end: float = 3.0,
                 timeout: float = 60.0, log_dir=None):
    """Returns ({stamp_ns: (x_motor, x_load, v_motor, v_load)}, sim seconds per wall second)."""
    import pathlib
    import rclpy
    d = params_dir()
    log = (lambda n: pathlib.Path(log_dir) / f'{n}.log') if log_dir else (lambda n: None)
    domain = _private_domain()
    env = os.environ | {'ROS_DOMAIN_ID': str(domain)}
    context = rclpy.Context()
    rclpy.init(context=context, domain_id=domain)
    controller = NodeProcess('controller_node', d / 'controller.yaml',
                             {'use_sim_time': 'true'}, log('controller'), env=_with_path(env))
    client = SlideClient(name='lockstep_client', context=context)
    truth, clock = {}, []
    live = []       # set once this run's plant starts
    # Depth for a whole run: a slow reader must not lose samples.
    deep = QoSProfile(depth=20000, reliability=ReliabilityPolicy.RELIABLE)

    def on_truth(msg):
        stamp = msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec
        if live:
            truth[stamp] = tuple(msg.position) + tuple(msg.velocity)

    def on_clock(msg):
        t = msg.clock.sec + msg.clock.nanosec * 1e-9
        if live:
            clock.append((time.monotonic(), t))
    client.create_subscription(JointState, md.PLANT_STATES, on_truth, deep)
    client.create_subscription(Clock, md.CLOCK, on_clock, deep)
    plant = None
    try:
        if not client.spin_until(lambda: client.pub_target.get_subscription_count() > 0, 30.0):
            raise RuntimeError('controller not discovered')
        stamp = JointState().header.stamp
        stamp.sec, stamp.nanosec = int(start), round((start % 1) * 1e9)
        msg = md.joint_state(stamp, ['x'], [target])
        client.pub_target.publish(msg)
        client.spin_until(lambda: False, 0.2)       # delivered before the clock starts
        live.append(True)
        plant = NodeProcess('plant_node', d / 'plant.yaml', {'lockstep': 1}, log('plant'),
                            env=_with_path(env))
        if not client.spin_until(lambda: clock and clock[-1][1] >= end, timeout):
            raise RuntimeError(
                f'lockstep did not reach {end} s of sim time: stopped at '
                f'{clock[-1][1] if clock else None} s; plant exit {plant.proc.poll()}, '
                f'controller exit {controller.proc.poll()}')
    finally:
        client.destroy_node()
        for n in (plant, controller):
            if n is not None:
                n.stop()
        context.try_shutdown()
    moving = [(w, s) for w, s in clock if s > 0.0]
    speed = ((moving[-1][1] - moving[0][1]) / (moving[-1][0] - moving[0][0])
             if len(moving) > 1 else float('nan'))
    return truth, speed


def _with_path(env: dict) -> dict:
    root = str(pathlib.Path(__file__).resolve().parent.parent)
    return env | {'PYTHONPATH': os.pathsep.join(p for p in (root, env.get('PYTHONPATH')) if p)}


def bench_lockstep() -> float:
    return run_lockstep(end=3.0)[1]
