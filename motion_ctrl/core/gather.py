"""A test signal injected into one axis's servo output, and the per-tick record of what it did.

PMAC's gather (I5049, DEFINE GATHER / GATHER): the servo interrupt stores chosen registers every
servo cycle into a buffer, so a tuning tool reads back every sample, not what a slower link
happened to deliver; Kollmorgen WorkBench's Bode tool adds its excitation (PRBS, sine sweep) to
the servo output in closed loop the same way. Here `Gather` adds `excitation.at(k)` volts to the
servo law's output on servo tick k (tick-exact: one value per tick, the motion_ctrl.core.excitation
signals) and records, per tick: the excitation, the total output, both encoders' positions and
the commanded position: the closed-loop records identify.frequency_response wants (the
excitation is the instrument: G = S_ry / S_ru).

Safety, as for a move: the axis starts one only enabled and at rest (Axis.excite); a STOP,
ESTOP, ABORT, disable, fault or a new move ends it (the record says why), and so does the slide
leaving `budget` metres around where it started. Plain Python/numpy, no ROS.
"""
from __future__ import annotations

import numpy as np

from motion_ctrl.core.excitation import Excitation

# The records, one column each, in this order.
COLUMNS = ('excitation', 'output', 'motor', 'load', 'command')


class Gather:
    """One excitation run on one axis. `inject(servo_volts, axis)` each tick while `running`."""

    def __init__(self, excitation: Excitation, budget: float, start_load: float,
                 output_limit: float):
        self.excitation = excitation
        self.budget = float(budget)
        self.start_load = float(start_load)
        self.output_limit = float(output_limit)
        self.records = np.full((excitation.ticks, len(COLUMNS)), np.nan)
        self.tick = 0
        self.ended: str | None = None      # 'done', or why it was cut short

    @property
    def running(self) -> bool:
        return self.ended is None

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
        if abs(axis.load_pos - self.start_load) > self.budget:
            self.ended = (f'the slide left its travel budget of {self.budget * 1e3:g} mm '
                          f'after {k} of {self.excitation.ticks} ticks')
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
