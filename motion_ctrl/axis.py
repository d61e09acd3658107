"""One servo axis: the modules a motion engineer names, composed into the per-tick sequence of a
PMAC / Galil / RMC servo interrupt.

Each tick (`update`):
 1. read both encoders, estimate velocities over the real dt (rcl timers skip late ticks);
 2. step the profile (move generator + Galil IT smoothing);
 3. backlash / leadscrew compensation (PMAC Ixx85..87, BLCOMP, COMP) on loops that close on the
    motor encoder; hidden from the reported position;
 4. pick the feedback: motor, load, dual (Galil DV: position on the load, damping on the motor)
    or sampled (motor loop + Galil's correction moves on the load encoder after each move);
 5. following-error checks (PMAC Ixx11 / Ixx12); fatal opens the loop;
 6. the servo law (PID / I-PD, notch, deadband, output limit);
 7. settling events (RMP) and the status word.

Commands (`move_to`, `jog`, `stop`, ...) return (accepted, reason): a refused one changes nothing
but the LIMIT bit where SPEC.md says so. The axis starts with the loop closed at the position the
encoders report on the first tick (PMAC Ixx80 = 1, power-on enable).
"""
from __future__ import annotations

import math

from msg_defs.status import Status
from motion_ctrl.backlash import BacklashCompensation
from motion_ctrl.dual_loop import SampledCorrection, feedback_encoders
from motion_ctrl.profile import Profile
from motion_ctrl.registers import AXIS_REGISTERS, axis_defaults, consistency
from motion_ctrl.servo_law import ServoLaw
from motion_ctrl.settling import Settling

_STICKY = Status.LIMIT


class Axis:
    def __init__(self, name: str, registers: dict | None = None, servo_period: float = 1e-3):
        self.name = name
        self.servo_period = servo_period
        self.servo = ServoLaw()
        self.profile = Profile(0.0)
        self.settling = Settling()
        self.backlash = BacklashCompensation()
        self.sampled = SampledCorrection()
        self.r = None
        self.configure(axis_defaults(AXIS_REGISTERS) | (registers or {}))
        self.enabled = False
        self.homed = False           # first feedback seen
        self.faults = Status(0)      # FOLLOWING_ERROR_FATAL | FEEDBACK_FAULT
        self.sticky = Status(0)      # LIMIT
        self.status = Status(0)
        self.output = 0.0
        # Encoder state (load units, m) and estimates.
        self.motor_pos = self.load_pos = 0.0
        self.motor_vel = self.load_vel = 0.0
        self.motor_acc = self.load_acc = 0.0
        self.actual_pos = self.actual_vel = 0.0    # what the loop controls, compensation hidden
        self.following_error = 0.0
        self.correction = 0.0        # backlash + leadscrew correction on the motor command
        # Sampled dual loop (Galil): motor target = user target + offset.
        self.target = None
        self.sampled_offset = 0.0
        self.events = []             # (time, Status word) on every change, for tests and tools
        self.time = 0.0

    # -- configuration --------------------------------------------------------------------------
    def configure(self, values: dict) -> None:
        """Apply a complete, validated register set at a tick boundary (all or nothing)."""
        from motion_ctrl.registers import CONTROLLER_AXIS
        for name, value in values.items():
            reason = CONTROLLER_AXIS[name].check(value) if name in CONTROLLER_AXIS else \
                f'unknown register {name!r}'
            if reason:
                raise ValueError(f'{self.name}.{reason}')
        reasons = consistency(values)
        if reasons:
            raise ValueError('; '.join(f'{self.name}.{r}' for r in reasons))
        r = dict(values)
        T = self.servo_period
        # Every module validates its own inputs before anything is replaced.
        self.profile.configure(r['max_velocity'], r['max_acceleration'], r['max_jerk'],
                               r['smoothing'], T)
        self.settling.configure(r['fine_position_tolerance'], r['coarse_position_tolerance'],
                                r['velocity_tolerance'], r['settling_time'])
        self.backlash.configure(r['backlash_distance'], r['backlash_takeup_rate'],
                                r['backlash_hysteresis'], r['backlash_table'],
                                r['backlash_table_spacing'], r['leadscrew_table'],
                                r['leadscrew_table_spacing'])
        self.sampled.configure(r['correction_tolerance'], r['correction_max_moves'],
                               r['load_counts_per_m'], r['settling_time'])
        old = self.r
        self.servo.configure(r)
        self.r = r
        if old is not None and old['feedback'] != r['feedback'] and self.homed:
            self._rehome_command()

    # -- derived -------------------------------------------------------------------------------
    @property
    def motor_side_loop(self) -> bool:
        """Position loop closed on the motor encoder: compensation applies there only."""
        return feedback_encoders(self.r['feedback'])[0] == 'motor'

    def _loop_position(self) -> float:
        return self.motor_pos if self.motor_side_loop else self.load_pos

    def _loop_velocity(self) -> float:
        return self.load_vel if self.r['feedback'] == 'load' else self.motor_vel

    def _half_count(self) -> float:
        cpm = self.r['motor_counts_per_m' if self.motor_side_loop else 'load_counts_per_m']
        return 0.5 / cpm

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

    # -- commands -------------------------------------------------------------------------------
    def _refuse_unless_ready(self):
        if self.faults:
            return f'{self.name}: faulted ({self.faults!r}), call {self.name}/reset'
        if not self.enabled:
            return f'{self.name}: not enabled'
        return None

    def move_to(self, target: float):
        if not isinstance(target, (int, float)) or not math.isfinite(target):
            return False, f'{self.name}: target {target!r} is not a finite number'
        lo, hi = self.r['soft_limit_min'], self.r['soft_limit_max']
        if not lo <= target <= hi:
            self.sticky |= Status.LIMIT
            return False, (f'{self.name}: target {target:g} m outside the soft limits '
                           f'[{lo:g}, {hi:g}]')
        reason = self._refuse_unless_ready()
        if reason:
            return False, reason
        self.sticky &= ~Status.LIMIT
        self.target = float(target)
        self.profile.move_to(self.target + self.sampled_offset)
        self.settling.start_position_move(self.target + self.sampled_offset)
        if self.r['feedback'] == 'sampled':
            self.sampled.start()
        return True, ''

    def jog(self, velocity: float):
        if not isinstance(velocity, (int, float)) or not math.isfinite(velocity):
            return False, f'{self.name}: velocity {velocity!r} is not a finite number'
        reason = self._refuse_unless_ready()
        if reason:
            return False, reason
        self.target = None
        self.sampled.cancel()
        self.profile.jog(float(velocity))
        self.settling.start_velocity_move(float(velocity))
        return True, ''

    def stop(self, kind: str = 'stop'):
        reason = self._refuse_unless_ready()
        if reason:
            return False, reason
        self.sampled.cancel()
        self.profile.stop(self.r['stop_deceleration' if kind == 'stop' else 'estop_deceleration'])
        self.settling.start_stop(kind)
        return True, ''

    def abort(self):
        """Open the loop at once, output 0 (RMP ABORT)."""
        self._open_loop()
        self.settling.abort()
        return True, ''

    def enable(self, on: bool):
        if not on:
            self._open_loop()
            self.settling.idle()
            return True, ''
        if self.faults:
            return False, f'{self.name}: faulted ({self.faults!r}), call {self.name}/reset first'
        if not self.homed:
            return False, f'{self.name}: no encoder feedback yet'
        if not self.enabled:
            self.enabled = True
            self._rehome_command()
            self.settling.idle()
        return True, ''

    def reset(self):
        """Clear faults (fatal following error, feedback fault); the loop stays open."""
        self.faults = Status(0)
        self.sticky = Status(0)
        return True, ''

    def correct(self):
        """Run the sampled dual-loop correction now (Galil #CORRECT)."""
        reason = self._refuse_unless_ready()
        if reason:
            return False, reason
        if not self.profile.done:
            return False, f'{self.name}: a move is in progress'
        if self.target is None:
            self.target = self.command_position
        self.sampled.start_now()
        self.settling.start_position_move(self.target + self.sampled_offset)
        return True, ''

    # -- internals ------------------------------------------------------------------------------
    def _open_loop(self):
        self.enabled = False
        self.sampled.cancel()
        self.servo.reset()
        self.output = 0.0

    def _rehome_command(self):
        """Hold the present position without a bump: the command becomes the actual position."""
        self.sampled_offset = 0.0
        if self.motor_side_loop:
            pos = self.motor_pos - self.correction
        else:
            pos = self.load_pos
        self.profile.hold(pos)
        self.servo.reset()
        self.target = None

    def _correct_by(self, v2: float) -> None:
        """A sampled correction move: PR V2 on the motor, relative to its command."""
        self.sampled_offset += v2
        self.profile.move_to(self.target + self.sampled_offset)
        self.settling.start_position_move(self.target + self.sampled_offset)

    def home(self, motor_counts: int, load_counts: int) -> None:
        """First feedback: take the encoders as they are and close the loop there."""
        r = self.r
        self.motor_pos = motor_counts / r['motor_counts_per_m']
        self.load_pos = load_counts / r['load_counts_per_m']
        self.backlash.reset(self.motor_pos)
        self.correction = 0.0
        self.homed = True
        self.enabled = True
        self._rehome_command()
        self.settling.idle()

    def feedback_fault(self) -> None:
        if self.enabled or not self.faults & Status.FEEDBACK_FAULT:
            self._open_loop()
            self.faults |= Status.FEEDBACK_FAULT

    # -- the servo tick -------------------------------------------------------------------------
    def update(self, dt: float, motor_counts, load_counts, sample_dt: float | None = None
               ) -> float:
        """One servo tick with the latest encoder counts; returns the amplifier command [V].

        sample_dt: time between this encoder sample and the previous one (from their stamps),
        None = dt (sampled in step with the loop), 0 = no new sample since the last tick (the
        velocity estimates are kept rather than read as a stop).
        """
        r = self.r
        self.time += dt
        if not self.homed:
            self.home(motor_counts, load_counts)
        if sample_dt is None:
            sample_dt = dt
        if sample_dt > 0.0:
            motor_pos = motor_counts / r['motor_counts_per_m']
            load_pos = load_counts / r['load_counts_per_m']
            motor_vel = (motor_pos - self.motor_pos) / sample_dt
            load_vel = (load_pos - self.load_pos) / sample_dt
            self.motor_acc = (motor_vel - self.motor_vel) / sample_dt
            self.load_acc = (load_vel - self.load_vel) / sample_dt
            self.motor_pos, self.load_pos = motor_pos, load_pos
            self.motor_vel, self.load_vel = motor_vel, load_vel

        if not self.enabled:
            # Loop open: the command follows the actual position so closing it is bumpless.
            self.profile.hold(self._loop_position() - (self.correction if self.motor_side_loop
                                                       else 0.0))
            self.output = 0.0
            self._update_actual()
            self._compose_status(self.settling.bits & (Status.MOTION_DONE | Status.ABORTED
                                                       | Status.STOPPED | Status.ESTOPPED))
            return 0.0

        self.profile.step(dt)
        p = self.profile
        if self.motor_side_loop:
            self.correction = self.backlash.step(p.position, dt)
        loop_cmd = p.position + (self.correction if self.motor_side_loop else 0.0)
        self._update_actual()
        fe = loop_cmd - self._loop_position()
        self.following_error = fe
        fatal = r['following_error_fatal']
        if fatal > 0.0 and abs(fe) > fatal:
            self._open_loop()
            self.faults |= Status.FOLLOWING_ERROR_FATAL
            self.settling.abort()
            self._compose_status(Status.MOTION_DONE)
            return 0.0

        target_stopped = p.velocity == 0.0 and not p.moving
        out = self.servo.update(
            dt, cmd_pos=loop_cmd, cmd_vel=p.velocity, cmd_acc=p.acceleration,
            act_pos=self._loop_position(), act_vel=self._loop_velocity(),
            vel_loop_vel=self.motor_vel if r['feedback'] != 'load' else self.load_vel,
            vel_loop_acc=self.motor_acc if r['feedback'] != 'load' else self.load_acc,
            target_stopped=target_stopped, half_count=self._half_count())
        self.output = out

        bits = self.settling.update(dt, command_position=p.position, command_velocity=p.velocity,
                                    profile_done=p.done, actual_position=self.actual_pos
                                    + self.sampled_offset, actual_velocity=self.actual_vel)
        if r['feedback'] == 'sampled' and self.target is not None:
            bits = self._sampled_step(dt, motor_counts, load_counts, bits)
        self._compose_status(bits)
        return out

    def _sampled_step(self, dt, motor_counts, load_counts, bits) -> Status:
        """Galil's #CORRECT after each move; MOTION_DONE only when the load is there."""
        s = self.sampled
        load_error = self.target - self.load_pos
        v2 = s.update(dt, profile_done=self.profile.done,
                      motor_settled=bool(bits & Status.MOTION_DONE),
                      motor_counts=int(motor_counts),
                      load_error_counts=round(load_error * self.r['load_counts_per_m']),
                      motor_error=self.following_error, load_error=load_error)
        if v2 is not None:
            self._correct_by(v2)
            bits = self.settling.bits
        if s.phase in (s.MOVING, s.CORRECTING):
            bits &= ~(Status.MOTION_DONE | Status.IN_FINE_POSITION)
        elif s.done:
            bits |= Status.MOTION_DONE | Status.IN_FINE_POSITION
        return bits

    def _update_actual(self):
        if self.motor_side_loop:
            self.actual_pos = self.motor_pos - self.correction - self.sampled_offset
        else:
            self.actual_pos = self.load_pos
        self.actual_vel = self._loop_velocity()

    def _compose_status(self, motion_bits: Status) -> None:
        s = Status(motion_bits) | self.faults | self.sticky
        r = self.r
        if self.enabled:
            s |= Status.ENABLED
            w = r['following_error_warning']
            if w > 0.0 and abs(self.following_error) > w:
                s |= Status.FOLLOWING_ERROR_WARNING
            if self.servo.saturated:
                s |= Status.OUTPUT_SATURATED
            if self.servo.integrator_held:
                s |= Status.INTEGRATOR_HELD
            if self.correcting:
                s |= Status.CORRECTING | Status.MOVING
        if self.motor_side_loop and self.backlash.active:
            s |= Status.BACKLASH_ACTIVE
        if s != self.status:
            self.events.append((self.time, s))
        self.status = s
