"""The servo loop of a controller: one whole tick for all its axes, as a PMAC servo interrupt or
LinuxCNC's motion controller cycle runs it, in named stages:

 1. register sets accepted since the last tick, applied together (a set of several parameters
    takes effect on one tick; PMAC applies I-variables at the next servo cycle);
 2. scheduled targets: those a stop, abort, disable or fault made void are dropped (said why),
    those due are started;
 3. per axis, feedback freshness: a tick with no new encoder sample counts its time (a late tick
    at most two periods) and beyond `feedback_timeout` the axis faults (FEEDBACK_FAULT); at
    start-up the loop closes only once the encoder stream has run STREAM_SETTLE (real time;
    PMAC Ixx80 = 1 power-on enable) or at the first sample (sim time);
 4. coordinated trajectories (PMAC PVT, core.coordination): those due start, and one whose
    axis was stopped, aborted, disabled or faulted stops the other axes of it too (a
    coordinate system stops as one);
 5. per axis, the sample's age (it is compared with the command of its own time) and the
    axis's own tick (`Axis.update`).

No ROS here: the controller node feeds it samples, targets and register sets and publishes
what `tick` returns; the lines it returns are for the node's log.
"""
from __future__ import annotations

from dataclasses import dataclass, field

from motion_ctrl.core import excitation
from motion_ctrl.core.axis import Axis
from motion_ctrl.core.diagnostics import LoopStats
from motion_ctrl.core.coordination import CoordinateSystem
from msg_defs.status import Status

# s of encoder samples before the loop closes at start-up (real time): while DDS discovery
# settles, a stream can pause for longer than feedback_timeout right after its first sample.
STREAM_SETTLE = 0.5
# s: an encoder stamp this much older than the sample in hand is a new clock, not a late copy
# (a copy through a bridge lags by milliseconds, at most its second of history).
CLOCK_RESTART = 1.0
_FEEDBACK_FAULT = int(Status.FEEDBACK_FAULT)
_FE_FATAL = int(Status.FOLLOWING_ERROR_FATAL)


def _ns(seconds: float) -> float:
    """A difference of two stamps [s], back on the nanosecond grid ROS stamps live on: k·T − (k−1)·T
    in floats is T only to ~1e-18, and the profile must step by exactly the period."""
    return round(seconds * 1e9) / 1e9


@dataclass
class Tick:
    """What one tick produced: the axes that have feedback, their outputs [V], and log lines
    as (level, text), level 'error' or 'warning'."""
    names: list[str] = field(default_factory=list)
    outputs: list[float] = field(default_factory=list)
    log: list[tuple[str, str]] = field(default_factory=list)


class ServoLoop:
    def __init__(self, axes: dict[str, Axis], values: dict[str, dict], period: float,
                 feedback_timeout: float, sim_time: bool = False):
        self.axes = axes
        self.values = values                  # registers applied, per axis
        self.staged: dict[str, dict] = {}     # accepted, applied at the next tick
        self.period = period
        self.feedback_timeout = feedback_timeout
        self.sim_time = sim_time
        self.stats = LoopStats(period)
        self.last_tick: float | None = None
        # Per axis: the latest sample (motor, load, stamp [s]), the stamp of the last one used,
        # the stamp of the first, and the servo time waited for a new one.
        self.enc: dict[str, tuple[int, int, float] | None] = {a: None for a in axes}
        self.enc_used: dict[str, float | None] = {a: None for a in axes}
        self.first_sample: dict[str, float] = {}
        self.waited = {a: 0.0 for a in axes}
        self.scheduled: list[tuple[float, str, float, int]] = []   # (stamp, axis, target, epoch)
        self.coords = CoordinateSystem(axes)
        self._faults = {a: 0 for a in axes}
        self._diverged: dict[str, tuple | None] = {}      # the last logged, per axis
        self._age_recorded = False   # the sample age of this tick is in the statistics

    # -- inputs ---------------------------------------------------------------------------------
    def feedback(self, axis: str, motor: int, load: int, stamp: float) -> None:
        """An encoder sample of `axis`, stamped by the plant [s]. One not newer than the sample
        in hand is dropped: two paths to the loop (the plant's stream and a bridge's copy of it,
        a hop later) deliver a sample twice and out of order. A stamp more than CLOCK_RESTART
        older is a new clock (a restarted lockstep plant), taken."""
        held = self.enc[axis]
        if held is not None and held[2] - CLOCK_RESTART < stamp <= held[2]:
            return
        self.enc[axis] = (motor, load, stamp)

    def current(self, axis: str) -> dict:
        """The axis's registers as they will be at the next tick."""
        return self.values[axis] | self.staged.get(axis, {})

    def stage(self, axis: str, changes: dict) -> None:
        self.staged.setdefault(axis, {}).update(changes)

    def apply_staged(self) -> list[tuple[str, str]]:
        log = []
        for axis, changes in self.staged.items():
            merged = self.values[axis] | changes
            try:
                self.axes[axis].configure(merged)
                self.values[axis] = merged
            except ValueError as e:      # validated already; a core refusal is still logged
                log.append(('error', f'parameters not applied: {e}'))
        self.staged.clear()
        return log

    def schedule(self, stamp: float, axis: str, target: float) -> None:
        """A target to start at the first tick at or after `stamp` [s] (a coordinated start)."""
        self.scheduled.append((stamp, axis, target, self.axes[axis].command_epoch))

    def unschedule(self, axes, why: str) -> list[tuple[str, str]]:
        """Drop the scheduled targets of `axes`; the log lines saying so."""
        log = [('warning', f'{a}: scheduled target {t:g} m (stamped {stamp:.3f} s) cancelled '
                           f'by {why}') for stamp, a, t, _ in self.scheduled if a in axes]
        self.scheduled = [x for x in self.scheduled if x[1] not in axes]
        return log

    def move(self, targets: dict) -> list[tuple[str, str]]:
        """Start moves now, after any register set accepted before them (commands take effect in
        the order they came: a feedback change applied at the next tick would re-home the
        command and drop a move started meanwhile). Returns (axis, refusal) of those refused."""
        return self._start(Axis.move_to, targets)

    def jog(self, velocities: dict) -> list[tuple[str, str]]:
        """Start jogs now, after any register set accepted before them (as `move`)."""
        return self._start(Axis.jog, velocities)

    def excite(self, axis: str):
        """Start the test signal `axis`'s excitation_* registers describe (Axis.excite), after
        any register set accepted before (a client sets the registers, then calls
        <axis>/excite). Returns (accepted, reason); a refusal changes nothing."""
        if self.staged:
            self.apply_staged()
        r = self.values[axis]
        try:
            signal = excitation.from_registers(r, 1.0 / self.period)
        except ValueError as e:
            return False, f'{axis}.{e}'
        return self.axes[axis].excite(signal, r['excitation_budget'], r['excitation_velocity'])

    def _start(self, command, values: dict) -> list[tuple[str, str]]:
        if self.staged:
            self.apply_staged()
        refused = []
        for a, value in values.items():
            ok, reason = command(self.axes[a], value)
            if not ok:
                refused.append((a, reason))
        return refused

    # -- coordinated trajectories (PMAC PVT): the coordinate system ------------------------------
    def prepare(self, spec: dict):
        """Check and build the trajectory of `spec` from the axes' commanded state now
        (CoordinateSystem.prepare: may run off the servo thread)."""
        return self.coords.prepare(spec, self.values)

    def trajectory(self, job, stamp: float | None = None, now: float | None = None):
        """Start (or, with a `stamp` after `now`, schedule) a multi-axis trajectory, after any
        register set accepted before it (CoordinateSystem.start); returns the refusal, or
        None. A refused trajectory changes nothing."""
        if self.staged:
            self.apply_staged()
        return self.coords.start(job, self.values, stamp, now)

    # -- the tick -------------------------------------------------------------------------------
    def tick(self, now: float) -> Tick | None:
        """One servo tick at time `now` [s]; None when time did not advance (sim time paused)."""
        dt = self.period if self.last_tick is None else _ns(now - self.last_tick)
        self.last_tick = now
        if dt <= 0.0:
            return None
        out = Tick()
        self.stats.period(dt)
        if self.staged:
            out.log += self.apply_staged()
        if self.scheduled:
            self._scheduled(now, out)
        if self.coords.busy:
            out.log += self.coords.tick(now, self.values)
        self._age_recorded = False   # (one encoder message carries every axis)
        for a, axis in self.axes.items():
            enc = self.enc[a]
            if enc is None:
                continue                 # no feedback yet: the loop stays open, nothing sent
            stale = self._watch_feedback(a, enc[2], dt)
            if not axis.homed and not self._stream_established(a, enc[2], stale):
                continue                 # the encoder stream is not established yet: wait
            if stale:
                volts = self._feedback_lost(a, axis, enc, now, dt, out)
            else:
                volts = self._servo(a, axis, enc, now, dt)
            self._report(a, axis, out)
            out.names.append(a)
            out.outputs.append(volts)
        return out

    # The stages of one axis's tick.
    def _watch_feedback(self, a: str, stamp: float, dt: float) -> bool:
        """The feedback watchdog: servo time waited for a new sample of axis `a` (a late tick
        counts at most two periods); True once it exceeds feedback_timeout."""
        if stamp != self.enc_used[a]:
            self.waited[a] = 0.0
        else:
            self.waited[a] = _ns(self.waited[a] + min(dt, 2 * self.period))
            if self.waited[a] > self.stats.feedback_wait_max:
                self.stats.feedback_wait_max = self.waited[a]
        return self.waited[a] > self.feedback_timeout

    def _stream_established(self, a: str, stamp: float, stale: bool) -> bool:
        """The loop-closing gate: an axis closes its loop once its encoder stream has run for
        STREAM_SETTLE (real time), not on the first sample of a stream that may still stall."""
        first = self.first_sample.setdefault(a, stamp)
        return not stale and (self.sim_time or stamp - first >= STREAM_SETTLE)

    def _feedback_lost(self, a: str, axis: Axis, enc, now: float, dt: float, out: Tick) -> float:
        """FEEDBACK_FAULT: the loop opens (logged once, when it latches)."""
        motor, load, stamp = enc
        if not axis.fault_bits & _FEEDBACK_FAULT:
            opened = 'loop opened' if axis.enabled else 'the loop was open'
            out.log.append(('error', (
                f'{a}: FEEDBACK_FAULT: no new encoder sample for {self.waited[a] * 1e3:.0f} ms '
                f'of servo time (the last is stamped {(now - stamp) * 1e3:.0f} ms ago); '
                f'{opened}, call {a}/reset')))
        axis.feedback_fault()
        return axis.update(dt, motor, load, sample_dt=0.0)

    def _servo(self, a: str, axis: Axis, enc, now: float, dt: float) -> float:
        """The axis's tick on its latest sample: the time since the previous sample, and the
        sample's age at this tick (the axis takes the error against the command of then)."""
        motor, load, stamp = enc
        prev = self.enc_used[a]
        sample_dt = None if prev is None else _ns(stamp - prev)
        self.enc_used[a] = stamp
        age = min(max(now - stamp, 0.0), 3 * self.period)
        if not self._age_recorded:
            self._age_recorded = True
            self.stats.feedback_age(age)
        return axis.update(dt, motor, load, sample_dt=sample_dt, age=age)

    def _report(self, a: str, axis: Axis, out: Tick) -> None:
        """Log what latched this tick: a fatal following error, a correction loop stopped, hunting
        at rest."""
        faults = axis.fault_bits
        if faults & _FE_FATAL and not self._faults[a] & _FE_FATAL:
            out.log.append(('error', f'{a}: {axis.fault_reason}; loop opened, call {a}/reset'))
        self._faults[a] = faults
        diverged = axis.sampled.diverged
        if diverged is not None and self._diverged.get(a) != diverged:
            out.log.append(('warning', f'{a}: correction moves stopped: the load error grew '
                                       f'from {diverged[0]} to {diverged[1]} counts'))
        self._diverged[a] = diverged
        hunting = axis.hunting
        if hunting.started:
            out.log.append(('warning', f'{a}: hunting: {hunting.describe(axis.loop_counts_per_m)}'
                                       ' (autotune sizes the anti-hunting window for the slide: '
                                       'deadband_tolerance, fine_position_tolerance)'))

    def _scheduled(self, now: float, out: Tick) -> None:
        void = {a for _, a, _, epoch in self.scheduled if epoch != self.axes[a].command_epoch}
        for a in void:
            out.log += self.unschedule({a}, self.axes[a].cancelled_by)
        due = [x for x in self.scheduled if x[0] <= now + 1e-9]
        if due:
            self.scheduled = [x for x in self.scheduled if x[0] > now + 1e-9]
            for a, reason in self.move({a: t for _, a, t, _ in due}):
                out.log.append(('warning', f'target_position refused: {reason}'))
