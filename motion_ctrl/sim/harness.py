"""In-process harness: controller axis cores coupled to plant cores, stepped in lockstep.

Each servo tick is the controller's servo cycle (`ServoLoop.cycle`, the same object the controller
node drives, in its sim-time form) on the `sim` hardware (motion_ctrl.sim.hardware, the same
backend as the node's `hardware: sim`): it reads the plant's encoders, computes the command, and
the plant integrates one servo period with that command held (zero-order hold, like a DAC). An
optional transport delay of whole ticks models the encoder → command path over DDS. No ROS, no
clocks: a scenario is deterministic and runs many times faster than real time. Several axes
(`axes=('x', 'y')`: a slide each, the same registers) run on the one ServoLoop, as the node's do;
`axis`, `plant` and the trace are the first one's.
"""
from __future__ import annotations

from typing import Final

from dataclasses import dataclass, field

from msg_defs.status import Status
from motion_ctrl.core.axis import Axis
from motion_ctrl.sim.hardware import SimHardware
from motion_ctrl.core.registers import CONTROLLER_GLOBAL
from motion_ctrl.core.servo_loop import ServoLoop

_DONE: Final = int(Status.MOTION_DONE)


@dataclass
class Trace:
    """Per-tick record of a run (lists of floats / ints)."""
    t: list = field(default_factory=list)
    command: list = field(default_factory=list)      # commanded position [m] (user frame)
    actual: list = field(default_factory=list)       # the axis' actual position [m]
    motor: list = field(default_factory=list)        # true motor position [m]
    load: list = field(default_factory=list)         # true slide position [m]
    output: list = field(default_factory=list)       # command [V]
    status: list = field(default_factory=list)       # status word
    following_error: list = field(default_factory=list)  # [m]


class Harness:
    """A controller's servo loop on simulated slides, stepped tick by tick (see the module
    docstring); the loops are closed at the slides' start before the first tick.

    Parameters
    ----------
    registers : dict, optional
        Axis registers over the table's defaults (AXIS_REGISTERS, SI units), for every axis.
    plant : dict, optional
        Plant registers over the table's defaults (PLANT_PARAMETERS, SI units), every slide.
    servo_period : float
        The servo period [s].
    latency_ticks : int
        Transport delay of the outputs [whole ticks] (encoder → command over DDS).
    record : bool
        Keep a per-tick `trace` (Trace) of the first axis.
    axes : tuple of str
        The axes' names, a slide each; `axis`, `plant` and the trace are the first's.
    """

    def __init__(self, registers: dict | None = None, plant: dict | None = None,
                 servo_period: float = 1e-3, latency_ticks: int = 0, record: bool = True,
                 axes=('x',)):
        self.T = servo_period
        self.axes = {a: Axis(a, registers, servo_period, record_events=True) for a in axes}
        self.hardware = SimHardware(axes, servo_period, {a: dict(plant or {}) for a in axes},
                                    latency_ticks=latency_ticks)
        self.hardware.activate()
        self.loop = ServoLoop(self.axes, {a: x.r for a, x in self.axes.items()}, servo_period,
                              float(CONTROLLER_GLOBAL['feedback_timeout'].default),  # type: ignore[arg-type]
                              sim_time=True, hardware=self.hardware)
        self.plants = self.hardware.plants
        self.axis, self.plant = self.axes[axes[0]], self.plants[axes[0]]
        self.trace = Trace() if record else None
        self.ticks = 0
        for a, x in self.axes.items():
            x.home(*self.plants[a].encoder_counts())

    @property
    def time(self) -> float:
        """The simulation's time [s]: ticks run × servo period."""
        return self.ticks * self.T

    def tick(self, disturbance=None) -> None:
        """One servo cycle (ServoLoop.cycle on the sim hardware), recorded in `trace`.

        Parameters
        ----------
        disturbance : callable, optional
            `disturbance(harness)`, run after the cycle (a push on the slide, a register
            change, a fault injected).
        """
        tick = self.loop.cycle(self.ticks * self.T)
        self.ticks += 1
        if disturbance:
            disturbance(self)
        tr = self.trace
        if tr is not None:
            a = self.axis
            tr.t.append(self.time)
            tr.command.append(a.command_position)
            tr.actual.append(a.actual_pos)
            tr.motor.append(self.plant.x_m)
            tr.load.append(self.plant.x_l)
            io = self.hardware.io[a.name]
            tr.output.append(io.output if tick is not None and io.commanded else 0.0)
            tr.status.append(a.word)
            tr.following_error.append(a.following_error)

    def run(self, seconds: float, until=None, disturbance=None) -> bool:
        """Run for `seconds`, or until `until(harness)` is true; returns whether it became true.
        `disturbance(harness)`, if given, runs after every tick (as in `tick`).

        Parameters
        ----------
        seconds : float
            How long to run [s] (rounded to whole servo periods).
        until : callable, optional
            `until(harness) -> bool`, tested after each tick.
        disturbance : callable, optional
            As `tick`'s.

        Returns
        -------
        bool
            `until` became true (False without one).
        """
        n = round(seconds / self.T)
        for _ in range(n):
            self.tick(disturbance)
            if until is not None and until(self):
                return True
        return False

    def move(self, target: float, timeout: float = 3.0):
        """Command a move and run until MOTION_DONE; returns seconds to MOTION_DONE or None.

        Parameters
        ----------
        target : float
            The first axis's target in its user frame [m] (Axis.move_to).
        timeout : float
            Servo time to wait for MOTION_DONE [s].

        Returns
        -------
        float or None
            Servo time from the command to MOTION_DONE [s]; None when the timeout passed.

        Raises
        ------
        ValueError
            The move was refused (its reason).
        """
        ok, reason = self.axis.move_to(target)
        if not ok:
            raise ValueError(reason)
        start = self.time
        self.tick()   # the move starts on this tick; MOTION_DONE of the last move is cleared
        done = self.run(timeout, until=lambda h: h.axis.word & _DONE)
        return self.time - start if done else None

    def load_error_counts(self, target: float) -> float:
        """True slide error from `target` in linear encoder counts.

        Parameters
        ----------
        target : float
            [m].

        Returns
        -------
        float
            (slide position − target) × load_counts_per_m [counts], unquantised.
        """
        return (self.plant.x_l - target) * self.plant.load_counts_per_m
