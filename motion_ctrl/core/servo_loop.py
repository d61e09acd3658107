"""The servo loop of a controller: one whole tick for all its axes, as a PMAC servo interrupt or
LinuxCNC's motion controller cycle runs it, in named stages:

 1. targets and jogs posted since the last tick, the latest of each axis (`post`: a flood of
    them costs one re-plan per axis per tick); register sets accepted since the last tick,
    applied together (a set of several parameters takes effect on one tick; PMAC applies
    I-variables at the next servo cycle);
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

`cycle` is the whole servo cycle around the tick, as PMAC's servo interrupt and ros2_control's
read / update / write run it: the hardware interface (motion_ctrl.core.hardware) reads the
encoders (and reports the drives' faults), the tick computes, the amplifiers follow the loops'
enable state and the hardware writes the outputs.

No ROS here: the controller node feeds it targets and register sets, drives `cycle` from its
timer (or from its sim clock) and publishes what it returns; the lines it returns are for the
node's log.
"""
from __future__ import annotations

from typing import Final

import math
from dataclasses import dataclass, field

from motion_ctrl.core import excitation
from motion_ctrl.core.axis import Axis
from motion_ctrl.core.commands import CommandResult
from motion_ctrl.core.diagnostics import LoopStats
from motion_ctrl.core.coordination import CoordinateSystem
from motion_ctrl.core.hardware import LINK, AxisIO, HardwareInterface, NoHardware
from msg_defs.status import Status

# s of encoder samples before the loop closes at start-up (real time): while DDS discovery
# settles, a stream can pause for longer than feedback_timeout right after its first sample.
STREAM_SETTLE: Final = 0.5
_FEEDBACK_FAULT: Final = int(Status.FEEDBACK_FAULT)
_FE_FATAL: Final = int(Status.FOLLOWING_ERROR_FATAL)
# The faults the axis's tick latches itself, logged with their reason when they do.
_TICK_FAULTS: Final = _FE_FATAL | int(Status.OVERSPEED)
# 1.5 * 2**52: adding and taking it away rounds a double of magnitude below 2**51 to the nearest
# whole number (half to even), in floats (round() would make a Python int).
_ROUND: Final = 6755399441055744.0


def _ns(seconds: float) -> float:
    """A difference of two stamps [s], back on the nanosecond grid ROS stamps live on: k·T − (k−1)·T
    in floats is T only to ~1e-18, and the profile must step by exactly the period."""
    return ((seconds * 1e9 + _ROUND) - _ROUND) / 1e9


class _Channel:
    """The loop's bookkeeping of one axis: its I/O, the stamps of the first sample and of the
    last one used, the servo time waited for a new one, and what was last logged."""

    def __init__(self, name: str, axis: Axis, io: AxisIO) -> None:
        self.name = name
        self.axis = axis
        self.io = io
        self.first: float = math.nan
        self.used: float = math.nan
        self.waited: float = 0.0
        self.faults: int = 0
        self.diverged: tuple | None = None
        self.word: int = -1              # the status word last reported in Tick.changed


@dataclass
class Tick:
    """What one tick produced: the axes that have feedback, their outputs [V], the axes whose
    status word changed since the last tick, log lines as (level, text), level 'error' or
    'warning', and the posted targets and jogs it refused."""
    names: list[str] = field(default_factory=list)
    outputs: list[float] = field(default_factory=list)
    changed: list[str] = field(default_factory=list)
    log: list[tuple[str, str]] = field(default_factory=list)
    # targets and jogs posted since the last tick and refused at it: (what, axis, reason), what
    # 'target_position' or 'target_velocity' (the node logs them at most once a second)
    refused: list[tuple[str, str, str]] = field(default_factory=list)


class ServoLoop:
    """The servo loop of one controller: its axes ticked together, in the stages of the module
    docstring, by `cycle` (or `tick`) at each servo interrupt; commands and register sets come
    in between ticks and take effect in the order they came.

    Parameters
    ----------
    axes : dict[str, Axis]
        The axes by name, ticked in this order.
    values : dict[str, dict]
        Per axis, the registers applied (each Axis's register set); kept up to date by
        `apply_staged`.
    period : float
        The servo period [s] (1 / servo_rate, PMAC's servo clock): the first tick's dt.
    feedback_timeout : float
        Servo time without a new encoder sample before FEEDBACK_FAULT [s] (register
        feedback_timeout).
    sim_time : bool
        Time is a simulation's: a loop closes at its first sample (else after STREAM_SETTLE).
    hardware : HardwareInterface, optional
        The backend `cycle` reads and writes (core.hardware), activated by the caller; None:
        NoHardware, samples given by `feedback`.
    """

    def __init__(self, axes: dict[str, Axis], values: dict[str, dict], period: float,
                 feedback_timeout: float, sim_time: bool = False,
                 hardware: HardwareInterface | None = None):
        self.axes = axes
        self.hardware: HardwareInterface = NoHardware(axes) if hardware is None else hardware
        self.channels = [_Channel(a, axis, self.hardware.io[a]) for a, axis in axes.items()]
        self.values = values                  # registers applied, per axis
        self.staged: dict[str, dict] = {}     # accepted, applied at the next tick
        self.period = period
        self.feedback_timeout = feedback_timeout
        self.sim_time = sim_time
        self.stats = LoopStats(period)
        self.last_tick: float | None = None
        self.scheduled: list[tuple[float, str, float, int]] = []   # (stamp, axis, target, epoch)
        self.coords = CoordinateSystem(axes)
        self._age_recorded = False   # the sample age of this tick is in the statistics
        # Targets and jogs posted since the last tick, the latest per axis: {axis: (jog, value)}
        self.pending: dict[str, tuple[bool, float]] = {}

    # -- inputs ---------------------------------------------------------------------------------
    def feedback(self, axis: str, motor: int, load: int, stamp: float) -> None:
        """An encoder sample of `axis` stamped `stamp` [s], from outside the hardware's `read`
        (AxisIO.sample: an older or repeated one is dropped).

        Parameters
        ----------
        axis : str
            The axis.
        motor, load : int
            The motor and load encoders [counts].
        stamp : float
            The time the sample was taken [s], on the loop's clock.
        """
        self.hardware.io[axis].sample(motor, load, stamp)

    @property
    def waited(self) -> dict[str, float]:
        """Per axis, the servo time waited for a new encoder sample [s]."""
        return {c.name: c.waited for c in self.channels}

    def reset(self, axis: str):
        """`<axis>/reset`: the drive's fault reset, then the axis's (Axis.reset).

        Returns
        -------
        CommandResult
            Axis.reset's: always accepted.
        """
        self.hardware.reset(axis)
        return self.axes[axis].reset()

    def current(self, axis: str) -> dict:
        """The axis's registers as they will be at the next tick.

        Returns
        -------
        dict
            {register: value}: those applied, with those staged over them.
        """
        return self.values[axis] | self.staged.get(axis, {})

    def stage(self, axis: str, changes: dict) -> None:
        """Register changes of `axis`, accepted already (validated by the caller), to apply
        together at the next tick or before the next command (`apply_staged`).

        Parameters
        ----------
        axis : str
            The axis.
        changes : dict
            {register: value}, SI units; merged over what is staged already.
        """
        self.staged.setdefault(axis, {}).update(changes)

    def apply_staged(self) -> list[tuple[str, str]]:
        """Apply the staged register sets now, each axis's all or nothing (Axis.configure).

        Returns
        -------
        list[tuple[str, str]]
            Log lines (level, text): a set the core refused, not applied.
        """
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
        """A target to start at the first tick at or after `stamp` [s] (a coordinated start).

        Parameters
        ----------
        stamp : float
            When to start [s], on the loop's clock.
        axis : str
            The axis.
        target : float
            Position in the user's frame [m] (Axis.move_to; refused then, it is logged).
        """
        self.scheduled.append((stamp, axis, target, self.axes[axis].command_epoch))

    def unschedule(self, axes, why: str) -> list[tuple[str, str]]:
        """Drop the scheduled targets of `axes`; the log lines saying so.

        Parameters
        ----------
        axes : collection of str
            The axes whose scheduled targets are dropped.
        why : str
            What cancelled them, for the log.

        Returns
        -------
        list[tuple[str, str]]
            ('warning', text), one per target dropped.
        """
        log = [('warning', f'{a}: scheduled target {t:g} m (stamped {stamp:.3f} s) cancelled '
                           f'by {why}') for stamp, a, t, _ in self.scheduled if a in axes]
        self.scheduled = [x for x in self.scheduled if x[1] not in axes]
        return log

    def post(self, axis: str, value: float, jog: bool = False) -> None:
        """A target position (or, `jog`, a jog velocity) for `axis`, started at the next tick
        or at the next `flush`; of those posted before then the latest of each axis wins and the
        others are never tried. A stream of targets, however fast, then costs one re-plan per
        axis per tick (the input budget of a per-tick input; a drive's cyclic setpoint is the
        same: one per cycle, the last written).

        Parameters
        ----------
        axis : str
            The axis.
        value : float
            Target position in the user's frame [m], or with `jog` a velocity [m/s].
        jog : bool
            `value` is a jog velocity (Axis.jog), not a target (Axis.move_to).
        """
        self.pending[axis] = (jog, value)

    def flush(self) -> tuple[list[tuple[str, str]], list[tuple[str, str, str]]]:
        """Start what was posted (move, jog) now: (log lines, refused as (what, axis, reason)).
        The tick does this first; a caller with another command (stop, a register set, a
        schedule) does it before, so that commands take effect in the order they came.

        Returns
        -------
        tuple[list[tuple[str, str]], list[tuple[str, str, str]]]
            Log lines (level, text), and the refused as (what, axis, reason), what
            'target_position' or 'target_velocity'.
        """
        pending = self.pending
        self.pending = {}
        log: list[tuple[str, str]] = []
        refused: list[tuple[str, str, str]] = []
        moves = {a: v for a, (jog, v) in pending.items() if not jog}
        jogs = {a: v for a, (jog, v) in pending.items() if jog}
        if moves:
            log += self.unschedule(moves, 'a newer immediate target')
            refused += [('target_position', a, r) for a, r in self.move(moves)]
        if jogs:
            log += self.unschedule(jogs, 'a jog')
            refused += [('target_velocity', a, r) for a, r in self.jog(jogs)]
        return log, refused

    def move(self, targets: dict) -> list[tuple[str, str]]:
        """Start moves now, after any register set accepted before them (commands take effect in
        the order they came: a feedback change applied at the next tick would re-home the
        command and drop a move started meanwhile). Returns (axis, refusal) of those refused.

        Parameters
        ----------
        targets : dict
            {axis: target position in the user's frame [m]} (Axis.move_to).

        Returns
        -------
        list[tuple[str, str]]
            (axis, reason) of each target refused.
        """
        return self._start(Axis.move_to, targets)

    def jog(self, velocities: dict) -> list[tuple[str, str]]:
        """Start jogs now, after any register set accepted before them (as `move`).

        Parameters
        ----------
        velocities : dict
            {axis: jog velocity [m/s]} (Axis.jog).

        Returns
        -------
        list[tuple[str, str]]
            (axis, reason) of each jog refused.
        """
        return self._start(Axis.jog, velocities)

    def excite(self, axis: str) -> CommandResult:
        """Start the test signal `axis`'s excitation_* registers describe (Axis.excite), after
        any register set accepted before (a client sets the registers, then calls
        <axis>/excite). A refusal changes nothing.

        Parameters
        ----------
        axis : str
            The axis; its excitation_* registers (signal, amplitude [V], band [Hz], duration
            [s], excitation_budget [m], excitation_velocity [m/s]) describe the run.

        Returns
        -------
        CommandResult
            Axis.excite's, or refused with the reason the registers make no signal.
        """
        if self.staged:
            self.apply_staged()
        r = self.values[axis]
        try:
            signal = excitation.from_registers(r, 1.0 / self.period)
        except ValueError as e:
            return CommandResult(False, f'{axis}.{e}')
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
        (CoordinateSystem.prepare: may run off the servo thread).

        Parameters
        ----------
        spec : dict
            msg_defs.read_joint_trajectory's dict: names, times [s], and per point positions
            [m], velocities [m/s], accelerations [m/s²] (empty where a point leaves one out).

        Returns
        -------
        Prepared or str
            The trajectory and each axis's path (core.coordination.Prepared), or the refusal.
        """
        return self.coords.prepare(spec, self.values)

    def trajectory(self, job, stamp: float | None = None, now: float | None = None):
        """Start (or, with a `stamp` after `now`, schedule) a multi-axis trajectory, after any
        register set accepted before it (CoordinateSystem.start); returns the refusal, or
        None. A refused trajectory changes nothing.

        Parameters
        ----------
        job : dict or Prepared
            A spec (as `prepare` takes) or `prepare`'s result (built again if the axes moved).
        stamp : float, optional
            When to start [s], on the loop's clock; None or not after `now`: at once.
        now : float, optional
            The loop's time now [s].

        Returns
        -------
        str or None
            The refusal, or None (started or scheduled).
        """
        if self.staged:
            self.apply_staged()
        return self.coords.start(job, self.values, stamp, now)

    # -- the cycle ------------------------------------------------------------------------------
    def cycle(self, now: float) -> Tick | None:
        """One servo cycle at time `now` [s]: the hardware reads, the loop ticks, the hardware
        writes. None when time did not advance (nothing written).

        Parameters
        ----------
        now : float
            The servo interrupt's time [s], on the servo grid (whole periods of the clock).

        Returns
        -------
        Tick or None
            What the tick produced (outputs [V], status changes, log lines, refusals).
        """
        hardware = self.hardware
        hardware.read(now)
        tick = self.tick(now)
        if tick is not None:
            hardware.write(now)
        return tick

    # -- the tick -------------------------------------------------------------------------------
    def tick(self, now: float) -> Tick | None:
        """One servo tick at time `now` [s]; None when time did not advance (sim time paused).

        Parameters
        ----------
        now : float
            The tick's time [s]; dt is the time since the last tick (the period at the first).

        Returns
        -------
        Tick or None
            As `cycle`; the outputs are left in each AxisIO for the hardware's `write`.
        """
        dt = self.period if self.last_tick is None else _ns(now - self.last_tick)
        self.last_tick = now
        if dt <= 0.0:
            return None
        out = Tick()
        self.stats.period(dt)
        if self.pending:
            out.log, out.refused = self.flush()
        if self.staged:
            out.log += self.apply_staged()
        if self.scheduled:
            self._scheduled(now, out)
        if self.coords.busy:
            out.log += self.coords.tick(now, self.values)
        self._age_recorded = False   # (one encoder message carries every axis)
        for ch in self.channels:
            io = ch.io
            stamp = io.stamp
            if stamp != stamp:           # (nan) no feedback yet: the loop stays open, nothing sent
                io.commanded = False
                continue
            axis = ch.axis
            if io.fault_kind:
                self._hardware_fault(ch, out)
            stale = self._watch_feedback(ch, stamp, dt)
            if not axis.homed and not self._stream_established(ch, stamp, stale):
                io.commanded = False     # the encoder stream is not established yet: wait
                continue
            if stale:
                volts = self._feedback_lost(ch, now, dt, out)
            else:
                volts = self._servo(ch, now, dt)
            self._report(ch, out)
            word = axis.word
            if word != ch.word:
                ch.word = word
                out.changed.append(ch.name)
            io.output = volts
            io.commanded = True
            io.enabled = axis.enabled
            out.names.append(ch.name)
            out.outputs.append(volts)
        return out

    # The stages of one axis's tick.
    def _hardware_fault(self, ch: _Channel, out: Tick) -> None:
        """A fault the hardware reports (core.hardware): LINK opens the loop as FEEDBACK_FAULT,
        DRIVE as an ABORT that holds until reset; logged when it latches."""
        axis, io, a = ch.axis, ch.io, ch.name
        if io.fault_kind == LINK:
            if not axis.fault_bits & _FEEDBACK_FAULT:
                opened = 'loop opened' if axis.enabled else 'the loop was open'
                out.log.append(('error', f'{a}: FEEDBACK_FAULT: {io.fault_reason}; {opened}, '
                                         f'call {a}/reset'))
            axis.feedback_fault(io.fault_reason)
        elif not axis.drive_fault_reason:
            opened = 'loop opened (ABORTED)' if axis.enabled else 'the loop was open'
            out.log.append(('error', f'{a}: amplifier fault: {io.fault_reason}; {opened}, call '
                                     f'{a}/reset'))
            axis.drive_fault(io.fault_reason)

    def _watch_feedback(self, ch: _Channel, stamp: float, dt: float) -> bool:
        """The feedback watchdog: servo time waited for a new sample (a late tick counts at
        most two periods); True once it exceeds feedback_timeout."""
        if stamp != ch.used:
            ch.waited = 0.0
        else:
            ch.waited = _ns(ch.waited + min(dt, 2 * self.period))
            if ch.waited > self.stats.feedback_wait_max:
                self.stats.feedback_wait_max = ch.waited
        return ch.waited > self.feedback_timeout

    def _stream_established(self, ch: _Channel, stamp: float, stale: bool) -> bool:
        """The loop-closing gate: an axis closes its loop once its encoder stream has run for
        STREAM_SETTLE (real time), not on the first sample of a stream that may still stall."""
        if ch.first != ch.first:
            ch.first = stamp
        return not stale and (self.sim_time or stamp - ch.first >= STREAM_SETTLE)

    def _feedback_lost(self, ch: _Channel, now: float, dt: float, out: Tick) -> float:
        """FEEDBACK_FAULT: the loop opens (logged once, when it latches)."""
        axis, io, a = ch.axis, ch.io, ch.name
        if not axis.fault_bits & _FEEDBACK_FAULT:
            opened = 'loop opened' if axis.enabled else 'the loop was open'
            out.log.append(('error', (
                f'{a}: FEEDBACK_FAULT: no new encoder sample for {ch.waited * 1e3:.0f} ms '
                f'of servo time (the last is stamped {(now - io.stamp) * 1e3:.0f} ms ago); '
                f'{opened}, call {a}/reset')))
        axis.feedback_fault()
        return axis.update(dt, io.motor, io.load, sample_dt=0.0)

    def _servo(self, ch: _Channel, now: float, dt: float) -> float:
        """The axis's tick on its latest sample: the time since the previous sample, and the
        sample's age at this tick (the axis takes the error against the command of then)."""
        io = ch.io
        stamp = io.stamp
        prev = ch.used
        sample_dt = None if prev != prev else _ns(stamp - prev)
        ch.used = stamp
        age = max(now - stamp, 0.0)
        if not self._age_recorded:       # (once a tick: one message carries every axis)
            self._age_recorded = True
            if sample_dt == 0.0:
                self.stats.ticks_without_sample += 1
            else:
                self.stats.feedback_age(min(age, 3 * self.period))
        return ch.axis.update(dt, io.motor, io.load, sample_dt=sample_dt, age=age)

    def _report(self, ch: _Channel, out: Tick) -> None:
        """Log what latched this tick: a fatal following error or an overspeed, a correction loop
        stopped, hunting at rest."""
        axis = ch.axis
        faults = axis.fault_bits
        if faults & _TICK_FAULTS & ~ch.faults:
            out.log.append(('error', f'{ch.name}: {axis.fault_reason}; loop opened, call '
                                     f'{ch.name}/reset'))
        ch.faults = faults
        diverged = axis.sampled.diverged
        if diverged is not None and ch.diverged != diverged:
            out.log.append(('warning', f'{ch.name}: correction moves stopped: the load error '
                                       f'grew from {diverged[0]} to {diverged[1]} counts'))
        ch.diverged = diverged
        hunting = axis.hunting
        if hunting.started:
            what = hunting.describe(axis.loop_counts_per_m)
            out.log.append(('warning', f'{ch.name}: hunting: {what} (autotune sizes the '
                                       'anti-hunting window for the slide: deadband_tolerance, '
                                       'fine_position_tolerance)'))

    def _scheduled(self, now: float, out: Tick) -> None:
        void = {a for _, a, _, epoch in self.scheduled if epoch != self.axes[a].command_epoch}
        for a in void:
            out.log += self.unschedule({a}, self.axes[a].cancelled_by)
        due = [x for x in self.scheduled if x[0] <= now + 1e-9]
        if due:
            self.scheduled = [x for x in self.scheduled if x[0] > now + 1e-9]
            for a, reason in self.move({a: t for _, a, t, _ in due}):
                out.log.append(('warning', f'target_position refused: {reason}'))
