"""A test signal injected into one axis's servo output, and the per-tick record of what it did.

PMAC's gather (I5049, DEFINE GATHER / GATHER): the servo interrupt stores chosen registers every
servo cycle into a buffer, so a tuning tool reads back every sample, not what a slower link
happened to deliver; Kollmorgen WorkBench's Bode tool adds its excitation (PRBS, sine sweep) to
the servo output in closed loop the same way. Here `Gather` adds `excitation.at(k)` volts to the
servo law's output on servo tick k (tick-exact: one value per tick, the motion_ctrl.core.excitation
signals) and records, per tick: the excitation, the total output, both encoders' positions and
the commanded position: the closed-loop records identify.frequency_response wants (the
excitation is the instrument: G = S_ry / S_ru).

Optionally on a base motion (Beckhoff TwinCAT's autotuning): the axis jogs at a slow constant
velocity and the signal starts only once it is MOTION_AT_VELOCITY, so the friction keeps one
sign and the nut stays on one flank of the backlash gap while the response is measured.

Safety, as for a move: the axis starts one only enabled and at rest (Axis.excite); a STOP,
ESTOP, ABORT, disable, fault or a new move ends it (the record says why), and so does the slide
leaving `budget` metres around where it started (with a base motion, `reserve` — its braking
distance — is kept in hand, so the slide stops inside the budget). Plain Python/numpy, no ROS.
"""
from __future__ import annotations

from typing import Final

import math

import numpy as np

from motion_ctrl.core.excitation import Excitation
from motion_ctrl.core.soft_limits import stopping_distance

# The records, one column each, in this order.
COLUMNS: Final = ('excitation', 'output', 'motor', 'load', 'command')


def base_motion(v: float, seconds: float, budget: float, start: float,
                soft_limits: tuple[float, float], max_velocity: float, max_acceleration: float,
                max_jerk: float, servo_period: float) -> tuple[float, str | None]:
    """A base motion at `v` [m/s] under a run of `seconds` (Beckhoff TwinCAT: a slow constant
    velocity keeps stiction and the backlash gap out of the measurement): the travel to keep
    in hand for braking (at max_acceleration, plus two ticks, as the jog's limit guard), and
    why it cannot run, or None. Its nominal travel, both ramps and the run, must fit in the
    budget and in the soft limits from `start`."""
    if not v:
        return 0.0, None
    if abs(v) > max_velocity:
        return 0.0, f'base velocity {v:g} m/s is above max_velocity {max_velocity:g} m/s'
    reserve = (stopping_distance(abs(v), 0.0, max_acceleration, max_jerk)
               + 2.0 * abs(v) * servo_period)
    travel = 2.0 * reserve + abs(v) * seconds
    if travel > budget:
        return reserve, (f'the base motion at {v:g} m/s travels {travel * 1e3:.4g} mm with its '
                         f'ramps over {seconds:g} s, more than the travel budget '
                         f'{budget * 1e3:g} mm')
    end = start + math.copysign(travel, v)
    lo, hi = soft_limits
    if not lo <= end <= hi:
        return reserve, (f'the base motion would reach {end:g} m, outside the soft limits '
                         f'[{lo:g}, {hi:g}]')
    return reserve, None


class Gather:
    """One excitation run on one axis. `inject(servo_volts, axis)` each tick while `running`."""

    def __init__(self, excitation: Excitation, budget: float, start_load: float,
                 output_limit: float, base_velocity: float = 0.0, reserve: float = 0.0):
        self.excitation = excitation
        self.budget = float(budget)
        self.start_load = float(start_load)
        self.output_limit = float(output_limit)
        self.base_velocity = float(base_velocity)
        self.reserve = float(reserve)
        # With a base motion the signal waits until the axis runs at its velocity (begin()).
        self.waiting = self.base_velocity != 0.0
        self.records = np.full((excitation.ticks, len(COLUMNS)), np.nan)
        self.tick = 0
        self.ended: str | None = None      # 'done', or why it was cut short

    @property
    def running(self) -> bool:
        return self.ended is None

    def begin(self) -> None:
        """The base motion runs at its velocity: the signal starts at this tick."""
        self.waiting = False

    def end(self, why: str) -> None:
        if self.ended is None:
            self.ended = why

    def inject(self, servo_volts: float, axis) -> float:
        """This tick's output with the excitation added (within ±output_limit), recorded;
        the servo law's own output once the run has ended."""
        if self.ended is not None:
            return servo_volts
        k = self.tick
        if k >= self.excitation.ticks:
            self.ended = 'done'
            return servo_volts
        if abs(axis.load_pos - self.start_load) + self.reserve > self.budget:
            brake = (f' (less {self.reserve * 1e3:.3g} mm to brake)' if self.reserve else '')
            self.ended = (f'the slide left its travel budget of {self.budget * 1e3:g} mm'
                          f'{brake} after {k} of {self.excitation.ticks} ticks')
            return servo_volts
        if self.waiting:
            return servo_volts
        e = self.excitation.at(k)
        limit = self.output_limit
        volts = min(max(servo_volts + e, -limit), limit)
        self.records[k] = (e, volts, axis.motor_pos, axis.load_pos, axis.command_position)
        self.tick = k + 1
        return volts

    def columns(self) -> dict[str, np.ndarray]:
        """The records so far, by name (only the ticks that ran)."""
        rows = self.records[:self.tick]
        return {name: rows[:, j] for j, name in enumerate(COLUMNS)}
