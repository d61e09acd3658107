"""The servo timer's phase against the encoder stream (real-time mode).

Two free-running timers at the same rate — the one that samples the encoders (the plant, a
drive) and the controller's servo timer — meet at a phase set by chance at start-up: a sample
may wait anywhere from nothing to a whole period for the tick that uses it, and the phase
differs from one start to the next. A PMAC reads its encoders at its own servo interrupt, and an
EtherCAT master shifts its cycle against the drives' SYNC0 ("shift time") for this reason.

FeedbackSync watches when samples arrive relative to the ticks and, when another phase of the
ticks would cut the mean wait of the samples clearly, asks for one shorter period, which moves
every later tick to that phase. The mean wait counts a sample that arrives just after a tick as
waiting a whole period, so the best phase lies just after most arrivals, not after all of them.
Pure logic: the node feeds it clock readings and sets the timer's period as told.
"""
from __future__ import annotations

import numpy as np


class FeedbackSync:
    """Times in seconds, all from one clock (the node uses time.perf_counter).

    window: arrivals looked at per decision (0.5 s at 1 kHz); gain: the mean wait a shift must
    save, as a fraction of the period, so the phase moves once and then stays.
    """

    STEPS = 100      # candidate tick phases per period

    def __init__(self, period: float, window: int = 500, gain: float = 0.1):
        self.period = period
        self.window = window
        self.gain = gain
        self.phases: list[float] = []     # arrival - preceding tick, modulo the period
        self.last_tick: float | None = None
        self.restore = False
        self.shifts = 0                   # phase moves so far (reported in /diagnostics)

    def arrived(self, t: float) -> None:
        """An encoder sample reached the controller at time t."""
        if self.last_tick is not None and not self.restore:
            self.phases.append((t - self.last_tick) % self.period)

    def tick(self, t: float) -> float | None:
        """A servo tick at time t. Returns the period [s] the timer must take from now on
        (which, with rcl timers, sets the time between the next tick and the one after), or
        None to leave it. A shift returns the short period once and the nominal one at the
        tick after."""
        self.last_tick = t
        if self.restore:
            self.restore = False
            self.phases.clear()
            return self.period
        if len(self.phases) < self.window:
            return None
        phi = np.array(self.phases)
        self.phases.clear()
        T = self.period
        candidates = np.arange(self.STEPS) * (T / self.STEPS)
        waits = self.mean_waits(phi, candidates)
        best = int(np.argmin(waits))
        if waits[0] - waits[best] < self.gain * T:
            return None
        self.restore = True
        self.shifts += 1
        # Ticks fall at phase 0 now; one period of theta puts them at theta (a very short one
        # would be a tick with nothing new to do: then one of theta + T).
        theta = float(candidates[best])
        return theta if theta >= 0.05 * T else theta + T

    def mean_waits(self, phi: np.ndarray, theta: np.ndarray) -> np.ndarray:
        """Mean time the samples arriving at phases `phi` wait for ticks at each phase in
        `theta` (a sample arriving at a tick's phase has just missed it: it waits a period)."""
        T = self.period
        return T - np.mean((phi[None, :] - theta[:, None]) % T, axis=1)
