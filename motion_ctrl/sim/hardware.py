"""`hardware: sim`: the backlash slide's physics (motion_ctrl.sim.plant) stepped inside the servo
loop, one slide per axis, behind the loop's hardware interface (motion_ctrl.core.hardware).

Each tick (`ServoLoop.cycle`):

* `write` commands each slide's amplifier with the tick's output and integrates every slide one
  servo period on it (the DAC's zero-order hold over the coming period); an axis the tick did not
  command gets nothing, and its amplifier's command watchdog runs as the plant node's
  (`SlidePlant.advance`: after `command_timeout` 0 V and the dynamic brake). The amplifier does
  not follow the loop's enable: an open loop commands 0 V, as it does to the plant node;
* `read` takes the encoders of every slide, stamped with the simulation's time. The loop's
  times must lie on its servo grid (the node ticks at whole periods of its clock, as a PMAC's
  servo interrupt does; in sim time they do), so that every period of the loop is one of the
  slides: a tick that comes after skipped ones first integrates the periods it missed on the
  held command (the machine does not stop while the loop is held up), each one a period without
  a command for the amplifier's watchdog, which trips after command_timeout as a drive's does
  when its controller stops sending. A loop whose ticks and slides
  advanced by different times would compare the command of one time with the slide of another
  (tens of counts of following error at speed, a hundred microseconds of jitter apart).

`deactivate` commands 0 V and disables every amplifier: from the next integration on its output
is 0 V with the dynamic brake closed.

An optional transport delay of whole ticks on the outputs (`latency_ticks`) models a command
path over a network (the in-process harness uses it).
"""
from __future__ import annotations

import math
from collections import deque

from motion_ctrl.core.hardware import AxisIO, HardwareError, HardwareInterface
from motion_ctrl.sim.plant import SlidePlant



class SimHardware(HardwareInterface):
    """One SlidePlant per axis, stepped by the servo loop.

    Parameters
    ----------
    axes : iterable of str
        The axes' names: a slide each.
    period : float
        The servo period [s]: each `write` integrates the slides this long.
    plant : dict[str, dict], optional
        Per axis, plant registers over the table's defaults (core.registers PLANT_PARAMETERS,
        SI units), validated at `configure` (HardwareError `sim: <axis>.<reason>`).
    substep_rate : float
        The physics' integration rate [Hz] (SlidePlant).
    latency_ticks : int
        Transport delay of the outputs [whole ticks], 0: none.
    """

    kind = 'sim'

    def __init__(self, axes, period: float, plant: dict[str, dict] | None = None,
                 substep_rate: float = 20000.0, latency_ticks: int = 0) -> None:
        """`plant`: per axis, the plant registers that differ from the table's defaults."""
        super().__init__(axes)
        self.period: float = period
        self.params: dict[str, dict] = {a: dict((plant or {}).get(a, {})) for a in self.axes}
        self.substep_rate: float = substep_rate
        self.latency_ticks: int = latency_ticks
        self.plants: dict[str, SlidePlant] = {}
        self._slides: list[tuple[AxisIO, SlidePlant]] = []
        self._delay: list[deque] = []
        self.time: float = math.nan        # the simulation's time: where the last step ended

    def on_configure(self) -> None:
        plants = {}
        for a in self.axes:
            try:
                plants[a] = SlidePlant(substep_rate=self.substep_rate, **self.params[a])
            except ValueError as e:
                raise HardwareError(f'sim: {a}.{e}') from None
        self.plants = plants
        self._slides = [(self.io[a], plants[a]) for a in self.axes]
        self._delay = [deque([0.0] * self.latency_ticks) for _ in self.axes]

    def on_deactivate(self) -> None:
        for plant in self.plants.values():
            plant.command(0.0)
            plant.disable()

    def configure_plant(self, axis: str, changes: dict) -> None:
        """New plant registers for one axis, at a tick boundary (validated together; raises
        ValueError and changes nothing on a refusal).

        Parameters
        ----------
        axis : str
            The axis whose slide changes.
        changes : dict
            {plant register: value}, SI units (PLANT_PARAMETERS).
        """
        self.plants[axis].configure(**changes)
        self.params[axis].update(changes)

    # -- the cycle ----------------------------------------------------------------------------
    def read(self, now: float) -> None:
        """Every slide's encoders [counts] into its AxisIO, stamped `now` [s]; ticks skipped
        since the last `write` are integrated first on the held commands.

        Parameters
        ----------
        now : float
            The servo cycle's time [s], on the servo grid.
        """
        t = self.time
        if t != t or abs(now - t) < 1e-9:   # the first read; or on time (ROS stamps: whole ns)
            t = self.time = now
        elif now > t:                       # ticks were skipped: the slides ran on meanwhile
            self._run_on(now - t)
            t = self.time = now
        for io, plant in self._slides:
            io.motor = plant.motor_count()
            io.load = plant.load_count()
            io.stamp = t

    def _run_on(self, late: float) -> None:
        """The `late` [s] of skipped ticks: periods in which no command reached the amplifiers,
        each counted by their watchdogs (after command_timeout: 0 V and the dynamic brake), as
        a drive counts the cycles its controller missed."""
        T = self.period
        whole = int(late / T + 1e-6)
        rest = late - whole * T
        for _, plant in self._slides:
            for _ in range(whole):
                plant.advance(T)
            if rest > 1e-12:
                plant.advance(rest)

    def write(self, now: float) -> None:
        """Each commanded axis's output [V] to its amplifier (after `latency_ticks`), then every
        slide integrated one servo period through its command watchdog.

        Parameters
        ----------
        now : float
            The servo cycle's time [s], as `read`'s.
        """
        T = self.period
        delayed = self.latency_ticks > 0
        i = 0
        for io, plant in self._slides:
            if io.commanded:
                volts = io.output
                if delayed:
                    line = self._delay[i]
                    line.append(volts)
                    volts = line.popleft()
                plant.command(volts)
            plant.advance(T, T)
            i += 1
        t = self.time
        self.time = (now if t != t else max(t, now)) + T

    # -- what the slides are doing (the ROS shell publishes it as the plant node does) ---------
    def truth(self) -> tuple[list[float], list[float]]:
        """Positions and velocities [m, m/s] of every slide: motor then load, axis by axis
        (the order of plant_states: `<axis>_motor`, `<axis>_load`).

        Returns
        -------
        tuple[list[float], list[float]]
            (positions [m], velocities [m/s]), two entries an axis.
        """
        pos: list[float] = []
        vel: list[float] = []
        for _, p in self._slides:
            pos.append(p.x_m)
            pos.append(p.x_l)
            vel.append(p.v_m)
            vel.append(p.v_l)
        return pos, vel

    def applied(self) -> list[float]:
        """The output each amplifier applied in the last integration [V].

        Returns
        -------
        list[float]
            One an axis [V], clipped at amplifier_limit.
        """
        return [p.volts for _, p in self._slides]

    def tripped(self) -> list[bool]:
        """Per axis: the amplifier's command watchdog held the output at 0 V.

        Returns
        -------
        list[bool]
            One an axis: True when it tripped (command_timeout) in the last integration.
        """
        return [p.tripped for _, p in self._slides]
