"""Hunting at rest, seen by the controller: the servo output reversing its push while the axis
has nothing to do and has not settled.

What RMC's Deadband Tolerance ("reduce hunting ... ratcheting the axis back and forth around the
deadband", shared/seeds/000) and PMAC's Ixx34 / Ixx64-65 deadband are set against, counted so
that an operator sees it without a plot: a slide that stiction holds a count or two off the
target while the integrator winds the output up until it breaks away, overshoots and sticks on
the other side, again and again, never meeting the fine window (no MOTION_DONE).

The count (register `hunting_reversals`: how many make it hunting; 0 = not watched):

* watched while the profile is at rest (no move, jog or stop commanding motion) and the axis is
  not settled (IN_FINE_POSITION clear): after a move before MOTION_DONE, or later if the axis
  leaves its fine window; not during a test signal;
* a reversal is the output changing sign, each side held for HOLD_S (a servo tick's kick from
  kd on a motor count, or the ringing of a settle, is not a push) beyond BAND_V;
* the count restarts with each new motion and after QUIET_S without a reversal (an axis that
  was knocked and recovered is not hunting an hour later);
* period: twice the mean time between reversals; amplitude: half the spread of the position
  error from the first reversal on.

Plain Python, compiled with the servo tick (setup.py COMPILED): a few comparisons a tick.
"""
from __future__ import annotations

from typing import Final

#: a side of the output [V] counts beyond this
BAND_V: Final = 1e-3
#: ... held this long [s]
HOLD_S: Final = 0.01
#: no reversal for this long [s]: the count restarts
QUIET_S: Final = 10.0


class Hunting:
    """The hunting watch of one axis. `step` once per servo tick; `hunting` once the output has
    reversed `limit` times at rest without settling (`started` is True on the tick it became
    so, for the one log line)."""

    def __init__(self, limit: int = 0):
        self.limit = limit
        self.reversals = 0
        self.hunting = False
        self.started = False
        self.first = 0.0              # time [s] of the first and the last counted reversal
        self.last = 0.0
        self.error_min = 0.0          # position error [m] while watched since the count began
        self.error_max = 0.0
        self._time = 0.0
        self._side = 0                # accepted side of the output: +1, -1, 0 none yet
        self._pending = 0             # side the output is on now, waiting for HOLD_S
        self._held = 0.0
        self._watching = False

    def configure(self, limit: int) -> None:
        self.limit = limit
        if limit <= 0:
            self.reset()

    def reset(self) -> None:
        """A new motion: nothing counted."""
        self.reversals = 0
        self.hunting = self.started = False
        self._side = self._pending = 0
        self._held = 0.0
        self._watching = False

    @property
    def period(self) -> float:
        """Seconds per cycle (two reversals), 0 until two reversals were counted."""
        n = self.reversals
        return 2.0 * (self.last - self.first) / (n - 1) if n >= 2 else 0.0

    @property
    def amplitude(self) -> float:
        """Half the spread of the position error [m] from the first reversal on."""
        return 0.5 * (self.error_max - self.error_min) if self.reversals else 0.0

    def describe(self, counts_per_m: float) -> str:
        """The finding in words, for the log and /diagnostics."""
        text = f'{self.reversals} output reversals at rest without settling'
        if self.reversals >= 2:
            text += (f' (period {self.period:.2f} s, position ±'
                     f'{self.amplitude * counts_per_m:.1f} counts)')
        return text

    def step(self, dt: float, watch: bool, moving: bool, output: float, error: float) -> None:
        """One servo tick. watch: at rest and not settled; moving: the profile commands motion
        (the count restarts); output [V]; error: the position error [m]."""
        self._time += dt
        self.started = False
        if moving:
            if self.reversals or self._side or self._watching:
                self.reset()
            return
        if not watch or self.limit <= 0:
            self._watching = False
            return
        now = self._time
        if not self._watching:
            self._watching = True
            if not self.reversals:
                self.error_min = self.error_max = error
        if error < self.error_min:
            self.error_min = error
        elif error > self.error_max:
            self.error_max = error
        if self.reversals and now - self.last > QUIET_S:
            self.reversals = 0
            self.hunting = False
            self.error_min = self.error_max = error
        side = 1 if output > BAND_V else -1 if output < -BAND_V else 0
        if side == 0 or side == self._side:
            self._pending = 0
            self._held = 0.0
            return
        if side != self._pending:
            self._pending = side
            self._held = 0.0
        else:
            self._held += dt
        if self._held + 1e-9 < HOLD_S:
            return
        if self._side:
            if not self.reversals:
                self.first = now
                self.error_min = self.error_max = error    # the cycle's, not the approach's
            self.reversals += 1
            self.last = now
            if not self.hunting and self.reversals >= self.limit:
                self.hunting = self.started = True
        self._side = side
        self._pending = 0
        self._held = 0.0
