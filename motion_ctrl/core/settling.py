"""RMP-style settling criteria and motion events for one servo axis.

Plain Python (no rclpy), deterministic, stepped with an explicit ``dt`` once per servo tick
after the profile generator has been stepped.  SI units: m, m/s, s.

Source: RSI RapidCode/RMP "Axis Settling" (shared/seeds/004) and the status-word table of
doc/interface.md.  The four settling criteria are

* fine position tolerance  [m]   -- position moves only;
* coarse position tolerance [m]  -- position moves only, should be >= fine;
* velocity tolerance [m/s]       -- position moves (|actual velocity|) and velocity moves
  (|actual - target velocity|);
* settling time [s]              -- how long a criterion must hold before its event.

"Setting VelocityTolerance to 0 does not disable the velocity criteria" (seed 004): here no
tolerance of 0 disables anything; it only makes the criterion hard (exact) to meet.

Motion events produced (``Status`` bits, see :mod:`msg_defs.status`):

MOVING              profile generator active: the profile is not done, or it is still commanding
                    a non-zero velocity (a jog cruising at constant speed keeps MOVING set).
AT_TARGET           position move and command position == target, compared exactly.
                    Never for velocity moves.
IN_COARSE_POSITION  position move and |target - actual| <= coarse tolerance; may set and clear
                    more than once when the target is changed on the fly.
IN_FINE_POSITION    RMP SETTLED.  Evaluated after AT_TARGET: |target - actual| <= fine and
                    |actual velocity| <= velocity tolerance, both held for the settling time.
                    Whenever either breaks the bit clears and the settling timer resets.
MOTION_DONE         position move settled (raised once, together with the first
                    IN_FINE_POSITION, then latched for that move even if the axis is later
                    disturbed; IN_FINE_POSITION keeps tracking); a velocity move to zero velocity
                    whose velocity criterion held for the settling time after the profile reached
                    zero; a STOP/ESTOP deceleration that finished; an ABORT (at once); or the
                    idle axis at rest (nothing pending).  A new move clears it.
MOTION_AT_VELOCITY  velocity move with non-zero target, profile at its constant velocity,
                    |actual - target velocity| <= velocity tolerance held for the settling time;
                    clears (timer reset) whenever broken or the velocity changes.
STOPPED / ESTOPPED  with MOTION_DONE when a STOP / ESTOP deceleration finished.
ABORTED             with MOTION_DONE at once on ABORT.
                    STOPPED, ESTOPPED and ABORTED stay set until the next move starts (or
                    ``idle()`` is called, e.g. when the loop is enabled again).

Timing rule ("held for the settling time"), exactly:
    Each ``update(dt, ...)`` first advances the internal clock by ``dt``, then evaluates the
    sample it is given.  On the first tick of an unbroken run where the criterion holds,
    ``settle_start`` = clock and the held time is 0.  On each further tick of the run the held
    time grows by that tick's ``dt`` (summed from 0, so it does not depend on the size of the
    clock).  The event is reported on every tick of the run where
    ``held >= settling_time - TIME_EPSILON`` (TIME_EPSILON = 1 ns).
    So with dt = 1 ms and settling_time = 10 ms, a criterion first holding on tick k is reported
    on tick k + 10 (the 11th consecutive holding tick); settling_time = 0 reports on tick k.
    A tick where the criterion fails resets the run.
"""

import math
import numbers
from typing import Final

from msg_defs.status import Status

from motion_ctrl.core.config import SettlingConfig, defaults

__all__ = ['Settling', 'TIME_EPSILON', 'MOTION_BITS', 'STOP_KINDS', 'status_word']

#: Tolerance [s] for "held for settling_time" comparisons of accumulated dt.
TIME_EPSILON: Final = 1e-9

#: The bits this module owns; the caller ORs in the others.
MOTION_BITS: Final = (Status.MOVING | Status.AT_TARGET | Status.IN_COARSE_POSITION
               | Status.IN_FINE_POSITION | Status.MOTION_DONE | Status.MOTION_AT_VELOCITY
               | Status.STOPPED | Status.ESTOPPED | Status.ABORTED)

#: start_stop() kinds and the status bit each one reports when finished.
STOP_KINDS: Final = {'stop': Status.STOPPED, 'estop': Status.ESTOPPED}

# The same bits as plain ints for the per-tick path: IntFlag arithmetic costs ~1 us an
# operation (enum machinery), int arithmetic ~30 ns. A Status is built once per distinct word.
_MOVING: Final = int(Status.MOVING)
_AT_TARGET: Final = int(Status.AT_TARGET)
_IN_COARSE: Final = int(Status.IN_COARSE_POSITION)
_IN_FINE: Final = int(Status.IN_FINE_POSITION)
_DONE: Final = int(Status.MOTION_DONE)
_AT_VELOCITY: Final = int(Status.MOTION_AT_VELOCITY)
_STOPPED: Final = int(Status.STOPPED)
_ESTOPPED: Final = int(Status.ESTOPPED)
_ABORTED: Final = int(Status.ABORTED)
_LATCHED: Final = _STOPPED | _ESTOPPED | _ABORTED   # events that outlive their move

_STATUS_MEMO: dict[int, Status] = {}


def status_word(value: int) -> Status:
    """``Status(value)``, memoised: the enum constructor costs ~0.6 us, a dict hit ~50 ns.
    There are only a few dozen distinct words in practice (at most 2**18)."""
    s = _STATUS_MEMO.get(value)
    if s is None:
        s = _STATUS_MEMO[value] = Status(value)
    return s


# Modes (what is pending).
IDLE: Final = 'idle'
POSITION: Final = 'position'
VELOCITY: Final = 'velocity'
STOP: Final = 'stop'
ESTOP: Final = 'estop'
ABORT: Final = 'abort'


def _finite(name, value):
    """Return ``value`` as float, or raise ValueError naming ``name``."""
    if isinstance(value, bool) or not isinstance(value, numbers.Real):
        raise ValueError(f'{name} must be a real number, got {value!r}')
    value = float(value)
    if not math.isfinite(value):
        raise ValueError(f'{name} must be finite, got {value!r}')
    return value


def _non_negative(name, value):
    value = _finite(name, value)
    if value < 0.0:
        raise ValueError(f'{name} must be >= 0, got {value!r}')
    return value


class Settling:
    """Settling criteria and motion events of one axis (RSI RMP semantics, seed 004).

    Call one of ``start_position_move``, ``start_velocity_move``, ``start_stop``, ``abort``
    or ``idle`` when the motion state changes, then ``update()`` once per servo tick (or
    ``step()``, its unchecked positional twin returning a plain int, in a servo loop).

    Attributes (read-only for callers):
        bits          last result of ``update()`` (or of ``abort()`` / a start call)
        settle_start  clock [s] at which the criterion being timed (fine position and velocity
                      for a position move, the velocity criterion for a velocity move) last
                      started holding; None while it does not hold
        clock         internal time [s], the sum of all dt given to ``update()``
        mode          'idle' | 'position' | 'velocity' | 'stop' | 'estop' | 'abort'
        target        target position [m] of the position move (None otherwise)
        target_velocity  target velocity [m/s] of the velocity move (None otherwise)
    """

    def __init__(self, config: SettlingConfig | None = None):
        self.fine_tolerance = 0.0
        self.coarse_tolerance = 0.0
        self.velocity_tolerance = 0.0
        self.settling_time = 0.0
        self.configure(config or defaults(SettlingConfig))
        self.clock = 0.0
        self._bits = 0            # last motion word, plain int (``bits`` gives the Status)
        self.settle_start: float | None = None
        self._held = 0.0          # time [s] the timed criterion has held, summed from 0
        self._done = False        # MOTION_DONE latched for the current move
        self.mode = IDLE
        self.target: float | None = None
        self.target_velocity: float | None = None

    # ------------------------------------------------------------------ configuration
    def configure(self, config: SettlingConfig) -> None:
        """Set the settling criteria (m, m, m/s, s), validated by the register table. A
        tolerance of 0 does not disable its criterion. New values apply from the next
        ``update()``; a running settling timer keeps its held time and is judged against the
        new values."""
        self.fine_tolerance = config.fine_position_tolerance
        self.coarse_tolerance = config.coarse_position_tolerance
        self.velocity_tolerance = config.velocity_tolerance
        self.settling_time = config.settling_time

    @property
    def word(self) -> int:
        """Last motion bits as a plain int (the servo tick's form of ``bits``)."""
        return self._bits

    def open_loop_bits(self) -> int:
        """The motion bits while the loop is open: nothing is being moved (MOTION_DONE), and the
        STOPPED / ESTOPPED / ABORTED event that ended the last move stays shown."""
        return _DONE | (self._bits & _LATCHED)

    @property
    def bits(self) -> Status:
        """Last result of ``update()`` / ``step()`` (or of ``abort()`` / a start call)."""
        return status_word(self._bits)

    # ------------------------------------------------------------------ state changes
    def _begin(self, mode):
        self.mode = mode
        self.target = None
        self.target_velocity = None
        self._done = False
        self.settle_start = None
        self._held = 0.0
        self._bits = 0          # a new move clears every event, incl. STOPPED/ESTOPPED/ABORTED

    def start_position_move(self, target):
        """A new point-to-point move to ``target`` [m] (also an on-the-fly re-target).

        Clears MOTION_DONE, AT_TARGET etc. and restarts the settling timer; the next
        ``update()`` evaluates against the new target.
        """
        target = _finite('target', target)
        self._begin(POSITION)
        self.target = target

    def start_velocity_move(self, target_velocity):
        """A velocity (jog) move to ``target_velocity`` [m/s]; 0 decelerates to rest."""
        target_velocity = _finite('target_velocity', target_velocity)
        self._begin(VELOCITY)
        self.target_velocity = target_velocity

    def start_stop(self, kind):
        """A STOP (``'stop'``) or ESTOP (``'estop'``) deceleration began.

        The move's target is abandoned; MOTION_DONE | STOPPED (or ESTOPPED) is reported once
        the profile is done at rest.
        """
        if kind not in STOP_KINDS:
            raise ValueError(f"stop kind must be 'stop' or 'estop', got {kind!r}")
        self._begin(STOP if kind == 'stop' else ESTOP)

    def abort(self):
        """ABORT done: MOTION_DONE | ABORTED at once (and until the next move)."""
        self._begin(ABORT)
        self._done = True
        self._bits = _DONE | _ABORTED

    def idle(self):
        """No move yet / loop just enabled: nothing pending.

        Reports MOTION_DONE while the profile is at rest (nothing left to finish) and MOVING if
        the caller's profile is somehow active; no position or velocity events.
        """
        self._begin(IDLE)

    # ------------------------------------------------------------------ servo tick
    def update(self, dt, *, command_position, command_velocity, profile_done,
               actual_position, actual_velocity):
        """Evaluate one servo tick and return the motion bits (see ``MOTION_BITS``).

        Args (SI): ``dt`` tick length [s] (finite, >= 0); ``command_position`` [m] and
        ``command_velocity`` [m/s] of the profile after this tick's step; ``profile_done``
        True once the profile generator has finished (for a velocity move: reached its
        constant velocity); ``actual_position`` [m], ``actual_velocity`` [m/s] measured.
        """
        dt = _non_negative('dt', dt)
        return status_word(self.step(dt, command_position, command_velocity, profile_done,
                                     actual_position, actual_velocity))

    def step(self, dt: float, command_position: float, command_velocity: float,
             profile_done: bool, actual_position: float, actual_velocity: float) -> int:
        """``update()`` for the servo tick: positional arguments, no validation (the caller
        passes a finite dt >= 0 and finite floats), returns the word as a plain int."""
        clock = self.clock + dt
        self.clock = clock
        moving = (not profile_done) or command_velocity != 0.0
        bits = _MOVING if moving else 0
        mode = self.mode

        if mode == POSITION:
            bits |= self._position_bits(clock, dt, command_position, actual_position,
                                        actual_velocity)
        elif mode == VELOCITY:
            bits |= self._velocity_bits(clock, dt, moving, profile_done, actual_velocity)
        elif mode == STOP or mode == ESTOP:
            # "Normally a MOTION_DONE event will be created at the end of STOP time."
            if not moving:
                self._done = True
            if self._done:
                bits |= _DONE | (_STOPPED if mode == STOP else _ESTOPPED)

        elif mode == ABORT:
            bits = _DONE | _ABORTED

        else:  # IDLE: nothing pending
            if not moving:
                bits |= _DONE

        self._bits = bits
        return bits

    def _position_bits(self, clock: float, dt: float, command_position: float,
                       actual_position: float, actual_velocity: float) -> int:
        """A position move: AT_TARGET when the command equals the target (seed 004: "equal"),
        IN_COARSE within the coarse tolerance; "After AT_TARGET, the evaluation of the settling
        criteria begins ... Whenever either criteria 1 or 2 is not satisfied, SETTLED is cleared
        and the settling timer is reset" (velocity tolerance 0 does not disable its
        criterion); MOTION_DONE once settled, latched for the move."""
        bits = 0
        target = self.target
        assert target is not None         # (a position move has one)
        at_target = command_position == target
        error = abs(target - actual_position)
        if at_target:
            bits |= _AT_TARGET
        if error <= self.coarse_tolerance:
            bits |= _IN_COARSE
        if (at_target and error <= self.fine_tolerance
                and abs(actual_velocity) <= self.velocity_tolerance):
            if self._timer(clock, dt):
                bits |= _IN_FINE
                self._done = True
        elif self.settle_start is not None:
            self.settle_start = None
            self._held = 0.0
        return bits | _DONE if self._done else bits

    def _velocity_bits(self, clock: float, dt: float, moving: bool, profile_done: bool,
                       actual_velocity: float) -> int:
        """A velocity move. To zero: "MOTION_DONE ... by a velocity move only if the target
        velocity is zero and the velocity criteria have been met for the period specified by
        the settling time" (timed from when the profile reached zero). Otherwise "continuously
        evaluated during the constant velocity portion ... Whenever Criteria 1 is not
        satisfied, MOTION_AT_VELOCITY is set to FALSE and the settling timer is reset"."""
        tv = self.target_velocity
        assert tv is not None             # (a velocity move has one)
        if tv == 0.0:
            holds = not moving and abs(actual_velocity) <= self.velocity_tolerance
        else:
            holds = profile_done and abs(actual_velocity - tv) <= self.velocity_tolerance
        bits = 0
        if holds:
            if self._timer(clock, dt):
                if tv == 0.0:
                    self._done = True
                else:
                    bits = _AT_VELOCITY
        elif self.settle_start is not None:
            self.settle_start = None
            self._held = 0.0
        return bits | _DONE if self._done and tv == 0.0 else bits

    def _timer(self, clock: float, dt: float) -> bool:
        """The timed criterion holds on this tick: advance the settling timer; True once it has
        held for the settling time (see the timing rule in the module docstring)."""
        if self.settle_start is None:
            self.settle_start = clock    # first tick of the run: held time 0
            self._held = 0.0
            held = 0.0
        else:
            held = self._held + dt
            self._held = held
        return held >= self.settling_time - TIME_EPSILON
