"""Loop timing statistics, the servo loop's part of /diagnostics (the message is
motion_ctrl.ros.diagnostics).

The servo timer is measured, not trusted: rcl timers skip missed periods instead of queueing
them, so the achieved rate, the period jitter and the skipped ticks (overruns) are counted from
the real period of every tick. Statistics cover the last diagnostics window (1 s).
"""
from __future__ import annotations

from array import array

import numpy as np


class LoopStats:
    def __init__(self, period: float, capacity: int = 65536):
        self.nominal = period
        # array.array, not numpy: a servo tick stores into them (an ndarray item store costs
        # ~0.1 µs); summary() reads them through numpy.
        self.periods = array('d', bytes(8 * capacity))
        self.works = array('d', bytes(8 * capacity))
        self.ages = array('d', bytes(8 * capacity))
        self.capacity = capacity
        self.n = self.nw = self.na = 0
        self.overruns_total = 0
        # Longest servo time an axis waited for a new encoder sample (the feedback watchdog's
        # measure: FEEDBACK_FAULT when it exceeds feedback_timeout).
        self.feedback_wait_max = 0.0
        # Ticks that found no new encoder sample (the output held; in real time a sample that
        # came just after its tick, or none): how well the ticks meet the encoder stream.
        self.ticks_without_sample = 0
        # numpy's first percentile costs ~8 ms here (set-up done once per process): paid now,
        # not in the servo thread's first /diagnostics, where it held the ticks 13-20 ms and
        # tripped the amplifier's 10 ms command watchdog at every start.
        np.percentile(np.zeros(2), [50.0, 99.0])

    def period(self, dt: float) -> None:
        if self.n < self.capacity:
            self.periods[self.n] = dt
            self.n += 1
        # A period of k nominal periods means k - 1 ticks were skipped.
        if dt >= 1.5 * self.nominal:
            self.overruns_total += int(round(dt / self.nominal)) - 1

    def work(self, seconds: float) -> None:
        if self.nw < self.capacity:
            self.works[self.nw] = seconds
            self.nw += 1

    def feedback_age(self, seconds: float) -> None:
        """Age of the encoder sample a tick used (its stamp to the tick): the feedback latency."""
        if self.na < self.capacity:
            self.ages[self.na] = seconds
            self.na += 1

    def summary(self) -> dict:
        p = np.frombuffer(self.periods, count=self.n)
        w = np.frombuffer(self.works, count=self.nw)
        if not len(p):
            return {}
        jitter = np.abs(p - self.nominal)
        ages = np.frombuffer(self.ages, count=self.na)
        return {
            'rate_hz': len(p) / p.sum() if p.sum() > 0 else 0.0,
            'jitter_p50_us': float(np.percentile(jitter, 50) * 1e6),
            'jitter_p99_us': float(np.percentile(jitter, 99) * 1e6),
            'jitter_max_us': float(jitter.max() * 1e6),
            'tick_work_mean_us': float(w.mean() * 1e6) if len(w) else 0.0,
            'tick_work_max_us': float(w.max() * 1e6) if len(w) else 0.0,
            'overruns_total': self.overruns_total,
            'feedback_wait_max_ms': self.feedback_wait_max * 1e3,
            'ticks_without_new_sample': self.ticks_without_sample,
        } | ({'feedback_age_p50_us': float(np.percentile(ages, 50) * 1e6),
              'feedback_age_p99_us': float(np.percentile(ages, 99) * 1e6)}
             if self.na else {})

    def reset_window(self) -> None:
        self.n = self.nw = self.na = 0
        self.feedback_wait_max = 0.0
        self.ticks_without_sample = 0
