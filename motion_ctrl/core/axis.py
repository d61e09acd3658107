"""One servo axis: the modules a motion engineer names, composed into the per-tick sequence of a
PMAC / Galil / RMC servo interrupt.

Each tick (`update`):
 1. read both encoders, estimate velocities over the real dt (rcl timers skip late ticks);
    the motor's beyond overspeed_velocity opens the loop (OVERSPEED, a drive's overspeed fault);
 2. step the profile (move generator + Galil IT smoothing); a jog is kept inside the soft limits;
    after a stall of the loop the motion is planned again from the measured state instead
    (STALL_PERIODS: no catch-up sprint);
 3. backlash / leadscrew compensation (PMAC Ixx85..87, BLCOMP, COMP) on loops that close on the
    motor encoder; hidden from the reported position;
 4. pick the feedback: motor, load, dual (Galil DV: position on the load, damping on the motor)
    or sampled (motor loop + Galil's correction moves on the load encoder after each move);
 5. following-error checks (PMAC Ixx11 / Ixx12); fatal opens the loop;
 6. the servo law (PID / I-PD, notch, deadband, output limit);
 7. settling events (RMP) and the status word;
 8. a test signal on the output (PMAC gather), when one runs;
 9. the hunting watch: output reversals at rest without settling (core.hunting).

Commands (`move_to`, `jog`, `stop`, ...) and their rules are in motion_ctrl.core.commands; soft
limit braking is planned by motion_ctrl.core.soft_limits.

The per-tick path works on values cached at configure time and on plain-int status bits
(IntFlag arithmetic costs ~1 µs an operation); a Status object is built once per distinct word.
"""
from __future__ import annotations

import math
from typing import Final

from msg_defs.status import Status
from motion_ctrl.core.backlash import BacklashCompensation
from motion_ctrl.core.dual_loop import SampledCorrection
from motion_ctrl.core.commands import AxisCommands
from motion_ctrl.core.gather import Gather
from motion_ctrl.core.hunting import Hunting
from motion_ctrl.core.profile import Profile
from motion_ctrl.core.config import (AxisConfig, BacklashConfig,
                                     CorrectionConfig, LawConfig, ProfileConfig, SettlingConfig)
from motion_ctrl.core.registers import AXIS_REGISTERS, axis_defaults, refusals
from motion_ctrl.core.servo_law import ServoLaw
from motion_ctrl.core.settling import Settling, status_word

# Status bits as plain ints for the servo tick.
_ENABLED: Final = int(Status.ENABLED)
_MOVING: Final = int(Status.MOVING)
_DONE: Final = int(Status.MOTION_DONE)
_FE_WARNING: Final = int(Status.FOLLOWING_ERROR_WARNING)
_FE_FATAL: Final = int(Status.FOLLOWING_ERROR_FATAL)
_SATURATED: Final = int(Status.OUTPUT_SATURATED)
_INTEGRATOR_HELD: Final = int(Status.INTEGRATOR_HELD)
_BACKLASH: Final = int(Status.BACKLASH_ACTIVE)
_FEEDBACK_FAULT: Final = int(Status.FEEDBACK_FAULT)
_LIMIT: Final = int(Status.LIMIT)
_CORRECTING: Final = int(Status.CORRECTING)
_AT_VELOCITY: Final = int(Status.MOTION_AT_VELOCITY)
_IN_FINE: Final = int(Status.IN_FINE_POSITION)
_OVERSPEED: Final = int(Status.OVERSPEED)

# A tick more than this many servo periods after the previous one follows a stall of the loop
# (the process held up, SIGSTOPped, swapped out): the motion is planned again from the measured
# state (Profile.rebase) instead of stepping the plan on by the time lost, which would put the
# command that far ahead of a slide that stood still meanwhile (the amplifier's watchdog braked
# it after its command_timeout) and drive it at the output limit to catch up. A path keeps its
# time base and is stepped on by this much only (as LinuxCNC's planner steps its own cycle time
# on a late servo thread, never catching up). Late ticks up to this are stepped as they come:
# the slide ran on meanwhile on the held command.
STALL_PERIODS: Final = 5

_S_IDLE: Final = SampledCorrection.IDLE
_S_CORRECTING: Final = SampledCorrection.CORRECTING

# Status words kept in Axis.events when the caller asks for them (harness, tools): a bound, so a
# long run does not keep every change (~75 bytes each).
EVENTS_KEPT: Final = 100_000


class Axis(AxisCommands):
    """One servo axis: state, configuration, the servo tick and the status word; the
    commands are AxisCommands'.

    Parameters
    ----------
    name : str
        The axis's name: it leads every refusal and fault reason (`x: ...`).
    registers : dict, optional
        Register values over the table's defaults (core.registers AXIS_REGISTERS, SI units);
        applied by `configure` (ValueError naming the refused ones).
    servo_period : float
        The nominal servo period [s] (1 / servo_rate): IT smoothing, the stall rule
        (STALL_PERIODS) and the test signal's rate are taken on it.
    record_events : bool
        Keep (time [s], Status) of every change of the status word in `events`.
    """

    def __init__(self, name: str, registers: dict | None = None, servo_period: float = 1e-3,
                 record_events: bool = False):
        self.name = name
        self.servo_period = servo_period
        self.servo = ServoLaw()
        self.profile = Profile(0.0)
        self.settling = Settling()
        self.backlash = BacklashCompensation()
        self.sampled = SampledCorrection()
        self.gather: Gather | None = None       # a test signal running (Axis.excite)
        self.hunting = Hunting()                # output reversals at rest without settling
        self.r: dict = {}            # the registers applied (set by configure below)
        self.enabled = False
        self.homed = False           # first feedback seen
        self._faults = 0             # FOLLOWING_ERROR_FATAL | FEEDBACK_FAULT (int)
        self._sticky = 0             # LIMIT (int)
        self._motion = 0             # last motion bits (settling + sampled), int
        self._word = 0               # status word as an int; `status` is the Status of it
        self.status = status_word(0)
        self.output = 0.0
        # Encoder state (load units, m) and estimates.
        self.motor_pos = self.load_pos = 0.0
        self.motor_vel = self.load_vel = 0.0
        self.motor_acc = self.load_acc = 0.0
        self.actual_pos = self.actual_vel = 0.0    # what the loop controls, compensation hidden
        self.following_error = 0.0
        # A stall's plan was made from its sample's mean speed: planned again on the next one.
        self._replan_due = False
        # A stall whose sample is as old as it: planned from the first fresh sample instead,
        # waited for since this servo time, the motion then moving (planned again even if its
        # plan ran out meanwhile).
        self._stale_stall = False
        self._stale_since = math.nan
        self._stale_moving = False
        self._loop_cmd = self._loop_pos = self._loop_acc = 0.0   # this tick's loop terms
        self.correction = 0.0        # backlash + leadscrew correction on the motor command
        # Sampled dual loop (Galil): motor target = user target + offset.
        self.target: float | None = None
        self.sampled_offset = 0.0
        self._guard = 0              # jog direction watched against its soft limit (+1/-1/0)
        # (time, Status word) on every change, when asked for (harness, tests, tools)
        self.events: list | None = [] if record_events else None
        self._stopping = 0           # level of the STOP (1) / ESTOP (2) decelerating the axis
        self.command_epoch = 0       # advanced by STOP, ESTOP, ABORT, disable and faults
        self.cancelled_by = ''       # ... and what advanced it last
        self.fault_reason = ''       # why the last fault latched, for the log
        self.drive_fault_reason = ''  # the amplifier's fault, until reset (drive_fault)
        self.time = 0.0
        self.configure(axis_defaults(AXIS_REGISTERS) | (registers or {}))

    # -- configuration --------------------------------------------------------------------------
    def configure(self, values: dict) -> None:
        """Apply a complete, validated register set at a tick boundary (all or nothing).

        Parameters
        ----------
        values : dict
            Every register of AXIS_REGISTERS by name, SI units (m, m/s, m/s², V, s, counts/m);
            validated as a whole by `refusals`, then kept as `r`. A feedback change on a homed
            axis re-homes the command (it holds where it is).

        Raises
        ------
        ValueError
            The refusals, `<axis>.<register>: why` joined by '; '; nothing changed.
        """
        reasons = refusals(values)
        if reasons:
            raise ValueError('; '.join(f'{self.name}.{r}' for r in reasons))
        r = dict(values)
        T = self.servo_period
        # Validated once, above; each object takes its typed part of the set.
        self.profile.configure(ProfileConfig.of_checked(r), T)
        self.settling.configure(SettlingConfig.of_checked(r))
        self.backlash.configure(BacklashConfig.of_checked(r))
        self.sampled.configure(CorrectionConfig.of_checked(r))
        old = self.r
        self.servo.configure(LawConfig.of_checked(r))
        self.r = r
        # What the servo tick and the commands read, typed and derived once here.
        self.config = c = AxisConfig.of_checked(r)
        feedback = c.feedback
        # ... and what the tick reads of it, copied: one native load each per tick
        self._motor_side: bool = c.motor_side
        self._vel_on_load: bool = c.velocity_on_load
        self._motor_cpm: float = c.motor_counts_per_m
        self._load_cpm: float = c.load_counts_per_m
        self._half: float = c.half_count
        self._shift: float = c.window_shift
        self._fe_fatal: float = c.following_error_fatal
        self._fe_warn: float = c.following_error_warning
        self._overspeed: float = c.overspeed
        self._stall: float = STALL_PERIODS * T
        self.hunting.configure(c.hunting_reversals)
        if old and old['feedback'] != feedback and self.homed:
            self._rehome_command()

    # -- derived -------------------------------------------------------------------------------
    @property
    def motor_side_loop(self) -> bool:
        """Position loop closed on the motor encoder: compensation applies there only."""
        return self._motor_side

    @property
    def loop_counts_per_m(self) -> float:
        """Counts per metre of the encoder the position loop closes on."""
        return self.config.loop_counts_per_m

    @property
    def word(self) -> int:
        """`status` as a plain int (IntFlag arithmetic costs ~0.5 µs an operation)."""
        return self._word

    @property
    def fault_bits(self) -> int:
        """`faults` as a plain int, for the servo tick."""
        return self._faults

    @property
    def faults(self) -> Status:
        """FOLLOWING_ERROR_FATAL | FEEDBACK_FAULT | OVERSPEED: the loop is open until reset."""
        return status_word(self._faults)

    @property
    def correcting(self) -> bool:
        return self.sampled.correcting

    @property
    def correction_moves(self) -> int:
        return self.sampled.moves

    @property
    def command_position(self) -> float:
        """Commanded (profile) position as reported: the user's frame, compensation hidden."""
        return self.profile.position - self.sampled_offset

    # -- internals ------------------------------------------------------------------------------
    def _open_loop(self):
        self.enabled = False
        self._stale_stall = False
        self._stopping = 0
        self.sampled.cancel()
        self.servo.reset()
        self.output = 0.0
        self.target = None
        self._guard = 0

    def _rehome_command(self):
        """Hold the present position without a bump: the command becomes the actual position and
        nothing is pending (a move, its settling or a correction in progress is over)."""
        self.sampled_offset = 0.0
        self.sampled.cancel()
        self.settling.idle()
        if self._motor_side:
            pos = self.motor_pos - self.correction
        else:
            pos = self.load_pos
        self.profile.hold(pos)
        self.servo.reset()
        self.target = None
        self._guard = 0

    def _correct_by(self, v2: float) -> None:
        """A sampled correction move: PR V2 on the motor, relative to its command, at the
        corrections' own acceleration."""
        assert self.target is not None           # (corrections follow a position move)
        self.sampled_offset += v2
        self.profile.move_to(self.target + self.sampled_offset,
                             max_acceleration=self.sampled.acceleration)
        self.settling.start_position_move(self.target + self.sampled_offset)

    def home(self, motor_counts: float, load_counts: float) -> None:
        """First feedback: take the encoders as they are and close the loop there (unless a
        fault came first: then it stays open until reset and enable).

        Parameters
        ----------
        motor_counts : float
            The motor encoder [counts] (motor_counts_per_m of them a metre of slide).
        load_counts : float
            The load (linear) encoder [counts] (load_counts_per_m of them a metre).
        """
        self.motor_pos = motor_counts / self._motor_cpm
        self.load_pos = load_counts / self._load_cpm
        self.backlash.reset(self.motor_pos)
        self.correction = 0.0
        self.homed = True
        self._rehome_command()
        if not self._faults:
            self.enabled = True

    def feedback_fault(self, reason: str = 'no new encoder sample within feedback_timeout'
                       ) -> None:
        """Encoder data stale or the link to the drive lost: the loop opens (FEEDBACK_FAULT)
        until reset."""
        if self.enabled or not self._faults & _FEEDBACK_FAULT:
            was_enabled = self.enabled
            self._open_loop()
            self._faults |= _FEEDBACK_FAULT
            self.fault_reason = f'FEEDBACK_FAULT: {reason}'
            self._cancel('FEEDBACK_FAULT')
            if was_enabled:
                self.settling.abort()    # the fault action: whatever moved is abandoned
            self._recompose()

    def drive_fault(self, reason: str) -> None:
        """The amplifier (drive) reports a fault: RMP's amplifier-fault action, an ABORT (loop
        open at once, output 0, ABORTED + MOTION_DONE), and enable and motion are refused with
        the reason until reset."""
        if self.drive_fault_reason:
            return
        self.drive_fault_reason = reason
        self.fault_reason = f'amplifier fault: {reason}'
        self._open_loop()
        self._cancel('amplifier fault')
        self.settling.abort()
        self._recompose()

    # -- the servo tick -------------------------------------------------------------------------
    def update(self, dt: float, motor_counts: float, load_counts: float,
               sample_dt: float | None = None, age: float = 0.0) -> float:
        """One servo tick with the latest encoder counts; returns the amplifier command [V].

        sample_dt: time between this encoder sample and the previous one (from their stamps),
        None = dt (sampled in step with the loop), 0 = no new sample since the last tick (the
        velocity estimates are kept rather than read as a stop, the output is held, and no
        settled time is counted).
        age: how old the sample is at this tick [s]. Over DDS a sample is 0..2 ms old; compared
        with the command of *now* it would read as a following error of velocity × age (at
        0.1 m/s, 1 ms is 40 counts) and jitter the output. So the error is taken against the
        command at the sample's time, cmd − cmd_velocity × age (a PMAC reads its encoders at
        the servo interrupt: age 0).

        Parameters
        ----------
        dt : float
            Time since the previous tick [s]: the servo period, more after a late tick (beyond
            STALL_PERIODS periods the motion is planned again from the measured state).
        motor_counts, load_counts : float
            The newest encoder sample [counts]; the first tick homes on it (`home`).
        sample_dt : float or None
            Time this sample covers [s]: None = dt, 0 = no new sample (see above).
        age : float
            Age of the sample at this tick [s] (see above).

        Returns
        -------
        float
            The amplifier command [V]: the servo law's (within ±output_limit, Ixx69), with a
            running test signal added; 0 while the loop is open or when a fault trips it.
        """
        self.time += dt
        if not self.homed:
            self.home(motor_counts, load_counts)
        if sample_dt is None:
            sample_dt = dt
        if sample_dt > 0.0:
            self._read_encoders(motor_counts, load_counts, sample_dt)
        if not self.enabled:
            return self._update_open()
        if abs(self.motor_vel) > self._overspeed:
            self._overspeed_fault()
            return 0.0
        self._step_command(dt, age, sample_dt)
        if self._stale_stall:       # no fresh sample since a stall: no error to judge yet
            sample_dt = 0.0
        elif self._following_error_fatal():
            return 0.0
        out = self._servo(sample_dt)
        self._update_status(sample_dt, motor_counts)
        g = self.gather
        if g is not None and g.running:
            return self._excite(g, out)
        if self.hunting.limit > 0:
            self._watch_hunting(sample_dt)
        return out

    # The stages of the tick, in order.
    def _read_encoders(self, motor_counts: float, load_counts: float, sample_dt: float) -> None:
        """1. Both encoders; velocity and acceleration over the time the sample covers."""
        motor_pos = motor_counts / self._motor_cpm
        load_pos = load_counts / self._load_cpm
        motor_vel = (motor_pos - self.motor_pos) / sample_dt
        load_vel = (load_pos - self.load_pos) / sample_dt
        self.motor_acc = (motor_vel - self.motor_vel) / sample_dt
        self.load_acc = (load_vel - self.load_vel) / sample_dt
        self.motor_pos = motor_pos
        self.load_pos = load_pos
        self.motor_vel = motor_vel
        self.load_vel = load_vel

    def _step_command(self, dt: float, age: float, sample_dt: float) -> None:
        """2-4. The profile's next command (a jog kept inside the soft limits), the screw
        compensation on a motor-side loop, and the feedback each term closes on; the following
        error against the command at the sample's time."""
        p = self.profile
        fresh = sample_dt > 0.0 and age <= self._stall
        if dt > self._stall:
            self._replan_due = True
            moving = p.moving or (self._stale_stall and self._stale_moving)
            if fresh:
                self._stale_stall = False
                self._replan_or_step(self._stall, age, moving=moving)
            else:                   # no sample of after the stall yet: wait for one
                if not self._stale_stall:
                    self._stale_since = self.time
                self._stale_stall = True
                self._stale_moving = moving
                p.step(self._stall if p.kind == 'path' else dt)
        elif self._stale_stall:
            if fresh or (sample_dt > 0.0 and self.time - self._stale_since > self._stall):
                self._stale_stall = False
                self._replan_or_step(dt, age, moving=self._stale_moving)
            else:
                p.step(dt)
        elif self._replan_due and fresh and sample_dt <= self._stall:
            self._replan_due = False
            self._replan_or_step(dt, age, abs(p.velocity))
        else:
            p.step(dt)
        if self._guard:
            self._guard_tick(dt)
        position = p.position
        if self._motor_side:
            correction = self.correction = self.backlash.step(position, dt)
            loop_cmd = position + correction
            loop_pos = self.motor_pos
            self.actual_pos = loop_pos - correction - self.sampled_offset
        else:
            loop_cmd = position
            loop_pos = self.actual_pos = self.load_pos
        if self._vel_on_load:
            self.actual_vel, self._loop_acc = self.load_vel, self.load_acc
        else:
            self.actual_vel, self._loop_acc = self.motor_vel, self.motor_acc
        if age > 0.0:
            loop_cmd -= p.velocity * age
        self._loop_cmd = loop_cmd
        self._loop_pos = loop_pos
        self.following_error = loop_cmd - loop_pos

    def _replan_or_step(self, step: float, age: float, most: float = math.inf,
                        moving: bool = False) -> None:
        """2a. The catch-up rule (STALL_PERIODS): a move, jog or stop planned again from the
        measured state, in the profile's frame, starting at most `most` fast [m/s] at the
        sample's time and stepped on by its `age` [s] to now (the error is taken against the
        command of the sample's time: planned from the sample, that is the sample itself); a
        path (or a profile at rest) stepped on by `step` [s], after a stall STALL_PERIODS
        only. The state is a fresh sample's, at most STALL_PERIODS old: when the tick after the
        stall has none (the encoders' process was held up with the loop, and its samples of the
        stall wait behind this tick) or only one from before the stall (it came in just before
        the loop stopped), the plan waits for the first fresh one (`_stale_stall`; a new sample
        of any age once it waited STALL_PERIODS), since the slide ran on from the last. The
        plan steps on meanwhile (a path STALL_PERIODS at the stall), the output is held and
        the following error not judged (against a plan about to be made again, an old sample's
        error means nothing), and a motion that was `moving` at the stall is planned again
        even if its plan ran out in the wait (the slide, braked, is short of it). The stall's
        sample gives the mean speed over the stall, not the speed now (the amplifier's watchdog
        may have braked the slide within it): the next sample's plan replaces this one
        (`_replan_due`), before the command runs ahead of a slide that is slower; never faster
        than this one (a single sample's speed carries the motor's ringing)."""
        p = self.profile
        if not (p.moving or moving):
            p.step(step)
            return
        if self._motor_side:
            position, velocity = self.motor_pos - self.correction, self.motor_vel
        else:
            position = self.load_pos
            velocity = self.load_vel if self._vel_on_load else self.motor_vel
        if abs(velocity) > most:
            velocity = math.copysign(most, velocity)
        if not p.rebase(position, velocity):
            p.step(step)
        elif age > 0.0:
            p.step(age)

    def _overspeed_fault(self) -> None:
        """1a. The measured motor velocity (in load units) beyond overspeed_velocity: a drive's
        overspeed fault, which watches the motor (Kollmorgen VOSPD / F08, CiA 402 max motor
        speed): the loop opens at once, output 0, OVERSPEED until reset. (Not the slide's: on
        the load loop's limit cycle across the backlash the slide bounces in the gap at twice
        the motor's speed, 0.23 m/s in the headline table's `load` row.)"""
        self._trip(_OVERSPEED, 'OVERSPEED', f'motor velocity {self.motor_vel:+.4f} m/s beyond '
                   f'overspeed_velocity {self._overspeed:g} m/s')

    def _following_error_fatal(self) -> bool:
        """5. Beyond following_error_fatal (PMAC Ixx11) the loop opens (the warning, Ixx12, is a
        status bit)."""
        fe, fatal = self.following_error, self._fe_fatal
        if not (fatal > 0.0 and abs(fe) > fatal):
            return False
        self._trip(_FE_FATAL, 'FOLLOWING_ERROR_FATAL', f'following error {fe * 1e3:+.3f} mm '
                   f'beyond following_error_fatal {fatal * 1e3:g} mm')
        return True

    def _trip(self, bit: int, name: str, why: str) -> None:
        """A fault of the tick (overspeed, fatal following error): the loop opens at once,
        output 0, the motion is abandoned, and `bit` holds until reset."""
        self._open_loop()
        self._faults |= bit
        self.fault_reason = f'{name}: {why}'
        self._cancel(name)
        self.settling.abort()
        self._compose(self.settling.open_loop_bits())

    def _servo(self, sample_dt: float) -> float:
        """6. The servo law, on new samples over the time they cover. Without a new sample
        (feedback held up, within feedback_timeout) the output is held, as a drive holds its
        command over a missed fieldbus frame: acting again on the same sample would wind the
        integrator up against a position that is only old. A sample covers at most
        STALL_PERIODS for the law: after a stall or a gap in the feedback, an error the loop did
        not see over the rest is not integrated (integrated over a 0.5 s stall at rest, 0.07 mm
        of error drove 5.6 V at once)."""
        if sample_dt > 0.0:
            p = self.profile
            velocity = p.velocity
            vel = self.actual_vel   # (positional: keywords cost 0.13 µs a call here)
            self.output = self.servo.update(
                min(sample_dt, self._stall), self._loop_cmd, velocity, p.acceleration,
                self._loop_pos, vel, vel, self._loop_acc, velocity == 0.0 and not p.moving,
                self._half, self._shift)
        return self.output

    def _update_status(self, sample_dt: float, motor_counts) -> None:
        """7. Settling events (RMP), the sampled loop's judgements and the status word. Settled
        time advances with the encoder samples: a frozen sample must not make a move look
        settled."""
        p = self.profile
        bits = self.settling.step(sample_dt, p.position, p.velocity, p.done,
                                  self.actual_pos + self.sampled_offset + self._shift,
                                  self.actual_vel)
        if self.target is not None and self.sampled.phase != _S_IDLE:
            bits = self._sampled_step(sample_dt, motor_counts, bits)
        self._compose(bits)

    def _excite(self, g: Gather, out: float) -> float:
        """8. The test signal on the output (core.gather; self.output stays the servo law's).
        On a base motion it starts once the jog is at velocity, and when the run ends (done,
        or out of budget) the base motion stops."""
        if g.waiting and self._motion & _AT_VELOCITY:
            g.begin()
        out = g.inject(out, self)
        if not g.running and g.base_velocity and self.profile.target_velocity == g.base_velocity:
            self.jog(0.0)
        return out

    def _watch_hunting(self, sample_dt: float) -> None:
        """9. Output reversals at rest without settling (core.hunting), on new samples."""
        if sample_dt > 0.0:
            p = self.profile
            self.hunting.step(sample_dt, not self._motion & _IN_FINE,
                              p.moving or p.velocity != 0.0, self.output, self.following_error)

    def _update_open(self) -> float:
        """Loop open: the command follows the actual position so closing it is bumpless."""
        if self._motor_side:
            self.profile.hold(self.motor_pos - self.correction)
            self.actual_pos = self.motor_pos - self.correction - self.sampled_offset
            self.actual_vel = self.motor_vel
        else:
            self.profile.hold(self.load_pos)
            self.actual_pos = self.load_pos
            self.actual_vel = self.load_vel if self._vel_on_load else self.motor_vel
        self.output = 0.0
        self._compose(self.settling.open_loop_bits())
        return 0.0

    def _sampled_step(self, dt, motor_counts, bits: int) -> int:
        """Galil's #CORRECT after each move; MOTION_DONE only when the load is there."""
        s = self.sampled
        assert self.target is not None           # (called only while a target is set)
        load_error = self.target - self.load_pos
        cpm = self._load_cpm
        v2 = None if dt <= 0.0 else s.update(
            dt, profile_done=self.profile.done, motor_settled=bool(bits & _DONE),
            motor_counts=int(motor_counts), load_counts=round(self.load_pos * cpm),
            load_error_counts=round(load_error * cpm),
            motor_error=self.following_error, load_error=load_error)
        if v2 is not None:
            self._correct_by(v2)
            bits = self.settling.word
        return s.motion_bits(bits)

    def _recompose(self) -> None:
        """The status word again after a command changed the state between ticks."""
        if self.enabled:
            self._compose(self._motion)
        else:
            self._compose(self.settling.open_loop_bits())

    def _compose(self, motion_bits: int) -> None:
        """The status word from its owners, one per bit:

        * MOVING, AT_TARGET, IN_COARSE_POSITION, IN_FINE_POSITION, AT_VELOCITY, MOTION_DONE,
          STOPPED, ESTOPPED, ABORTED: Settling (`motion_bits`); in the sampled loop
          SampledCorrection.motion_bits decides MOTION_DONE and IN_FINE_POSITION, and with the
          loop open Settling.open_loop_bits;
        * FOLLOWING_ERROR_FATAL, FEEDBACK_FAULT, OVERSPEED: the axis's faults (until reset);
        * LIMIT: the commands (a refused target, a jog braked at a soft limit);
        * ENABLED: the loop state; FOLLOWING_ERROR_WARNING: this tick's following error (Ixx12);
        * OUTPUT_SATURATED, INTEGRATOR_HELD: the servo law;
        * CORRECTING (and MOVING with it): SampledCorrection;
        * BACKLASH_ACTIVE: BacklashCompensation, on a motor-side loop.
        """
        self._motion = motion_bits
        s = motion_bits | self._faults | self._sticky
        if self.enabled:
            s |= _ENABLED
            w = self._fe_warn
            if w > 0.0 and abs(self.following_error) > w:
                s |= _FE_WARNING
            servo = self.servo
            if servo.saturated:
                s |= _SATURATED
            if servo.integrator_held:
                s |= _INTEGRATOR_HELD
            if self.sampled.phase == _S_CORRECTING:
                s |= _CORRECTING | _MOVING
        if self._motor_side and self.backlash.active:
            s |= _BACKLASH
        if s != self._word:
            self._word = s
            word = status_word(s)
            self.status = word
            if self.events is not None:
                self.events.append((self.time, word))
                if len(self.events) > EVENTS_KEPT:
                    del self.events[:len(self.events) - EVENTS_KEPT]
