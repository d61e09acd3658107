"""The benchmark's measurements (`benchmark` prints them as tables, doc/performance.md): what a
servo tick of the core costs, the machine's floor, the controller's loop in real time over DDS
or with the slides in its loop, and `hardware: canopen` against `virtual_drive`.

Speed is measured here, never asserted in a test.
"""
from __future__ import annotations

import math
import os
import statistics
import time

import numpy as np
from diagnostic_msgs.msg import DiagnosticArray
from rclpy.executors import SingleThreadedExecutor
from rclpy.experimental import EventsExecutor
from rclpy.node import Node
from sensor_msgs.msg import JointState
from std_srvs.srv import Trigger

import msg_defs as md
from motion_ctrl.canopen import busload
from motion_ctrl.canopen.objects import cycle_frames
from motion_ctrl.core import axis as axis_module
from motion_ctrl.core import trajectory as tj
from motion_ctrl.core.axis import Axis
from motion_ctrl.core.config import ProfileConfig, SettlingConfig
from motion_ctrl.core.profile import Profile
from motion_ctrl.core.registers import INCH, axis_defaults
from motion_ctrl.core.settling import Settling
from motion_ctrl.ros.processes import CAN_BUS, start_canopen, start_sim, start_slide
from motion_ctrl.sim import plant as plant_module
from motion_ctrl.sim.harness import Harness
from motion_ctrl.sim.plant import SlidePlant


def _pct(values, q):
    return float(np.percentile(np.asarray(values), q)) if len(values) else float('nan')


# -- core ----------------------------------------------------------------------------------------
def built() -> str:
    """How the servo tick and the plant run here: compiled by mypyc, or plain Python."""
    return ('compiled by mypyc' if axis_module.__file__.endswith('.so') and
            plant_module.__file__.endswith('.so') else 'plain Python (not compiled)')


def _per_tick(fn, count: int) -> float:
    """µs per call of fn(i), i = 0 .. count - 1."""
    t = time.perf_counter()
    for i in range(count):
        fn(i)
    return (time.perf_counter() - t) / count * 1e6


def bench_core(n: int = 20000) -> list[tuple[str, float]]:
    """(what, µs per servo tick) of the ROS-free core, each timed over `n` ticks: the profile
    and settling, an Axis at rest and moving, two axes following a two-axis trajectory."""
    r = axis_defaults()
    return _bench_profile(r, n) + _bench_axis(r, n) + _bench_trajectory(r, n)


def _bench_profile(r: dict, n: int) -> list[tuple[str, float]]:
    """Profile.step + Settling.update on a new 1-inch move every second, both ways."""
    p = Profile(0.0)
    p.configure(ProfileConfig.of(r | {'max_jerk': 20.0, 'smoothing': 0.1}), 1e-3)
    s = Settling(SettlingConfig.of(r))

    def profile_settling(i):
        if i % 1000 == 0:                     # a new 1-inch move every second, both ways
            tgt = 0.0254 if (i // 1000) % 2 == 0 else 0.0
            p.move_to(tgt)
            s.start_position_move(tgt)
        p.step(1e-3)
        s.update(1e-3, command_position=p.position, command_velocity=p.velocity,
                 profile_done=p.done, actual_position=p.position, actual_velocity=p.velocity)
    return [('Profile.step + Settling.update (jerk-limited, IT smoothing, moving)',
             _per_tick(profile_settling, n))]


def _bench_axis(r: dict, n: int) -> list[tuple[str, float]]:
    """A whole Axis.update at rest, and moving (its encoders read its command)."""
    a = Axis('x', r)
    a.home(0, 0)
    rows = [('Axis.update at rest', _per_tick(lambda i: a.update(1e-3, 0, 0), n))]
    b = Axis('x', r)
    b.home(0, 0)

    def moving(i):
        if i % 1000 == 0:
            b.move_to(0.0254 if (i // 1000) % 2 == 0 else 0.0)
        pos = b.profile.position
        b.update(1e-3, int(pos * r['motor_counts_per_m']), int(pos * r['load_counts_per_m']))
    rows.append(('Axis.update moving (servo law, profile, settling, status)',
                 _per_tick(moving, n)))
    return rows


def _bench_trajectory(r: dict, n: int) -> list[tuple[str, float]]:
    """Two axes following a two-axis trajectory (PVT, quintic): the circle of the draw example;
    the polynomials are evaluated once per tick for both (Trajectory.paths)."""
    limits = {a: tj.AxisLimits.from_registers(r) for a in 'xy'}
    circle = tj.circle((-0.01, 0.0), 0.01, 0.02)
    traj = tj.Trajectory.from_points(['x', 'y'], circle, start={'x': (0.0, 0.0, 0.0),
                                                                 'y': (0.0, 0.0, 0.0)},
                                     limits=limits)
    axes = {a: Axis(a, r) for a in 'xy'}
    for ax in axes.values():
        ax.home(0, 0)

    def following(i):
        if i % 4000 == 0:      # the circle lasts 3.64 s: start it again from its end, at rest
            paths = traj.paths()
            for name, ax in axes.items():
                ax.profile.hold(0.0)
                ok, why = ax.follow(paths[name])
                assert ok, why
        for ax in axes.values():
            pos = ax.profile.position
            ax.update(1e-3, int(pos * r['motor_counts_per_m']),
                      int(pos * r['load_counts_per_m']))
    rows = [('2 axes following a 2-axis trajectory (PVT, quintic): both Axis.update',
             _per_tick(following, n))]
    # What Trajectory.paths saves: the same state from scipy's BPoly calls (p, v, a).
    shared = traj.paths()['x']
    rows.append(('  of which the trajectory state for both axes (Trajectory.paths)',
                 _per_tick(lambda i: shared.at((i % 3000 + 0.5) * 1e-3), n)))
    rows.append(('  the same from scipy (Trajectory.sample: BPoly p, v, a)',
                 _per_tick(lambda i: traj.sample((i % 3000 + 0.5) * 1e-3), n // 4)))
    return rows


def bench_harness(repeats: int = 7) -> list[tuple[str, float, float, float]]:
    """The in-process harness (one axis + plant) making the 1-inch move and back (2.08 s of sim
    time), and the plant's step alone replaying that run's commands: (what, µs per 1 ms tick
    best and median of `repeats`, × real time at the median, nan for the plant alone)."""
    h = Harness()
    h.move(INCH)
    h.move(0.0)
    assert h.trace is not None
    volts, ticks = list(h.trace.output), h.ticks
    runs: list[float] = []
    plant_runs: list[float] = []
    for _ in range(repeats):
        h = Harness(record=False)
        t = time.perf_counter()
        h.move(INCH)
        h.move(0.0)
        runs.append((time.perf_counter() - t) / h.ticks * 1e6)
        assert h.ticks == ticks
        p = SlidePlant()
        t = time.perf_counter()
        for v in volts:
            p.step(v, 1e-3)
        plant_runs.append((time.perf_counter() - t) / len(volts) * 1e6)
    med = statistics.median(runs)
    return [('in-process harness, one axis + plant: 1-inch move and back', min(runs), med,
             1e3 / med),
            ('SlidePlant.step alone, replaying that run', min(plant_runs),
             statistics.median(plant_runs), math.nan)]


# -- floor ---------------------------------------------------------------------------------------
def _jitter(stamps, period: float) -> dict:
    """The achieved rate and the period jitter p50 / p99 / max [µs] of tick times [s]."""
    dt = np.diff(np.asarray(stamps))
    jitter = np.abs(dt - period) * 1e6
    return {'rate_hz': len(dt) / dt.sum(), 'jitter_p50_us': _pct(jitter, 50),
            'jitter_p99_us': _pct(jitter, 99), 'jitter_max_us': float(jitter.max())}


def bench_sleep_floor(rate: float, seconds: float = 3.0) -> dict:
    """A bare Python loop sleeping to each period's end at `rate`: its rate and jitter."""
    period = 1.0 / rate
    n = int(seconds * rate)
    stamps = np.empty(n)
    nxt = time.perf_counter()
    for i in range(n):
        nxt += period
        delay = nxt - time.perf_counter()
        if delay > 0:
            time.sleep(delay)
        stamps[i] = time.perf_counter()
    return _jitter(stamps, period)


def bench_rclpy_floor(rate: float, seconds: float = 3.0) -> dict:
    """A bare rclpy timer at `rate` doing nothing, on an EventsExecutor: its rate and jitter."""
    node = Node('bench_floor')
    stamps: list[float] = []
    node.create_timer(1.0 / rate, lambda: stamps.append(time.perf_counter()))
    ex = EventsExecutor()
    ex.add_node(node)
    end = time.perf_counter() + seconds
    while time.perf_counter() < end:
        ex.spin_once(timeout_sec=0.05)
    ex.shutdown()
    node.destroy_node()
    return _jitter(stamps, 1.0 / rate)


# -- dds -----------------------------------------------------------------------------------------
def _cpu_seconds(pid: int) -> float:
    with open(f'/proc/{pid}/stat') as f:
        fields = f.read().rsplit(')', 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf('SC_CLK_TCK')


def _cpu_while(pids, run) -> tuple[float, float]:
    """(CPU seconds of the processes `pids`, wall seconds) while `run()` runs."""
    cpu0, t0 = sum(_cpu_seconds(p) for p in pids), time.monotonic()
    run()
    cpu1, t1 = sum(_cpu_seconds(p) for p in pids), time.monotonic()
    return cpu1 - cpu0, t1 - t0


def _value(text: str):
    try:
        return float(text)
    except ValueError:
        return text


def _axis_names(n_axes: int) -> list[str]:
    return [f'a{i}' for i in range(n_axes)] if n_axes > 1 else ['x']


class _Observer:
    """The benchmark's own node: it reads only /diagnostics (a third process taking 1 kHz
    streams would load the cores it shares with the nodes measured) and keeps the servo loop's
    entries that `keep` accepts, each with the time it was received."""

    def __init__(self, keep):
        self.node = Node('bench_observer')
        self.executor = SingleThreadedExecutor()
        self.executor.add_node(self.node)
        self.diags: list[dict] = []

        def on_diagnostics(msg):
            for st in msg.status:
                if st.name.endswith('servo loop'):
                    d = {kv.key: _value(kv.value) for kv in st.values}
                    if keep(d):
                        self.diags.append(d | {'received': time.monotonic()})
        self.node.create_subscription(DiagnosticArray, md.DIAGNOSTICS, on_diagnostics, 10)

    def spin(self, seconds: float, until=lambda: False) -> None:
        end = time.monotonic() + seconds
        while time.monotonic() < end and not until():
            self.executor.spin_once(timeout_sec=0.05)

    def came_up(self, seconds: float) -> bool:
        """Whether two entries came within `seconds`: the nodes up, a second of loop behind."""
        self.spin(seconds, until=lambda: len(self.diags) >= 2)
        return len(self.diags) >= 2

    def interface_up(self, axis: str, seconds: float) -> bool:
        """Whether `axis`'s last service is on this domain within `seconds`: the bridge has
        mirrored the node's interface (for 256 axes it makes ~1800 services over tens of
        seconds after the loop runs, the busiest time of the controller's process)."""
        client = self.node.create_client(Trigger, md.service_name(axis, 'excite'))
        end = time.monotonic() + seconds
        while time.monotonic() < end and not client.service_is_ready():
            self.spin(0.2)
        up = client.service_is_ready()
        self.node.destroy_client(client)
        return up

    def jog(self, axes: list[str]) -> None:
        """Every axis jogging at 20 mm/s (half of them negative), at speed."""
        jog = self.node.create_publisher(JointState, md.TARGET_VELOCITY, 10)
        self.spin(5.0, until=lambda: jog.get_subscription_count() > 0)
        self.spin(0.5)
        jog.publish(md.joint_state(self.node.get_clock().now().to_msg(), axes,
                                   velocity=[0.02 * (-1) ** i for i in range(len(axes))]))
        self.spin(0.5)                                     # at speed

    def command_transport(self) -> list[float]:
        """Seconds from each command's stamp to its arrival here (as the plant receives it),
        over 2 s after a second for the new reader's discovery."""
        transport: list[float] = []

        def on_command(msg):
            now = self.node.get_clock().now().nanoseconds * 1e-9
            transport.append(now - (msg.header.stamp.sec + msg.header.stamp.nanosec * 1e-9))
        self.node.create_subscription(JointState, md.COMMAND, on_command, md.SERVO_READ_QOS)
        self.spin(1.0)                                     # discovery of the new reader
        transport.clear()
        self.spin(2.0)
        return transport

    def close(self) -> None:
        self.node.destroy_node()
        self.executor.shutdown()


def _start_loop(rate: float, axes: list[str], hardware: str) -> list:
    """The controller at `rate` for `axes`, with the plant (topics) or the slides in its loop
    (sim); the processes, the controller last."""
    axes_param = '[' + ','.join(axes) + ']'
    # Many axes: integrate the physics at the servo rate only, so the plant keeps up; the
    # controller's loop is what is measured.
    substep = 20000.0 if len(axes) <= 6 else rate
    if hardware == 'sim':
        return start_sim({'axes': axes_param, 'servo_rate': float(rate)},
                         {'substep_rate': substep}, params_files=False)
    return start_slide(
        {'axes': axes_param, 'servo_rate': float(rate)},
        {'axes': axes_param, 'publish_rate': float(rate), 'substep_rate': substep},
        params_files=False)


def bench_dds(rate: float, n_axes: int, seconds: float = 5.0, hardware: str = 'topics',
              moving: bool = False) -> dict:
    """Loop figures in real time. The observer (this process) reads only /diagnostics while the
    rate is measured: a third process taking 1 kHz streams would load the two cores it shares
    with plant and controller. The command transport (topics) is measured after, in a window of
    its own. `moving`: every axis jogs (at 20 mm/s, half of them negative) while the rate is
    measured, else they rest."""
    axes = _axis_names(n_axes)
    nodes = _start_loop(rate, axes, hardware)
    controller = nodes[-1]
    obs = _Observer(lambda d: 'rate_hz' in d)
    transport: list[float] = []
    try:
        # up, and a second of loop behind it (each axis's services take ~0.1 s to make: 35 s
        # for 256 axes here)
        if not (obs.came_up(30.0 + 0.2 * n_axes)
                and obs.interface_up(axes[-1], 30.0 + 0.2 * n_axes)):
            return {'error': 'nodes did not come up'}
        obs.spin(1.0)
        if moving:
            obs.jog(axes)
        obs.diags.clear()
        # The controller's CPU: its loop process and, on the servo bus (ros.servo_bus), the
        # bridge that started it, together.
        cpu, wall = _cpu_while({controller.proc.pid, controller.servo_pid()},
                               lambda: obs.spin(seconds))
        loops = list(obs.diags)
        if hardware == 'topics':
            transport = obs.command_transport()
    finally:
        obs.close()
        for n in reversed(nodes):
            n.stop()
    if not loops:
        return {'error': 'no diagnostics'}
    return _loop_figures(loops, rate, cpu, wall, transport)


def _loop_figures(loops: list[dict], rate: float, cpu: float, wall: float,
                  transport: list[float]) -> dict:
    """bench_dds's figures: the medians of the loop's /diagnostics entries, the controller's
    CPU (`cpu` s in `wall` s) and the command transport."""
    def f(k):
        return statistics.median(float(d[k]) for d in loops if k in d)
    ticks = f('rate_hz') * wall
    return {
        'rate_hz': f('rate_hz'), 'rate_pct': 100 * f('rate_hz') / rate,
        'jitter_p50_us': f('jitter_p50_us'), 'jitter_p99_us': f('jitter_p99_us'),
        'jitter_max_us': max(float(d['jitter_max_us']) for d in loops),
        'work_us': f('tick_work_mean_us'),
        'cpu_us_per_tick': cpu / ticks * 1e6 if ticks else float('nan'),
        'cpu_pct': 100 * cpu / wall,
        'feedback_age_p50_us': f('feedback_age_p50_us') if 'feedback_age_p50_us' in loops[0]
        else float('nan'),
        'feedback_age_p99_us': f('feedback_age_p99_us') if 'feedback_age_p99_us' in loops[0]
        else float('nan'),
        'command_transport_p50_us': _pct(transport, 50) * 1e6,
        'command_transport_p99_us': _pct(transport, 99) * 1e6,
    }


# -- canopen -------------------------------------------------------------------------------------
def bench_canopen(n_axes: int, seconds: float = 5.0) -> dict:
    """`hardware: canopen` against `virtual_drive` (processes.start_canopen, inside
    private_network) at the highest rate 1 Mbit/s carries for `n_axes` drives (node ids 1, 2,
    ...; one axis: its load encoder a CiA 406 node, as the headline; two: each drive's 60E4h)."""
    axes = _axis_names(n_axes)
    encoders = [5] if n_axes == 1 else [0] * n_axes
    frames = cycle_frames(encoders)
    rate = busload.max_rate(CAN_BUS['can_bitrate'], frames)
    ids = {f'{a}.can_node_id': i + 1 for i, a in enumerate(axes)} | {
        f'{a}.load_encoder_node_id': e for a, e in zip(axes, encoders)}
    axes_param = '[' + ','.join(axes) + ']'
    drive, controller = start_canopen({'axes': axes_param, 'servo_rate': rate} | ids,
                                      {'axes': axes_param} | ids, params_files=False)
    obs = _Observer(lambda d: 'can_cycles' in d)
    diags = obs.diags
    try:
        if not obs.came_up(40.0):
            return {'error': 'nodes did not come up', 'rate': rate}
        diags.clear()
        pids = {controller.proc.pid, controller.servo_pid(), drive.proc.pid, drive.servo_pid()}
        cpu, wall = _cpu_while(pids, lambda: obs.spin(seconds + 1.0,
                                                      until=lambda: len(diags) >= seconds + 1))
    finally:
        obs.close()
        for n in (controller, drive):
            n.stop()
    if len(diags) < 2:
        return {'error': 'no diagnostics', 'rate': rate}
    loops = diags[1:]            # each a window of one second

    def f(k):
        return statistics.median(d[k] for d in loops if k in d)
    cycles = diags[-1]['can_cycles'] - diags[0]['can_cycles']
    missed = diags[-1]['can_missed_cycles'] - diags[0]['can_missed_cycles']
    return {
        'rate': rate, 'frames': frames, 'load_pct': f('can_bus_load_pct'),
        # (the loop counts its time in SYNCs: the wall clock says how many went out)
        'achieved_hz': cycles / (diags[-1]['received'] - diags[0]['received']),
        'tpdo_p50_us': f('can_sync_to_tpdo_p50_us'), 'tpdo_p99_us': f('can_sync_to_tpdo_p99_us'),
        'rpdo_p50_us': f('can_sync_to_rpdo_p50_us'), 'rpdo_p99_us': f('can_sync_to_rpdo_p99_us'),
        'interval_p99_us': f('can_sync_interval_p99_us'),
        'interval_max_us': max(d.get('can_sync_interval_max_us', 0.0) for d in loops),
        'missed_pct': 100 * missed / cycles if cycles else float('nan'),
        'cpu_pct': 100 * cpu / wall,
    }
