"""Benchmark: what a servo tick costs and how well the loop holds its rate, measured here.

Sections (each prints a small table; paste the output into doc/performance.md with
the date, the commit and the machine):

* core   — cost per servo tick of the ROS-free core: Profile.step + Settling.update, and a
           whole Axis.update at rest and moving (in-process, no DDS); the in-process harness
           (one axis + plant: a 1-inch move and back) in × real time, and the plant's step alone.
* floor  — period jitter of a bare Python sleep loop and of a bare rclpy timer doing nothing
           (the machine's floor: the VM's scheduler sets it, not this code).
* dds    — the controller in real time at 1 kHz and 2 kHz for 1, 6, 64 and 256 axes, for each
           `hardware`: topics (plant and controller as two processes over DDS) and sim (the
           controller alone, the slides in its loop): achieved servo rate, period jitter
           p50/p99/max and work per tick (from the controller's /diagnostics), controller CPU
           per tick (/proc: its loop process and its bridge), feedback age at the tick (encoder
           stamp -> use) and, over topics, command transport (command stamp -> arrival at a
           reader in a third process, as the plant receives it).
* lockstep — sim seconds per wall second of the deterministic lockstep simulation, one axis:
           plant and controller (topics) and the controller alone (sim).
* canopen — `hardware: canopen` against `virtual_drive` in another process on udp_multicast (in
           a private network namespace: the benchmark runs itself again inside one), one axis
           and two on one bus, each at the highest rate 1 Mbit/s carries: the bus load, SYNC ->
           TPDO (the drive's answer) and SYNC -> RPDO (the loop's delay) p50 / p99, the SYNC
           period's p99 / max and the cycles whose samples had not all come, from the
           controller's /diagnostics; CPU of both.

Speed is measured here, never asserted in a test.
"""
from __future__ import annotations

import argparse
import math
import os
import platform
import statistics
import sys
import time

import numpy as np


def _pct(values, q):
    return float(np.percentile(np.asarray(values), q)) if len(values) else float('nan')


# -- core ----------------------------------------------------------------------------------------
def bench_core(n: int = 20000) -> list[tuple[str, float]]:
    from motion_ctrl.core.axis import Axis
    from motion_ctrl.core.profile import Profile
    from motion_ctrl.core.registers import axis_defaults
    from motion_ctrl.core.config import ProfileConfig, SettlingConfig
    from motion_ctrl.core.settling import Settling
    r = axis_defaults()
    rows = []

    def per_tick(fn, count=n):
        t = time.perf_counter()
        for i in range(count):
            fn(i)
        return (time.perf_counter() - t) / count * 1e6

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
    rows.append(('Profile.step + Settling.update (jerk-limited, IT smoothing, moving)',
                 per_tick(profile_settling)))

    a = Axis('x', r)
    a.home(0, 0)
    rows.append(('Axis.update at rest', per_tick(lambda i: a.update(1e-3, 0, 0))))
    b = Axis('x', r)
    b.home(0, 0)

    def moving(i):
        if i % 1000 == 0:
            b.move_to(0.0254 if (i // 1000) % 2 == 0 else 0.0)
        pos = b.profile.position
        b.update(1e-3, int(pos * r['motor_counts_per_m']), int(pos * r['load_counts_per_m']))
    rows.append(('Axis.update moving (servo law, profile, settling, status)', per_tick(moving)))

    # Two axes following a two-axis trajectory (PVT, quintic): the circle of the draw example;
    # the polynomials are evaluated once per tick for both (Trajectory.paths).
    from motion_ctrl.core import trajectory as tj
    limits = {n: tj.AxisLimits.from_registers(r) for n in 'xy'}
    circle = tj.circle((-0.01, 0.0), 0.01, 0.02)
    traj = tj.Trajectory.from_points(['x', 'y'], circle, start={'x': (0.0, 0.0, 0.0),
                                                                 'y': (0.0, 0.0, 0.0)},
                                     limits=limits)
    axes = {n: Axis(n, r) for n in 'xy'}
    for ax in axes.values():
        ax.home(0, 0)

    def following(i):
        if i % 4000 == 0:      # the circle lasts 3.64 s: start it again from its end, at rest
            paths = traj.paths()
            for n, ax in axes.items():
                ax.profile.hold(0.0)
                ok, why = ax.follow(paths[n])
                assert ok, why
        for ax in axes.values():
            pos = ax.profile.position
            ax.update(1e-3, int(pos * r['motor_counts_per_m']),
                      int(pos * r['load_counts_per_m']))
    rows.append(('2 axes following a 2-axis trajectory (PVT, quintic): both Axis.update',
                 per_tick(following)))
    # What Trajectory.paths saves: the same state from scipy's BPoly calls (p, v, a).
    shared = traj.paths()['x']
    rows.append(('  of which the trajectory state for both axes (Trajectory.paths)',
                 per_tick(lambda i: shared.at((i % 3000 + 0.5) * 1e-3))))
    rows.append(('  the same from scipy (Trajectory.sample: BPoly p, v, a)',
                 per_tick(lambda i: traj.sample((i % 3000 + 0.5) * 1e-3), n // 4)))
    return rows


def bench_harness(repeats: int = 7) -> list[tuple[str, float, float, float]]:
    """The in-process harness (one axis + plant) making the 1-inch move and back (2.08 s of sim
    time), and the plant's step alone replaying that run's commands: (what, µs per 1 ms tick
    best and median of `repeats`, × real time at the median, nan for the plant alone)."""
    from motion_ctrl.core.registers import INCH
    from motion_ctrl.sim.harness import Harness
    from motion_ctrl.sim.plant import SlidePlant
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
def bench_sleep_floor(rate: float, seconds: float = 3.0) -> dict:
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
    dt = np.diff(stamps)
    jitter = np.abs(dt - period) * 1e6
    return {'rate_hz': len(dt) / dt.sum(), 'jitter_p50_us': _pct(jitter, 50),
            'jitter_p99_us': _pct(jitter, 99), 'jitter_max_us': float(jitter.max())}


def bench_rclpy_floor(rate: float, seconds: float = 3.0) -> dict:
    from rclpy.node import Node
    from rclpy.experimental import EventsExecutor
    node = Node('bench_floor')
    stamps = []
    node.create_timer(1.0 / rate, lambda: stamps.append(time.perf_counter()))
    ex = EventsExecutor()
    ex.add_node(node)
    end = time.perf_counter() + seconds
    while time.perf_counter() < end:
        ex.spin_once(timeout_sec=0.05)
    ex.shutdown()
    node.destroy_node()
    dt = np.diff(np.array(stamps))
    jitter = np.abs(dt - 1.0 / rate) * 1e6
    return {'rate_hz': len(dt) / dt.sum(), 'jitter_p50_us': _pct(jitter, 50),
            'jitter_p99_us': _pct(jitter, 99), 'jitter_max_us': float(jitter.max())}


# -- dds -----------------------------------------------------------------------------------------
def _cpu_seconds(pid: int) -> float:
    with open(f'/proc/{pid}/stat') as f:
        fields = f.read().rsplit(')', 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf('SC_CLK_TCK')


def _value(text: str):
    try:
        return float(text)
    except ValueError:
        return text


class _Observer:
    """The benchmark's own node: it reads only /diagnostics (a third process taking 1 kHz
    streams would load the cores it shares with the nodes measured) and keeps the servo loop's
    entries that `keep` accepts, each with the time it was received."""

    def __init__(self, keep):
        from diagnostic_msgs.msg import DiagnosticArray
        from rclpy.executors import SingleThreadedExecutor
        from rclpy.node import Node

        import msg_defs as md
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

    def close(self) -> None:
        self.node.destroy_node()
        self.executor.shutdown()


def bench_dds(rate: float, n_axes: int, seconds: float = 5.0, hardware: str = 'topics',
              moving: bool = False) -> dict:
    """Loop figures in real time. The observer (this process) reads only /diagnostics while the
    rate is measured: a third process taking 1 kHz streams would load the two cores it shares
    with plant and controller. The command transport (topics) is measured after, in a window of
    its own. `moving`: every axis jogs (at 20 mm/s, half of them negative) while the rate is
    measured, else they rest."""
    from sensor_msgs.msg import JointState

    import msg_defs as md
    from motion_ctrl.ros.processes import start_sim, start_slide

    axes = [f'a{i}' for i in range(n_axes)] if n_axes > 1 else ['x']
    axes_param = '[' + ','.join(axes) + ']'
    # Many axes: integrate the physics at the servo rate only, so the plant keeps up; the
    # controller's loop is what is measured.
    substep = 20000.0 if n_axes <= 6 else rate
    if hardware == 'sim':
        nodes = start_sim({'axes': axes_param, 'servo_rate': float(rate)},
                          {'substep_rate': substep}, params_files=False)
    else:
        nodes = start_slide(
            {'axes': axes_param, 'servo_rate': float(rate)},
            {'axes': axes_param, 'publish_rate': float(rate), 'substep_rate': substep},
            params_files=False)
    controller = nodes[-1]
    obs = _Observer(lambda d: 'rate_hz' in d)
    node, diags, spin = obs.node, obs.diags, obs.spin
    transport: list[float] = []

    def on_command(msg):
        now = node.get_clock().now().nanoseconds * 1e-9
        transport.append(now - (msg.header.stamp.sec + msg.header.stamp.nanosec * 1e-9))

    try:
        # up, and a second of loop behind it (each axis's services take ~0.1 s to make: 35 s
        # for 256 axes here)
        spin(30.0 + 0.2 * n_axes, until=lambda: len(diags) >= 2)
        if len(diags) < 2:
            return {'error': 'nodes did not come up'}
        if moving:
            jog = node.create_publisher(JointState, md.TARGET_VELOCITY, 10)
            spin(5.0, until=lambda: jog.get_subscription_count() > 0)
            spin(0.5)
            jog.publish(md.joint_state(node.get_clock().now().to_msg(), axes,
                                       velocity=[0.02 * (-1) ** i for i in range(len(axes))]))
            spin(0.5)                                     # at speed
        diags.clear()
        # The controller's CPU: its loop process and, on the servo bus (ros.servo_bus), the
        # bridge that started it, together.
        pids = {controller.proc.pid, controller.servo_pid()}
        cpu0, t0 = sum(_cpu_seconds(p) for p in pids), time.monotonic()
        spin(seconds)
        cpu1, t1 = sum(_cpu_seconds(p) for p in pids), time.monotonic()
        loops = list(diags)
        if hardware == 'topics':
            node.create_subscription(JointState, md.COMMAND, on_command, md.SERVO_READ_QOS)
            spin(1.0)                                     # discovery of the new reader
            transport.clear()
            spin(2.0)
    finally:
        obs.close()
        for n in reversed(nodes):
            n.stop()
    if not loops:
        return {'error': 'no diagnostics'}
    def f(k):
        return statistics.median(float(d[k]) for d in loops if k in d)
    ticks = f('rate_hz') * (t1 - t0)
    return {
        'rate_hz': f('rate_hz'), 'rate_pct': 100 * f('rate_hz') / rate,
        'jitter_p50_us': f('jitter_p50_us'), 'jitter_p99_us': f('jitter_p99_us'),
        'jitter_max_us': max(float(d['jitter_max_us']) for d in loops),
        'work_us': f('tick_work_mean_us'),
        'cpu_us_per_tick': (cpu1 - cpu0) / ticks * 1e6 if ticks else float('nan'),
        'cpu_pct': 100 * (cpu1 - cpu0) / (t1 - t0),
        'feedback_age_p50_us': f('feedback_age_p50_us') if 'feedback_age_p50_us' in loops[0]
        else float('nan'),
        'feedback_age_p99_us': f('feedback_age_p99_us') if 'feedback_age_p99_us' in loops[0]
        else float('nan'),
        'command_transport_p50_us': _pct(transport, 50) * 1e6,
        'command_transport_p99_us': _pct(transport, 99) * 1e6,
    }


def bench_canopen(n_axes: int, seconds: float = 5.0) -> dict:
    """`hardware: canopen` against `virtual_drive` (processes.start_canopen, inside
    private_network) at the highest rate 1 Mbit/s carries for `n_axes` drives (node ids 1, 2,
    ...; one axis: its load encoder a CiA 406 node, as the headline; two: each drive's 60E4h)."""
    from motion_ctrl.canopen import busload
    from motion_ctrl.canopen.objects import cycle_frames
    from motion_ctrl.ros.processes import CAN_BUS, start_canopen

    axes = ['x'] if n_axes == 1 else [f'a{i}' for i in range(n_axes)]
    encoders = [5] if n_axes == 1 else [0] * n_axes
    frames = cycle_frames(encoders)
    rate = busload.max_rate(CAN_BUS['can_bitrate'], frames)
    ids = {f'{a}.can_node_id': i + 1 for i, a in enumerate(axes)} | {
        f'{a}.load_encoder_node_id': e for a, e in zip(axes, encoders)}
    axes_param = '[' + ','.join(axes) + ']'
    drive, controller = start_canopen({'axes': axes_param, 'servo_rate': rate} | ids,
                                      {'axes': axes_param} | ids, params_files=False)
    obs = _Observer(lambda d: 'can_cycles' in d)
    diags, spin = obs.diags, obs.spin
    try:
        spin(40.0, until=lambda: len(diags) >= 2)
        if len(diags) < 2:
            return {'error': 'nodes did not come up', 'rate': rate}
        diags.clear()
        pids = {controller.proc.pid, controller.servo_pid(), drive.proc.pid, drive.servo_pid()}
        cpu0, t0 = sum(_cpu_seconds(p) for p in pids), time.monotonic()
        spin(seconds + 1.0, until=lambda: len(diags) >= seconds + 1)
        cpu1, t1 = sum(_cpu_seconds(p) for p in pids), time.monotonic()
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
        'cpu_pct': 100 * (cpu1 - cpu0) / (t1 - t0),
    }


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description='Measure motion_ctrl servo-loop performance.')
    ap.add_argument('--sections', default='core,floor,dds,lockstep,canopen',
                    help='comma-separated subset of core,floor,dds,lockstep,canopen')
    ap.add_argument('--seconds', type=float, default=5.0, help='per DDS measurement')
    ap.add_argument('--rates', default='1000,2000', help='servo rates of the dds section [Hz]')
    ap.add_argument('--axes', default='1,6,64,256', help='axis counts of the dds section')
    ap.add_argument('--hardware', default='topics,sim',
                    help='comma-separated hardware of the dds and lockstep sections')
    ap.add_argument('--moving', action='store_true',
                    help='dds: every axis jogs while the rate is measured (default: at rest)')
    a = ap.parse_args(argv)
    sections = a.sections.split(',')
    from motion_ctrl.ros.processes import PRIVATE_NET, private_network
    if 'canopen' in sections and not os.environ.get(PRIVATE_NET):
        # (udp_multicast stays inside a network namespace of its own: run there, all of it)
        args = sys.argv[1:] if argv is None else list(argv)
        command = private_network([sys.executable, '-m', 'motion_ctrl.tools.benchmark', *args])
        os.execvp(command[0], command)
    print(f'motion_ctrl benchmark — {platform.processor() or platform.machine()}, '
          f'{os.cpu_count()} CPUs, Python {platform.python_version()}, {platform.system()} '
          f'{platform.release()}')
    if 'core' in sections:
        from motion_ctrl.core import axis
        from motion_ctrl.sim import plant
        built = ('compiled by mypyc' if axis.__file__.endswith('.so') and
                 plant.__file__.endswith('.so') else 'plain Python (not compiled)')
        print(f'\n## core (per servo tick, one axis, no ROS; servo tick and plant {built})\n')
        print('| what | µs per tick |\n|---|---:|')
        for name, us in bench_core():
            print(f'| {name} | {us:.1f} |')
        print('\n| in-process harness (2.08 s of sim time; 7 runs) | µs per tick best | median '
              '| × real time (median) |\n|---|---:|---:|---:|')
        for name, best, med, speed in bench_harness():
            x = '' if math.isnan(speed) else f'{speed:.0f}'
            print(f'| {name} | {best:.1f} | {med:.1f} | {x} |')
    ros = [s for s in sections if s in ('floor', 'dds', 'lockstep', 'canopen')]
    if ros:
        from motion_ctrl.ros import ros_env
        ros_env.private_domain()
        import rclpy
        rclpy.init()
    if 'floor' in sections:
        print('\n## floor (the machine: period jitter of loops that do nothing)\n')
        print('| loop | rate [Hz] | jitter p50 [µs] | p99 [µs] | max [µs] |\n'
              '|---|---:|---:|---:|---:|')
        for rate in (1000.0, 2000.0):
            for name, fn in (('time.sleep loop', bench_sleep_floor),
                             ('rclpy timer, EventsExecutor', bench_rclpy_floor)):
                r = fn(rate)
                print(f'| {name} @ {rate:g} Hz | {r["rate_hz"]:.1f} | {r["jitter_p50_us"]:.0f} | '
                      f'{r["jitter_p99_us"]:.0f} | {r["jitter_max_us"]:.0f} |')
    hardwares = a.hardware.split(',')
    if 'dds' in sections:
        print('\n## dds (the controller in real time; topics: plant + controller as two processes, '
              f'sim: the controller alone; axes {"jogging" if a.moving else "at rest"})\n')
        print('| hardware | servo rate | axes | achieved [Hz] | % of nominal | jitter p50 / p99 / '
              'max [µs] | work per tick [µs] | controller CPU per tick [µs] (CPU %) | '
              'encoder → tick p50 / p99 [µs] | command → plant p50 / p99 [µs] |'
              '\n|---|---:|---:|---:|---:|---|---:|---|---|---|')
        for rate in (float(x) for x in a.rates.split(',')):
            for n in (int(x) for x in a.axes.split(',')):
                for hw in hardwares:
                    r = bench_dds(rate, n, a.seconds, hw, a.moving)
                    if 'error' in r:
                        print(f'| {hw} | {rate:g} | {n} | {r["error"]} | | | | | | |')
                        continue
                    transport = (f'{r["command_transport_p50_us"]:.0f} / '
                                 f'{r["command_transport_p99_us"]:.0f}' if hw == 'topics'
                                 else '(in the loop)')
                    age = (f'{r["feedback_age_p50_us"]:.0f} / {r["feedback_age_p99_us"]:.0f}'
                           if math.isfinite(r['feedback_age_p50_us']) else '')
                    print(f'| {hw} | {rate:g} | {n} | {r["rate_hz"]:.1f} | {r["rate_pct"]:.1f} | '
                          f'{r["jitter_p50_us"]:.0f} / {r["jitter_p99_us"]:.0f} / '
                          f'{r["jitter_max_us"]:.0f} | {r["work_us"]:.0f} | '
                          f'{r["cpu_us_per_tick"]:.0f} ({r["cpu_pct"]:.0f} %) | {age} | '
                          f'{transport} |', flush=True)
    if 'lockstep' in sections:
        try:
            from motion_ctrl.ros.lockstep import bench_lockstep
        except ImportError:
            print('\n## lockstep: not available')
        else:
            print('\n## lockstep (one axis, the 1-inch move)\n')
            for hw in hardwares:
                speed = bench_lockstep(hw)
                print(f'{hw}: sim seconds per wall second: {speed:.2f}', flush=True)
    if 'canopen' in sections:
        print('\n## canopen (controller + virtual_drive, udp_multicast in a private network '
              'namespace, 1 Mbit/s)\n')
        print('| axes | servo rate [Hz] (bus load) | achieved [Hz] | SYNC → TPDO p50 / p99 [µs] '
              '| SYNC → RPDO p50 / p99 [µs] | SYNC period p99 / max [µs] | cycles missing a '
              'sample | CPU both nodes |\n|---:|---|---:|---|---|---|---:|---:|')
        for n in (1, 2):
            r = bench_canopen(n, a.seconds)
            if 'error' in r:
                print(f'| {n} | {r["rate"]:.0f} | {r["error"]} | | | | | |')
                continue
            print(f'| {n} | {r["rate"]:.0f} ({r["load_pct"]:.0f} %) | {r["achieved_hz"]:.0f} | '
                  f'{r["tpdo_p50_us"]:.0f} / {r["tpdo_p99_us"]:.0f} | {r["rpdo_p50_us"]:.0f} / '
                  f'{r["rpdo_p99_us"]:.0f} | {r["interval_p99_us"]:.0f} / '
                  f'{r["interval_max_us"]:.0f} | {r["missed_pct"]:.2f} % | '
                  f'{r["cpu_pct"]:.0f} % |')
    if ros:
        rclpy.try_shutdown()
    return 0


if __name__ == '__main__':
    sys.exit(main())
