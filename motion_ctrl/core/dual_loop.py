"""Galil's two ways to position a slide behind a backlash with a linear encoder.

* Dual loop (DMC-40x0 DV1): the position loop (KP, KI) closes on the load encoder, the damping
  (KD) on the motor encoder. That is only a choice of encoders per term: `feedback_encoders`.
* Sampled dual loop (manual example #DUALOOP / #CORRECT, seed 001): move on the motor encoder,
  wait for motion complete, read the linear-encoder error V1 and the motor's own error TE, and
  correct by V2 = V1 − TE until |V2| < 2 linear counts:

      #CORRECT  AMX              wait for motion completion
                V1=10000-_DEX    linear encoder error
                V2=-_TEX/4+V1    compensate for the motor error (4 rotary counts per linear)
                JP#END,@ABS[V2]<2
                PR V2*4; BGX; JP#CORRECT

  "Motion complete" here is the profile finished and the motor loop settled (RMP criteria on
  the motor encoder), or, when stiction keeps the motor loop from settling, the motor encoder
  still (within one count) for STILL_FACTOR settling times; and in either case the load
  encoder still (within one count) for a settling time: the slide is read at rest (it can coast
  on into the gap after the motor stopped), and the −TE term takes care of a motor that stopped
  short of its command.
  The correction moves run at their own acceleration (correction_acceleration, as a Galil
  program sets AC / DC before #CORRECT): a motor that crosses the backlash fast throws the slide
  across the gap when it meets it, and the corrections then hunt from flank to flank.
  V1 is read as the other at-rest windows are (window_centre): from the count's lower edge,
  or from its middle (count_middle), where a reading of the target or one count below it both
  put the slide within a count of the target.
  The sequence ends when |V1| and |V2| < correction_tolerance (the load is where it should
  be, and the motor where its command is: a motor left short by stiction would take the slide
  on when its integrator breaks it loose), after
  correction_max_moves, or when the load error grows beyond DIVERGED times the first one and
  DIVERGED coarse windows (the corrections drive the slide away).
"""
from __future__ import annotations

from typing import Final

from msg_defs.status import Status
from motion_ctrl.core.config import CorrectionConfig, defaults

_DONE: Final = int(Status.MOTION_DONE)
_IN_FINE: Final = int(Status.IN_FINE_POSITION)


def feedback_encoders(feedback: str) -> tuple[str, str]:
    """(position-loop encoder, velocity-loop encoder) for a `feedback` register value."""
    return {'motor': ('motor', 'motor'), 'load': ('load', 'load'),
            'dual': ('load', 'motor'), 'sampled': ('motor', 'motor')}[feedback]


STILL_FACTOR: Final = 5
# Corrections end when the load error exceeds this many times the first one (a runaway).
DIVERGED: Final = 4


class SampledCorrection:
    """The #CORRECT loop as a state machine stepped every servo tick."""

    IDLE: Final = 'idle'
    MOVING: Final = 'moving'
    CORRECTING: Final = 'correcting'
    DONE: Final = 'done'

    def __init__(self, config: CorrectionConfig | None = None):
        self.phase = self.IDLE
        self.moves = 0
        self.exhausted = False        # ended by correction_max_moves, not by the tolerance
        # Ended because the load error grew to more than DIVERGED times the one the first
        # correction was for (counts then, now), not by the tolerance.
        self.diverged: tuple[int, int] | None = None
        self._first_error: int | None = None
        self._still_ref: int | None = None
        self._still_time = 0.0
        self._load_ref: int | None = None
        self._load_still = 0.0
        self.tolerance_counts = 1
        self.near_counts = 0.0       # the coarse window [counts]: no runaway within DIVERGED of it
        self.max_moves = 0
        self.acceleration = 0.0      # of the correction moves [m/s²]
        self.settle_time = 0.0
        self.shift_counts = 0.0      # window_centre count_middle: judged from the count's middle
        self.shift = 0.0             # the same [m]
        self.counts_per_m = 1.0      # load encoder counts a metre
        self.configure(config or defaults(CorrectionConfig))

    def configure(self, config: CorrectionConfig) -> None:
        # Compare in whole counts, as Galil does: the encoder error is an integer.
        self.tolerance_counts = max(1, round(config.correction_tolerance
                                             * config.load_counts_per_m))
        self.max_moves = config.correction_max_moves
        self.acceleration = config.correction_acceleration
        self.near_counts = config.coarse_position_tolerance * config.load_counts_per_m
        self.settle_time = config.settling_time
        self.shift_counts = 0.5 if config.window_centre == 'count_middle' else 0.0
        self.shift = self.shift_counts / config.load_counts_per_m
        self.counts_per_m = config.load_counts_per_m

    def start(self) -> None:
        """A new move began: its end will be followed by corrections."""
        self.phase, self.moves, self.exhausted = self.MOVING, 0, False
        self._still_ref = self._load_ref = self._first_error = self.diverged = None

    def start_now(self) -> None:
        """`<axis>/correct`: run the correction loop from where the axis is."""
        self.phase, self.moves, self.exhausted = self.CORRECTING, 0, False
        self._still_ref = self._load_ref = self._first_error = self.diverged = None

    def cancel(self) -> None:
        self.phase = self.IDLE

    def motion_bits(self, bits: int) -> int:
        """The axis's motion bits in the sampled loop: the motor loop's settling (`bits`) says
        when the motor is there, but the axis is done only when the load is (Galil: the
        program waits for the correction loop), so MOTION_DONE and IN_FINE_POSITION follow
        the corrections while they run."""
        if self.phase == self.MOVING or self.phase == self.CORRECTING:
            return bits & ~(_DONE | _IN_FINE)
        if self.phase == self.DONE:
            return bits | _DONE | _IN_FINE
        return bits

    @property
    def correcting(self) -> bool:
        return self.phase == self.CORRECTING

    @property
    def done(self) -> bool:
        return self.phase == self.DONE

    def update(self, dt: float, *, profile_done: bool, motor_settled: bool, motor_counts: int,
               load_counts: int, load_error_counts: int, motor_error: float,
               load_error: float):
        """One tick. Returns V2 [m] to add to the motor command when a correction move is due,
        else None."""
        if self.phase not in (self.MOVING, self.CORRECTING):
            return None
        if not profile_done:
            self._still_ref = self._load_ref = None
            return None
        if self._still_ref is None or abs(motor_counts - self._still_ref) > 1:
            self._still_ref, self._still_time = motor_counts, 0.0
        else:
            self._still_time += dt
        if self._load_ref is None or abs(load_counts - self._load_ref) > 1:
            self._load_ref, self._load_still = load_counts, 0.0
        else:
            self._load_still += dt
        if not motor_settled and self._still_time + 1e-9 < STILL_FACTOR * self.settle_time:
            return None
        if self._load_still + 1e-9 < self.settle_time:
            return None
        v2 = load_error - self.shift - motor_error          # V2 = V1 − TE
        v1_counts = load_error_counts - self.shift_counts
        if (abs(v1_counts) < self.tolerance_counts and abs(
                v1_counts - motor_error * self.counts_per_m) < self.tolerance_counts):
            # (V2 too, as Galil's JP#END,@ABS[V2]<2: a motor that stopped short of its
            # command, held by stiction, goes on when its integrator breaks it loose and takes
            # the slide along; the correction by V2 moves its command to where it stands)
            self.phase = self.DONE
            return None
        if self.moves >= self.max_moves:
            self.phase, self.exhausted = self.DONE, True
            return None
        first = self._first_error
        if first is not None and abs(load_error_counts) > DIVERGED * max(abs(first),
                                                                          self.near_counts):
            # Galil's loop would go on. Corrections may overshoot on their way in: a few counts
            # of correction across the backlash can leave the slide ~20 counts the other side.
            # An error several times the first one, and several coarse windows out, means they
            # drive the slide away (stale or wrong readings, a slipping or blocked slide): stop.
            self.phase, self.diverged = self.DONE, (first, load_error_counts)
            return None
        if first is None:
            self._first_error = load_error_counts
        self.moves += 1
        self.phase = self.CORRECTING
        self._still_ref = self._load_ref = None
        return v2
