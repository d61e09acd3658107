"""PMAC-style backlash and leadscrew compensation for one servo axis.

Plain Python (no rclpy), deterministic, stepped with an explicit ``dt``.
SI units throughout: positions in metres (load units), rates in m/s, time in s.

Turbo PMAC parameters modelled here
-----------------------------------
* **Ixx86 backlash distance** -> ``distance`` (m).  A positive value adds extra
  motor travel on a reversal, which is what real backlash needs.  A negative
  value is accepted (the manual's only use for it is a slave geared to an axis
  with more backlash than its own).
* **Ixx85 take-up rate** -> ``takeup_rate`` (m/s).  PMAC adds Ixx85 per
  *background cycle*; here the rate is per *second* and the register moves by
  at most ``takeup_rate * dt`` per ``step()``.  ``takeup_rate == 0`` means
  "no ramp": the backlash is introduced or removed at once (a step) on the
  tick where the reversal is detected.
* **Ixx87 reversal hysteresis** -> ``hysteresis`` (m).  A reversal is detected
  only once the net commanded position has moved *more than* ``hysteresis`` in
  the new direction from the extreme point reached in the old direction (the
  running maximum while moving positive, the running minimum while moving
  negative).  A dither smaller than the hysteresis therefore never flips the
  direction.  Consequence: the take-up starts ``hysteresis`` after the real
  reversal point, exactly as on PMAC.
* **DEFINE BLCOMP** -> ``backlash_table`` / ``backlash_table_spacing``: a
  position-dependent backlash amount, interpolated from the table and *added
  to Ixx86*, active only while the direction is negative.  Typically it holds
  the difference between the positive-going and negative-going calibration.
* **DEFINE COMP** -> ``leadscrew_table`` / ``leadscrew_table_spacing``: the
  leadscrew error correction, applied in both directions.

Tables have uniform spacing starting at position 0 (entry ``i`` sits at
``i * spacing``), are linearly interpolated and hold their end values outside
their range (no roll-over, unlike PMAC's table modulo).  They are indexed by
the *nominal* commanded position passed to ``step()``.

One-sided (PMAC) convention, not LinuxCNC's +/- b/2
---------------------------------------------------
At start-up (and after ``reset()``: homing in the positive direction, abort)
the nut is assumed to bear on the flank that drives positive, so nothing is
applied while moving positive.  On a reversal to negative the backlash
register ramps toward ``distance + backlash_table(position)``; on the
reversal back to positive it ramps to 0.  As on PMAC the register is
*subtracted* from the nominal commanded position, so the correction returned
by ``step()`` is::

    correction = -register + leadscrew_table(commanded_position)

Position-dependent target: while the axis keeps moving negative with a
non-empty backlash table, the register's target changes along the travel.
The register follows it, again at most ``takeup_rate`` m/s (instantly when the
rate is 0), so a steep table combined with a slow take-up rate lags behind.

Hidden from reported position
-----------------------------
The correction only feeds the servo loop: the motor-loop target is
``commanded_position + correction`` (see :func:`apply_correction` and
:attr:`BacklashCompensation.motor_position`).  The caller must keep reporting
the *nominal* commanded position (:attr:`BacklashCompensation.nominal_position`)
as "commanded"; this class never hands back a corrected value under that name
and never modifies what it is given.
"""

import math
from numbers import Real

from motion_ctrl.core.config import BacklashConfig, defaults

__all__ = ["interpolate_table", "apply_correction", "BacklashCompensation"]


def _finite(name, value):
    """Return ``value`` as float if it is a finite real number, else raise ValueError."""
    if isinstance(value, bool) or not isinstance(value, Real):
        raise ValueError(f"{name} must be a finite number, got {value!r}")
    value = float(value)
    if not math.isfinite(value):
        raise ValueError(f"{name} must be finite, got {value!r}")
    return value


def interpolate_table(table, spacing, position) -> float:
    """Linearly interpolate a uniformly spaced compensation table.

    Entry ``i`` of ``table`` sits at ``i * spacing`` (the table starts at
    position 0).  Between entries the value is interpolated linearly; below 0
    the first entry is held, beyond ``(len(table) - 1) * spacing`` the last.
    An empty table gives 0.0.  ``spacing`` must be > 0 when the table is
    non-empty; ``position`` must be finite (ValueError otherwise).
    """
    n = len(table)
    if n == 0:
        return 0.0
    if not spacing > 0.0 or not math.isfinite(spacing):
        raise ValueError(f"spacing must be finite and > 0 for a non-empty table, got {spacing!r}")
    position = float(position)
    if not math.isfinite(position):
        raise ValueError(f"position must be finite, got {position!r}")
    if n == 1 or position <= 0.0:
        return float(table[0])
    x = position / spacing
    if x >= n - 1:
        return float(table[n - 1])
    i = int(math.floor(x))
    frac = x - i
    a = float(table[i])
    b = float(table[i + 1])
    return a + (b - a) * frac


def apply_correction(nominal_position: float, correction: float) -> float:
    """Motor-loop target = nominal commanded position + correction.

    Use the result only as the servo loop's position command.  Report the
    *nominal* position as "commanded": the backlash and leadscrew correction
    is hidden from position reporting, as on PMAC.
    """
    return float(nominal_position) + float(correction)


class BacklashCompensation:
    """Backlash (Ixx85/86/87 + DEFINE BLCOMP) and leadscrew (DEFINE COMP) compensation.

    Call :meth:`configure` (optional; defaults are all zero = no compensation),
    :meth:`reset` at start-up / after positive homing / after an abort, then
    :meth:`step` every servo tick with the nominal commanded position.  Add the
    returned correction to the motor position command only.

    If :meth:`step` is called before any :meth:`reset`, the first step acts
    as ``reset(commanded_position)`` followed by a normal step.
    """

    def __init__(self, config: BacklashConfig | None = None):
        # state
        self._direction = 1
        self._register = 0.0
        self._target = 0.0
        self._extreme: float | None = None   # running extreme in the current direction
        self._nominal: float | None = None   # last nominal commanded position seen
        self._correction = 0.0
        self.configure(config or defaults(BacklashConfig))

    # ------------------------------------------------------------------ config
    def configure(self, config: BacklashConfig) -> None:
        """Set the compensation registers (all SI: m, m/s), validated by the register table:
        ``backlash_distance`` (Ixx86, m, any sign); ``backlash_takeup_rate`` (Ixx85, m/s; 0 =
        introduce/remove the backlash at once, as a step); ``backlash_hysteresis`` (Ixx87, m);
        ``backlash_table`` (DEFINE BLCOMP, m, added to the distance while moving negative) and
        ``leadscrew_table`` (DEFINE COMP, m, added to the correction in both directions), each
        with a spacing (m), > 0 while the table is set.

        The running state (direction, register) is kept; a changed target is reached by the
        normal ramp on the following steps.
        """
        self._distance = config.backlash_distance
        self._takeup_rate = config.backlash_takeup_rate
        self._hysteresis = config.backlash_hysteresis
        self._bl_table = config.backlash_table
        self._bl_spacing = config.backlash_table_spacing
        self._ls_table = config.leadscrew_table
        self._ls_spacing = config.leadscrew_table_spacing

    # ------------------------------------------------------------------- state
    def reset(self, commanded_position: float) -> None:
        """Start-up / after homing positive / after abort.

        Direction positive, register 0, reversal reference (running extreme)
        at ``commanded_position``.  ``correction`` becomes the leadscrew value
        at that position (what :meth:`step` would return there at rest).
        """
        pos = _finite("commanded_position", commanded_position)
        self._direction = 1
        self._register = 0.0
        self._target = 0.0
        self._extreme = pos
        self._nominal = pos
        self._correction = self._leadscrew(pos)

    def step(self, commanded_position: float, dt: float) -> float:
        """Advance one servo tick; return the correction (m) to ADD to the motor command.

        ``commanded_position`` is the nominal commanded position (m, load
        units); it is not modified and stays the position to report.  ``dt``
        (s) must be finite and >= 0.  Returns
        ``-register + leadscrew_table(commanded_position)``.
        """
        pos = _finite("commanded_position", commanded_position)
        dt = _finite("dt", dt)
        if dt < 0.0:
            raise ValueError(f"dt must be >= 0, got {dt!r}")
        if self._extreme is None:
            self.reset(pos)

        # 1. reversal detection against the running extreme (Ixx87)
        if self._direction > 0:
            if pos > self._extreme:
                self._extreme = pos
            elif self._extreme - pos > self._hysteresis:
                self._direction = -1
                self._extreme = pos
        else:
            if pos < self._extreme:
                self._extreme = pos
            elif pos - self._extreme > self._hysteresis:
                self._direction = 1
                self._extreme = pos

        # 2. target: Ixx86 + BLCOMP(pos) moving negative, 0 moving positive
        if self._direction < 0:
            target = self._distance + interpolate_table(self._bl_table, self._bl_spacing, pos)
        else:
            target = 0.0
        self._target = target

        # 3. ramp the register toward the target at most takeup_rate*dt (Ixx85)
        if self._takeup_rate == 0.0:
            self._register = target
        else:
            max_step = self._takeup_rate * dt
            delta = target - self._register
            if abs(delta) <= max_step:
                self._register = target
            else:
                self._register += math.copysign(max_step, delta)

        # 4. correction: register subtracted, leadscrew added (both directions)
        self._nominal = pos
        self._correction = -self._register + self._leadscrew(pos)
        return self._correction

    def _leadscrew(self, pos):
        return interpolate_table(self._ls_table, self._ls_spacing, pos)

    # -------------------------------------------------------------- read-only
    @property
    def register(self) -> float:
        """Current backlash register (m); >= 0 for a positive distance and table."""
        return self._register

    @property
    def target(self) -> float:
        """Value the register is ramping toward (m)."""
        return self._target

    @property
    def direction(self) -> int:
        """Detected commanded direction: +1 or -1."""
        return self._direction

    @property
    def active(self) -> bool:
        """Status bit BACKLASH_ACTIVE: register non-zero or still ramping to its target."""
        return self._register != 0.0 or self._register != self._target

    @property
    def correction(self) -> float:
        """The last value :meth:`step` returned (m)."""
        return self._correction

    @property
    def nominal_position(self) -> float | None:
        """Last nominal commanded position passed in: the one to REPORT (None before any)."""
        return self._nominal

    @property
    def motor_position(self) -> float | None:
        """Motor-loop target = nominal + correction. Servo use only, never report it as
        commanded."""
        if self._nominal is None:
            return None
        return apply_correction(self._nominal, self._correction)

    @property
    def distance(self) -> float:
        """Ixx86 backlash distance (m)."""
        return self._distance

    @property
    def takeup_rate(self) -> float:
        """Ixx85 take-up rate (m/s); 0 = step."""
        return self._takeup_rate

    @property
    def hysteresis(self) -> float:
        """Ixx87 reversal hysteresis (m)."""
        return self._hysteresis
