"""Galil's tuning procedure for the dual loop, run on the simulated slide.

DMC-40x0 manual (seed 001): "start with KP = 0, KI = 0 and maximize the value of KD under the
condition DV1. Once KD is found, increase KP gradually to a maximum value, and finally, increase
KI, if necessary." Done here as an engineer would at the machine, with the harness standing in
for it (one servo tick of transport delay, as over DDS):

1. Feedforward from an open-loop identification: a 1 V pulse gives the acceleration per volt
   (kaff = 1/that) and two constant-velocity jogs the velocity-proportional friction (kvff = kd +
   its slope, PMAC form: the Kd term acts on actual velocity, kvff cancels it on a move).
2. KD: with KP = KI = 0, raise KD by factors of √2 until a velocity kick leaves a sustained
   oscillation of the motor (more than 3 counts peak to peak 0.2 s later: a dither of a count is
   velocity quantisation, not instability); keep half the largest stable KD (6 dB margin).
3. KP: raise KP until a 10-count step rings (the motor still moving more than 3 counts
   0.4 s after the step) or overshoots by more than 25 %; keep half.
4. KI: raise KI until the step overshoots by more than 25 % or ends in a limit cycle (the
   slide crossing the target more than once in the last 0.4 s); keep half.

`python -m motion_ctrl.tools.tuning` prints the result as `ros2 param load` YAML; the defaults in
registers.py are its output for the default slide.
"""
from __future__ import annotations

import argparse
import math
import sys

import numpy as np

from motion_ctrl.sim.harness import Harness
from motion_ctrl.sim.plant import SlidePlant

STEP = 25.4e-6        # 10 linear counts
LATENCY_TICKS = 1     # encoder -> command over DDS


def _harness(gains: dict, plant: dict | None, **extra) -> Harness:
    regs = dict(feedback='dual', following_error_fatal=0.0, following_error_warning=0.0,
                max_velocity=1.0, max_acceleration=100.0) | gains | extra
    return Harness(regs, plant, latency_ticks=LATENCY_TICKS)


def identify(plant: dict | None = None) -> dict:
    """Open loop on the machine: acceleration per volt and viscous slope [V per m/s].

    Two drive levels cancel the Coulomb friction: a(V) = (gain·V − friction)/M is linear in V,
    and so is the steady speed under viscous friction.
    """
    free = (plant or {}) | dict(travel_min=-1e3, travel_max=1e3)   # room for the jogs

    def accel(volts):
        p = SlidePlant(**free)
        for _ in range(10):                    # break away
            p.step(volts, 1e-3)
        v0 = p.v_m
        for _ in range(20):
            p.step(volts, 1e-3)
        return (p.v_m - v0) / 0.02

    def speed(volts):
        p = SlidePlant(**free)
        for _ in range(4000):
            p.step(volts, 1e-3)
        return p.v_m

    per_volt = (accel(4.0) - accel(2.0)) / 2.0
    slope = (2.0 - 1.0) / (speed(2.0) - speed(1.0))
    return {'accel_per_volt': per_volt, 'viscous_v_per_mps': slope}


def kd_stable(kd: float, plant=None) -> bool:
    h = _harness(dict(kp=0.0, ki=0.0, kd=kd, kvff=0.0, kaff=0.0), plant)
    h.plant.v_m = h.plant.v_l = 0.005           # a kick: 5 mm/s
    h.run(0.4)
    assert h.trace is not None
    # Unstable: the motor still oscillating 0.2 s later by more than the dither of a count or
    # two that velocity quantisation alone causes.
    motor = np.array(h.trace.motor[200:]) * h.plant.motor_counts_per_m
    return motor.max() - motor.min() <= 3.0


def step_response(gains: dict, plant=None, seconds=0.8):
    """A 10-count step: overshoot [fraction of the step]; how much the motor still moves in the
    last 0.2 s [motor counts p-p] (ringing); how often the slide crosses the target in the last
    0.4 s (a limit cycle)."""
    h = _harness(gains, plant, integration_mode='always')
    h.run(0.05)
    h.axis.move_to(STEP)
    h.run(seconds)
    assert h.trace is not None
    load = np.array(h.trace.load[50:])
    overshoot = max(0.0, (load.max() - STEP) / STEP)
    motor = np.array(h.trace.motor[-200:]) * h.plant.motor_counts_per_m
    side = np.sign(np.array(h.trace.load[-400:]) - STEP)
    crossings = int(np.count_nonzero(np.diff(side[side != 0])))
    return overshoot, float(motor.max() - motor.min()), crossings


def _raise_until(ok, start: float, limit: float) -> float:
    """Largest gain on a √2 ladder from `start` for which ok(gain) holds (0 if none)."""
    g, best = start, 0.0
    while g <= limit and ok(g):
        best = g
        g *= math.sqrt(2.0)
    return best


def tune(plant: dict | None = None, log=print) -> dict:
    ident = identify(plant)
    kaff = 1.0 / ident['accel_per_volt']
    log(f'identified: {ident["accel_per_volt"]:.3f} m/s² per V -> kaff {kaff:.4f} V·s²/m; '
        f'viscous {ident["viscous_v_per_mps"]:.3f} V per m/s')
    kd_max = _raise_until(lambda g: kd_stable(g, plant), 10.0, 1e5)
    kd = kd_max / 2
    log(f'KD: largest stable {kd_max:.1f} V·s/m -> KD = {kd:.1f}')

    def kp_ok(kp):
        ov, late, _ = step_response(dict(kp=kp, ki=0.0, kd=kd, kvff=kd, kaff=kaff), plant)
        return late <= 3.0 and ov < 0.25
    kp_max = _raise_until(kp_ok, 500.0, 1e7)
    kp = kp_max / 2
    log(f'KP: largest without ringing or >25 % overshoot {kp_max:.0f} V/m -> KP = {kp:.0f}')

    def ki_ok(ki):
        ov, _, crossings = step_response(dict(kp=kp, ki=ki, kd=kd, kvff=kd, kaff=kaff), plant)
        return crossings <= 1 and ov < 0.25
    ki_max = _raise_until(ki_ok, 1000.0, 1e9)
    ki = ki_max / 2
    log(f'KI: largest without >25 % overshoot or a limit cycle {ki_max:.0f} V/(m·s) -> '
        f'KI = {ki:.0f}')
    kvff = kd + ident['viscous_v_per_mps']
    return dict(kp=round(kp, 1), ki=round(ki, 1), kd=round(kd, 2), kvff=round(kvff, 2),
                kaff=round(kaff, 4))


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument('--axis', default='x')
    a = ap.parse_args(argv)
    gains = tune(log=lambda s: print('# ' + s))
    print('controller:\n  ros__parameters:')
    for k, v in gains.items():
        print(f'    {a.axis}.{k}: {float(v)!r}')
    return 0


if __name__ == '__main__':
    sys.exit(main())
