"""Soft limits on the commanded position (Galil BL / FL, PMAC Ixx13 / Ixx14): keeping a jog or a
stop inside them by planning the profile's braking.

A target outside the limits is refused by the axis; this module handles what a target check
cannot: a jog runs on until told, and a STOP's deceleration may carry the command past a limit.

* `brake_within`: after a jog or stop was planned, if its planned travel crosses a limit, plan a
  stop at the limit instead;
* `due`: while a jog heads for a limit, whether the distance left is down to what braking at
  max_acceleration needs (jerk-limited if max_jerk > 0), plus two ticks of travel;
* `stop_at`: the re-plan itself, a position move to the limit that cruises no faster than now
  (or than the jog) and brakes at the given deceleration, or at the deceleration it takes
  (about v²/2d), at most the hardest allowed (estop_deceleration).

Each function plans on the `Profile` (ruckig takes the limits) and reports what it did; the axis
keeps the books (LIMIT bit, settling events, the target). Positions are in the profile's (loop)
frame. Plain Python, no ROS.
"""
from __future__ import annotations

from typing import Final

import math

from motion_ctrl.core.profile import Profile

# ruckig's extrema carry float residue; a limit is "passed" only by more than this [m].
EPS: Final = 1e-9


def stopping_distance(speed: float, acceleration: float, max_acceleration: float,
                      max_jerk: float) -> float:
    """Distance [m] to rest from `speed` (>= 0) with `acceleration` along the motion (> 0 =
    speeding up), braking at max_acceleration, jerk-limited at max_jerk (0 = trapezoid).

    Exact for the trapezoid; with a jerk limit an acceleration still speeding up is first
    ramped to 0 (speed + a²/2j, travelled at that speed: an upper bound)."""
    a_max = max_acceleration
    if max_jerk <= 0.0:
        return speed * speed / (2.0 * a_max)
    j = max_jerk
    extra = 0.0
    if acceleration > 0.0:
        ramp = acceleration / j
        speed += acceleration * acceleration / (2.0 * j)
        extra = speed * ramp
    if speed * j >= a_max * a_max:
        return extra + 0.5 * speed * (speed / a_max + a_max / j)
    return extra + speed * math.sqrt(speed / j)


def crossed(p: Profile, lo: float, hi: float) -> float | None:
    """The limit the planned segment crosses from inside (None if it stays within)."""
    if p.done:
        return None
    a, b = p.raw_extrema()
    start = p.raw_position
    if b > hi + EPS and start <= hi:
        return hi
    if a < lo - EPS and start >= lo:
        return lo
    return None


def due(p: Profile, direction: int, lo: float, hi: float, dt: float, max_acceleration: float,
        max_jerk: float) -> float | None:
    """A jog toward the limit on side `direction` (+1: hi, -1: lo): the limit, when braking
    must start now; None while there is room (or while not moving toward it)."""
    v = p.raw_velocity * direction
    if v <= 0.0:
        return None
    limit = hi if direction > 0 else lo
    left = (limit - p.raw_position) * direction
    need = stopping_distance(v, p.raw_acceleration * direction, max_acceleration, max_jerk)
    return limit if left <= need + 2.0 * v * dt else None


def stop_at(p: Profile, limit: float, decel: float, hardest: float, max_velocity: float,
            lo: float, hi: float) -> bool:
    """Re-plan `p` as a position move to `limit`: cruise no faster than now (or than the jog),
    brake at `decel`, harder where that would pass the limit (up to `hardest`). False when
    ruckig refused every plan (the caller then stops as hard as allowed)."""
    speed = abs(p.raw_velocity)
    vcap = speed
    if p.target_velocity:
        vcap = max(vcap, abs(p.target_velocity))
    vcap = max(min(vcap, max_velocity), 1e-9)
    left = abs(limit - p.raw_position)
    hard = max(decel, hardest)
    tries = [decel]
    needed = speed * speed / (2.0 * left) if left > 0.0 else math.inf
    for factor in (1.02, 1.25):
        if decel < needed * factor < hard:
            tries.append(needed * factor)
    tries.append(hard)
    planned = False
    for a in tries:
        try:
            p.move_to(limit, vcap, a)
        except ValueError:
            continue
        planned = True
        a_lo, a_hi = p.raw_extrema()
        if a_lo >= lo - EPS and a_hi <= hi + EPS:
            break
    return planned
