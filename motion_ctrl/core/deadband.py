"""Delta RMC Output Deadband and Deadband Tolerance (RMCTools help, shared/seeds/000).

Registers: ``<axis>.output_deadband`` (V, >= 0) and ``<axis>.deadband_tolerance`` (m, >= 0).

The rule, briefly (RMC wording in quotes):

* Output Deadband: added to the control output by the sign of the output, in the closed-loop
  modes only ("The Deadband compensation applies to all the closed-loop control modes").  An
  output of exactly 0 gets nothing.
* Deadband Ratioing (position modes): "If the Deadband Output is non-zero, the target velocity
  is zero, and the absolute value of the Position Error is less than the Deadband Tolerance,
  only a fraction of the Output Deadband, proportional to the Position Error, is applied."
  Here: ``deadband * |error| / tolerance`` (half the deadband at half the tolerance).  Outside
  the tolerance, or while the target moves, the full deadband is applied.
* Velocity (and pressure/force-only) modes: "If the Deadband Tolerance value is non-zero, then
  the Output Deadband will not apply if the Target Velocity is zero.  Otherwise, the value of
  the Deadband Tolerance has no meaning."  No ratioing there.
* Anti-hunting (position modes): "When the target is stopped, and the Position Error is less
  than the Deadband Tolerance or less than the position corresponding to one half of a
  transducer Raw Count, then the Integral Output Term will only be allowed to wind down ...
  this works even if the Output Deadband is 0.  If the Deadband Tolerance is zero, this still
  works with the window defined by ... one half of a transducer Raw Count."

Pure functions, plain Python (no rclpy), deterministic.  The caller decides whether the loop is
closed and which mode the axis is in.
"""

import math

__all__ = ['output_deadband', 'apply_deadband', 'anti_hunting', 'in_anti_hunting_window',
           'limit_integral_to_wind_down']


def _check_non_negative(name, value):
    if not (isinstance(value, (int, float)) and value >= 0 and math.isfinite(value)):
        raise ValueError(f'{name} must be a finite number >= 0, got {value!r}')


def output_deadband(output, deadband, error, tolerance, target_stopped, position_mode):
    """Return ``output`` with the RMC Output Deadband added by its sign (closed loop only: the
    caller ensures that).

    output         control output before the deadband, V
    deadband       Output Deadband, V (>= 0)
    error          position error (target - actual), m; only its magnitude is used
    tolerance      Deadband Tolerance, m (>= 0; 0 = no ratioing / no velocity-mode rule)
    target_stopped the target (position mode) or target velocity (velocity mode) is at rest
    position_mode  True for Position PID / I-PD, False for Velocity PID / I-PD

    Position modes: full deadband, except while the target is stopped and
    ``|error| < tolerance``: then ``deadband * |error| / tolerance``.
    Velocity modes: full deadband, except none at all while the target velocity is zero and the
    tolerance is non-zero.  ValueError on a negative or non-finite deadband / tolerance.
    """
    _check_non_negative('deadband', deadband)
    _check_non_negative('tolerance', tolerance)
    return apply_deadband(output, deadband, error, tolerance, bool(target_stopped),
                          bool(position_mode))


def apply_deadband(output: float, deadband: float, error: float, tolerance: float,
                   target_stopped: bool, position_mode: bool) -> float:
    """output_deadband without the argument checks: for the servo tick, whose registers were
    validated when they were set."""
    if output == 0 or deadband == 0:
        return output
    if position_mode:
        err = abs(error)
        if target_stopped and tolerance > 0 and err < tolerance:
            applied = deadband * err / tolerance
        else:
            applied = deadband
    else:
        applied = 0.0 if (tolerance != 0 and target_stopped) else deadband
    return output + applied if output > 0 else output - applied


def anti_hunting(target_stopped, error, tolerance, half_count):
    """True when the integral term may only wind down (RMC anti-hunting; position modes).

    ``target_stopped`` and (``|error| < tolerance`` or ``|error| < half_count``), where
    ``half_count`` is the position of half a raw transducer count, m (e.g. 0.5 / counts_per_m).
    Independent of the Output Deadband; with ``tolerance`` 0 only the half-count window is left.
    """
    _check_non_negative('tolerance', tolerance)
    _check_non_negative('half_count', half_count)
    return in_anti_hunting_window(bool(target_stopped), error, tolerance, half_count)


def in_anti_hunting_window(target_stopped: bool, error: float, tolerance: float,
                           half_count: float) -> bool:
    """anti_hunting without the argument checks (the servo tick's registers are validated)."""
    if not target_stopped:
        return False
    err = abs(error)
    return err < tolerance or err < half_count


def limit_integral_to_wind_down(previous: float, proposed: float) -> float:
    """Integral term allowed while anti-hunting is active: it may only move toward zero.

    Returns ``proposed`` when it has the same sign as ``previous`` and no larger magnitude,
    ``0.0`` when it would cross zero (it may wind down to zero, not beyond), and ``previous``
    when it would grow in magnitude (including any move away from an integral of exactly 0).
    """
    if proposed == 0:
        return 0.0
    if previous > 0:
        if proposed < 0:
            return 0.0
        return proposed if proposed <= previous else previous
    if previous < 0:
        if proposed > 0:
            return 0.0
        return proposed if proposed >= previous else previous
    return 0.0 if previous == 0 else previous  # at 0 (or NaN): nothing to wind down
