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

Speed is measured here, never asserted in a test. The measurements are
motion_ctrl.procedures.benchmarks; here the command line and its tables.
"""
from __future__ import annotations

import argparse
import math
import os
import platform
import sys

import rclpy

from motion_ctrl.procedures.benchmarks import (bench_canopen, bench_core, bench_dds,
                                               bench_harness, bench_rclpy_floor,
                                               bench_sleep_floor, built)
from motion_ctrl.ros import ros_env
from motion_ctrl.ros.lockstep import bench_lockstep
from motion_ctrl.ros.processes import PRIVATE_NET, private_network

ROS_SECTIONS = ('floor', 'dds', 'lockstep', 'canopen')


def parser() -> argparse.ArgumentParser:
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
    return ap


def main(argv=None) -> int:
    """Parse, rerun inside a private network for canopen, print each section's table."""
    a = parser().parse_args(argv)
    sections = a.sections.split(',')
    if 'canopen' in sections and not os.environ.get(PRIVATE_NET):
        # (udp_multicast stays inside a network namespace of its own: run there, all of it)
        args = sys.argv[1:] if argv is None else list(argv)
        command = private_network([sys.executable, '-m', 'motion_ctrl.tools.benchmark', *args])
        os.execvp(command[0], command)
    print(f'motion_ctrl benchmark — {platform.processor() or platform.machine()}, '
          f'{os.cpu_count()} CPUs, Python {platform.python_version()}, {platform.system()} '
          f'{platform.release()}')
    if 'core' in sections:
        report_core()
    ros = [s for s in sections if s in ROS_SECTIONS]
    if ros:
        ros_env.private_domain()
        rclpy.init()
    if 'floor' in sections:
        report_floor()
    hardwares = a.hardware.split(',')
    if 'dds' in sections:
        report_dds(a.rates, a.axes, hardwares, a.seconds, a.moving)
    if 'lockstep' in sections:
        print('\n## lockstep (one axis, the 1-inch move; sim: sim_speed 0, unbounded)\n')
        for hw in hardwares:
            speed = bench_lockstep(hw)
            print(f'{hw}: sim seconds per wall second: {speed:.2f}', flush=True)
    if 'canopen' in sections:
        report_canopen(a.seconds)
    if ros:
        rclpy.try_shutdown()
    return 0


def report_core() -> None:
    """The core section: µs per servo tick of the core, and the in-process harness."""
    print(f'\n## core (per servo tick, one axis, no ROS; servo tick and plant {built()})\n')
    print('| what | µs per tick |\n|---|---:|')
    for name, us in bench_core():
        print(f'| {name} | {us:.1f} |')
    print('\n| in-process harness (2.08 s of sim time; 7 runs) | µs per tick best | median '
          '| × real time (median) |\n|---|---:|---:|---:|')
    for name, best, med, speed in bench_harness():
        x = '' if math.isnan(speed) else f'{speed:.0f}'
        print(f'| {name} | {best:.1f} | {med:.1f} | {x} |')


def report_floor() -> None:
    """The floor section: a sleep loop's and an rclpy timer's jitter at 1 and 2 kHz."""
    print('\n## floor (the machine: period jitter of loops that do nothing)\n')
    print('| loop | rate [Hz] | jitter p50 [µs] | p99 [µs] | max [µs] |\n'
          '|---|---:|---:|---:|---:|')
    for rate in (1000.0, 2000.0):
        for name, fn in (('time.sleep loop', bench_sleep_floor),
                         ('rclpy timer, EventsExecutor', bench_rclpy_floor)):
            r = fn(rate)
            print(f'| {name} @ {rate:g} Hz | {r["rate_hz"]:.1f} | {r["jitter_p50_us"]:.0f} | '
                  f'{r["jitter_p99_us"]:.0f} | {r["jitter_max_us"]:.0f} |')


def report_dds(rates: str, axis_counts: str, hardwares: list[str], seconds: float,
               moving: bool) -> None:
    """The dds section: a row per servo rate and axis count (--rates, --axes) and hardware,
    each printed as it is measured."""
    print('\n## dds (the controller in real time; topics: plant + controller as two processes, '
          f'sim: the controller alone; axes {"jogging" if moving else "at rest"})\n')
    print('| hardware | servo rate | axes | achieved [Hz] | % of nominal | jitter p50 / p99 / '
          'max [µs] | work per tick [µs] | controller CPU per tick [µs] (CPU %) | '
          'encoder → tick p50 / p99 [µs] | command → plant p50 / p99 [µs] |'
          '\n|---|---:|---:|---:|---:|---|---:|---|---|---|')
    for rate in (float(x) for x in rates.split(',')):
        for n in (int(x) for x in axis_counts.split(',')):
            for hw in hardwares:
                print(dds_row(hw, rate, n, bench_dds(rate, n, seconds, hw, moving)), flush=True)


def dds_row(hw: str, rate: float, n: int, r: dict) -> str:
    """One row of the dds table: bench_dds's figures `r`, or its error."""
    if 'error' in r:
        return f'| {hw} | {rate:g} | {n} | {r["error"]} | | | | | | |'
    transport = (f'{r["command_transport_p50_us"]:.0f} / '
                 f'{r["command_transport_p99_us"]:.0f}' if hw == 'topics'
                 else '(in the loop)')
    age = (f'{r["feedback_age_p50_us"]:.0f} / {r["feedback_age_p99_us"]:.0f}'
           if math.isfinite(r['feedback_age_p50_us']) else '')
    return (f'| {hw} | {rate:g} | {n} | {r["rate_hz"]:.1f} | {r["rate_pct"]:.1f} | '
            f'{r["jitter_p50_us"]:.0f} / {r["jitter_p99_us"]:.0f} / '
            f'{r["jitter_max_us"]:.0f} | {r["work_us"]:.0f} | '
            f'{r["cpu_us_per_tick"]:.0f} ({r["cpu_pct"]:.0f} %) | {age} | '
            f'{transport} |')


def report_canopen(seconds: float) -> None:
    """The canopen section: one axis and two on one bus against virtual_drive."""
    print('\n## canopen (controller + virtual_drive, udp_multicast in a private network '
          'namespace, 1 Mbit/s)\n')
    print('| axes | servo rate [Hz] (bus load) | achieved [Hz] | SYNC → TPDO p50 / p99 [µs] '
          '| SYNC → RPDO p50 / p99 [µs] | SYNC period p99 / max [µs] | cycles missing a '
          'sample | CPU both nodes |\n|---:|---|---:|---|---|---|---:|---:|')
    for n in (1, 2):
        r = bench_canopen(n, seconds)
        if 'error' in r:
            print(f'| {n} | {r["rate"]:.0f} | {r["error"]} | | | | | |')
            continue
        print(f'| {n} | {r["rate"]:.0f} ({r["load_pct"]:.0f} %) | {r["achieved_hz"]:.0f} | '
              f'{r["tpdo_p50_us"]:.0f} / {r["tpdo_p99_us"]:.0f} | {r["rpdo_p50_us"]:.0f} / '
              f'{r["rpdo_p99_us"]:.0f} | {r["interval_p99_us"]:.0f} / '
              f'{r["interval_max_us"]:.0f} | {r["missed_pct"]:.2f} % | '
              f'{r["cpu_pct"]:.0f} % |')


if __name__ == '__main__':
    sys.exit(main())
