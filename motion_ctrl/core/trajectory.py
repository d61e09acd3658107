"""Coordinated multi-axis trajectories (issue 16): a trajectory_msgs/JointTrajectory run as PVT.

The vendor rules implemented:

* Turbo PMAC "PVT" move mode (PVT{time}, Turbo PMAC User Manual, "Position-Velocity-Time Mode
  Moves"): every point gives a position and a velocity at a time, and the segment between two
  points is the cubic Hermite polynomial that meets both ends' position and velocity. All axes
  share the point times, so they move as one.
* ros2_control joint_trajectory_controller (its interpolation "splines"): which polynomial a
  segment gets depends on what the points carry: positions, velocities and accelerations ->
  quintic Hermite (p, v, a at both ends); positions and velocities -> cubic Hermite (= PMAC
  PVT); positions only -> here a C2 cubic spline through all points (the controller's
  positions-only rule is linear, which steps the velocity at every point: a servo axis
  would follow it with a jerk at each point). As there, the axis's current commanded state
  is an implicit point at t=0: a trajectory whose first point is later than 0 begins with a
  smooth segment from where the axis is (position, velocity, and acceleration in the quintic
  case) to that point, and one that replaces a running trajectory continues from its state
  without a step. A first point at t=0 must be where the axis is (START_TOLERANCE), else
  it would step the command: it is refused, not jumped to.

Interpolation (scipy.interpolate), per kind:

* 'quintic' (velocities and accelerations on every point): the quintic Hermite of
  BPoly.from_derivatives with [p, v, a] at each point (its Bernstein coefficients computed
  for all segments at once, see _quintic_hermite), the start point with the axis's own p, v, a;
* 'cubic' (velocities on every point): CubicHermiteSpline with [p, v]; the axis's own p, v
  at the start (its acceleration steps there and at every point, as on a PMAC);
* 'spline' (positions only): CubicSpline through the start position and all points, clamped at
  both ends: velocity = the axis's own velocity at t=0 and 0 at the last point, so it ends at
  rest; C2 (position, velocity and acceleration continuous) at every point.

Every trajectory ends at rest: the last point's velocity (and acceleration, if given) must be 0
(REST_TOLERANCE); after the last time the command holds the last position with velocity and
acceleration 0.

Checks, on the trajectory as a whole before it starts (`check`, `Trajectory.build`), in this
order: joint names (non-empty, no duplicate, each an axis), array lengths (velocities /
accelerations on every point or on none), times (finite, >= 0, strictly increasing), numbers
finite, the start (a point at t=0 where the axis is), the end at rest, each point inside the
soft limits, then the interpolated motion: |velocity| <= max_velocity, |acceleration| <=
max_acceleration and the position inside the soft limits between the points (a spline can
overshoot). These use each polynomial's exact extrema, not samples: a segment's extreme values
are at its two ends or where the next derivative is zero (PPoly.roots of that derivative), so
an overshoot between points of any width is found. Soft limits are always on (registers.py
requires soft_limit_min < soft_limit_max; there is no "off" value; ±inf is no limit). A
trajectory planned exactly at a limit passes: LIMIT_TOLERANCE.

Plain Python (numpy, scipy), no rclpy, deterministic.
"""
from __future__ import annotations

import bisect
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING, NamedTuple

import numpy as np

if TYPE_CHECKING:
    from scipy.interpolate import BPoly, PPoly      # (annotations only)
# scipy's interpolate / optimize / spatial are imported where used (python -X importtime, the
# servo loop loaded: interpolate 0.5-0.7 s, optimize and spatial ~0.4 s each alone): what does
# not build a trajectory does not pay for them (core.coordination, and so ServoLoop, imports this
# module). The controller node imports them before its loop runs (ros.targets.PRELOAD):
# imported on its first trajectory, they stalled the loop.

__all__ = ['AxisLimits', 'AxisPath', 'AxisState', 'Points', 'Trajectory', 'check', 'circle',
           'rounded_square', 'contour_error', 'START_TOLERANCE', 'REST_TOLERANCE',
           'LIMIT_TOLERANCE']

# A first point at t=0 "is" the axis's state within this (m, m/s, m/s²): far below a count
# (2.54 µm) yet above the rounding of a state read back from the controller and sent again.
START_TOLERANCE = 1e-9
# The last point's velocity (m/s) and acceleration (m/s²) count as 0 within this; the hold
# after the end is then exactly 0.
REST_TOLERANCE = 1e-9
# Soft limits: absolute, m (as core.soft_limits.EPS). max_velocity / max_acceleration: relative, so
# a trajectory planned exactly at a limit is not refused for the rounding of its polynomials.
LIMIT_TOLERANCE = 1e-9



class AxisState(NamedTuple):
    """Commanded state of one axis: m, m/s, m/s²."""
    position: float
    velocity: float = 0.0
    acceleration: float = 0.0


@dataclass(frozen=True)
class AxisLimits:
    """An axis's limits, as its registers of the same names (m, m/s, m/s²)."""
    soft_limit_min: float
    soft_limit_max: float
    max_velocity: float
    max_acceleration: float

    @classmethod
    def from_registers(cls, r: Mapping) -> AxisLimits:
        return cls(float(r['soft_limit_min']), float(r['soft_limit_max']),
                   float(r['max_velocity']), float(r['max_acceleration']))


class Points(NamedTuple):
    """Trajectory points, as a JointTrajectory carries them: times (n,) in s from the start,
    positions (n, axes) m, velocities / accelerations (n, axes) or None."""
    times: np.ndarray
    positions: np.ndarray
    velocities: np.ndarray | None = None
    accelerations: np.ndarray | None = None


# ------------------------------------------------------------------------------- validation

def _names_reason(names: Sequence[str], known: Mapping[str, AxisLimits]) -> str | None:
    if len(names) == 0:
        return 'joint_names is empty'
    seen: set[str] = set()
    for name in names:
        if name in seen:
            return f'joint_names: {name!r} is given twice'
        seen.add(name)
        if name not in known:
            return (f'joint_names: {name!r} is not an axis of this controller '
                    f'(axes: {", ".join(known)})')
    return None


def _per_point(what: str, rows, n_points: int, n_axes: int, names) -> np.ndarray | None | str:
    """velocities / accelerations: None when on no point, (points, axes) when on every point,
    else the reason (a wrong length, or given on some points only)."""
    if rows is None or len(rows) == 0:
        return None
    if len(rows) != n_points:
        return f'{len(rows)} lists of {what} for {n_points} points'
    sizes = [len(row) for row in rows]
    for i, size in enumerate(sizes):
        if size not in (0, n_axes):
            return (f'point {i}: {size} {what} for {n_axes} joint_names ({", ".join(names)})')
    if all(size == 0 for size in sizes):
        return None
    if any(size == 0 for size in sizes):
        have, lack = sizes.index(n_axes), sizes.index(0)
        return (f'{what} on some points only (point {have} has them, point {lack} has none): '
                f'give {what} on every point or on none')
    return np.array(rows, dtype=float)


def _arrays(names, times, positions, velocities, accelerations):
    """(t, P, V, A) as float arrays, or the reason they do not fit together."""
    n_axes = len(names)
    if len(positions) == 0:
        return 'the trajectory has no points'
    if len(times) != len(positions):
        return f'{len(times)} times for {len(positions)} points'
    for i, row in enumerate(positions):
        if len(row) != n_axes:
            return f'point {i}: {len(row)} positions for {n_axes} joint_names ({", ".join(names)})'
    V = _per_point('velocities', velocities, len(positions), n_axes, names)
    A = _per_point('accelerations', accelerations, len(positions), n_axes, names)
    for r in (V, A):
        if isinstance(r, str):
            return r
    if A is not None and V is None:
        return 'accelerations without velocities: give velocities with them'
    return np.array(times, dtype=float), np.array(positions, dtype=float), V, A


def _times_reason(t: np.ndarray) -> str | None:
    for i, ti in enumerate(t):
        if not math.isfinite(ti):
            return f'point {i}: time_from_start {ti} s is not finite'
        if ti < 0:
            return f'point {i}: time_from_start {ti:g} s is negative'
        if i and not ti > t[i - 1]:
            return (f'point {i}: time_from_start {ti:g} s is not after point {i - 1}\'s '
                    f'{t[i - 1]:g} s (times must increase strictly)')
    return None


_UNITS = (('position', 'm'), ('velocity', 'm/s'), ('acceleration', 'm/s²'))


def _finite_reason(names, arrays, start: Sequence[AxisState]) -> str | None:
    for j, name in enumerate(names):
        for (what, unit), value in zip(_UNITS, start[j]):
            if not math.isfinite(value):
                return f'{name}: the axis\'s {what} {value} {unit} is not finite'
    for (what, unit), X in zip(_UNITS, arrays):
        if X is None:
            continue
        bad = np.argwhere(~np.isfinite(X))
        if len(bad):
            i, j = bad[0]
            return f'{names[j]}: point {i} {what} {X[i, j]} {unit} is not finite'
    return None


def _ends_reason(names, t, arrays, start: Sequence[AxisState]) -> str | None:
    """A point at t=0 must be the axis's state; the last point must be at rest."""
    last = len(t) - 1
    for j, name in enumerate(names):
        for (what, unit), X, own in zip(_UNITS, arrays, start[j]):
            if X is None:
                continue
            if t[0] == 0 and abs(X[0, j] - own) > START_TOLERANCE:
                return (f'{name}: point 0 at t=0 has {what} {X[0, j]:.9g} {unit}, the axis is '
                        f'at {own:.9g} {unit}: the trajectory starts away from the axis: give '
                        f'the first point a time_from_start > 0')
            if what != 'position' and abs(X[last, j]) > REST_TOLERANCE:
                return (f'{name}: the last point ({last}) has {what} {X[last, j]:.6g} {unit}: '
                        f'the last point must have {what} 0 (a trajectory ends at rest)')
    if len(t) == 1 and t[0] == 0:
        return 'the only point is at t=0, where the axis already is: nothing to move'
    return None


def _points_in_limits_reason(names, P: np.ndarray, limits) -> str | None:
    for j, name in enumerate(names):
        lo, hi = limits[name].soft_limit_min, limits[name].soft_limit_max
        for i, p in enumerate(P[:, j]):
            if p > hi + LIMIT_TOLERANCE:
                return f'{name}: point {i} position {p:.9g} m is above soft_limit_max {hi:g} m'
            if p < lo - LIMIT_TOLERANCE:
                return f'{name}: point {i} position {p:.9g} m is below soft_limit_min {lo:g} m'
    return None


# --------------------------------------------------------------------------- interpolation

def _interpolant(t, P, V, A, start: Sequence[AxisState]):
    """(kind, knot times, position polynomial of all axes, offset of point 0 among the knots):
    the axis's state is the knot at t=0 (inserted before point 0, or point 0 itself)."""
    # (here: scipy.interpolate costs 0.5-0.7 s at load, -X importtime: see the top)
    from scipy.interpolate import CubicHermiteSpline, CubicSpline
    s = np.array(start, dtype=float)          # (axes, 3): p, v, a
    if t[0] > 0:
        x = np.concatenate([[0.0], t])
        P = np.vstack([s[:, 0], P])
        V = None if V is None else np.vstack([s[:, 1], V])
        A = None if A is None else np.vstack([s[:, 2], A])
        offset = 1
    else:
        x, P = t, P.copy()
        P[0] = s[:, 0]                        # within START_TOLERANCE: the axis's own value
        offset = 0
    if V is None:
        spline = CubicSpline(x, P, bc_type=((1, s[:, 1]), (1, np.zeros(len(s)))))
        return 'spline', x, spline, offset
    V = V.copy()
    V[0], V[-1] = s[:, 1], 0.0
    if A is None:
        return 'cubic', x, CubicHermiteSpline(x, P, V), offset
    A = A.copy()
    A[0], A[-1] = s[:, 2], 0.0
    return 'quintic', x, _quintic_hermite(x, P, V, A), offset


def _quintic_hermite(x, P, V, A) -> BPoly:
    """The quintic Hermite of BPoly.from_derivatives(x, [[p, v, a], ...]), its Bernstein
    coefficients computed for all segments at once: from_derivatives builds them segment by
    segment in Python (90 µs a segment: 0.86 s for 9,476 points, which would hold up the
    servo executor), and its result is the same (test_trajectory compares the two).
    On [0, h], p(0) = c0, p'(0) = 5 (c1 - c0) / h, p''(0) = 20 (c2 - 2 c1 + c0) / h², and the
    mirror image at h."""
    # (here: scipy.interpolate costs 0.5-0.7 s at load, -X importtime: see the top)
    from scipy.interpolate import BPoly
    h = np.diff(x)[:, None]
    p0, v0, a0, p1, v1, a1 = P[:-1], V[:-1], A[:-1], P[1:], V[1:], A[1:]
    c = np.stack([p0, p0 + v0 * h / 5, p0 + 2 * v0 * h / 5 + a0 * h ** 2 / 20,
                  p1 - 2 * v1 * h / 5 + a1 * h ** 2 / 20, p1 - v1 * h / 5, p1])
    return BPoly(c, x)


def _candidates(pp: PPoly, order: int):
    """Where the order-th derivative of a one-axis PPoly can be extreme, exactly: both ends of
    every segment (each end with its own segment's value: a cubic's acceleration steps at the
    points) and the real roots of the next derivative inside. Returns (times, values,
    segment index)."""
    d = pp.derivative(order) if order else pp
    x, h = pp.x, np.diff(pp.x)
    m = len(h)
    right = np.zeros(m)
    for row in d.c:                           # Horner at each segment's local end h
        right = right * h + row
    roots = d.derivative().roots(discontinuity=False, extrapolate=False)
    roots = roots[np.isfinite(roots)]
    seg = np.clip(np.searchsorted(x, roots, side='right') - 1, 0, m - 1)
    times = np.concatenate([x[:-1], x[1:], roots])
    values = np.concatenate([d.c[-1], right, d(roots)])
    return times, values, np.concatenate([np.arange(m), np.arange(m), seg])


def _between(seg: int, x, offset: int) -> str:
    end = seg + 1 - offset
    begin = 'the start (t=0)' if end == 0 else f'point {end - 1} (t={x[seg]:g} s)'
    return f'between {begin} and point {end} (t={x[seg + 1]:g} s)'


def _motion_reason(names, x, ppolys, positions, offset, limits) -> str | None:
    """Interpolated |velocity|, |acceleration| and position (`positions`: each axis's
    _candidates of order 0) against each axis's limits."""
    for order, (what, unit), register in ((1, _UNITS[1], 'max_velocity'),
                                          (2, _UNITS[2], 'max_acceleration')):
        for name, pp in zip(names, ppolys):
            limit = getattr(limits[name], register)
            times, values, seg = _candidates(pp, order)
            k = int(np.argmax(np.abs(values)))
            if abs(values[k]) > limit * (1 + LIMIT_TOLERANCE):
                return (f'{name}: {what} {values[k]:.6g} {unit} at t={times[k]:.6g} s, '
                        f'{_between(seg[k], x, offset)}, exceeds {register} {limit:g} {unit}')
    for name, (times, values, seg) in zip(names, positions):
        lo, hi = limits[name].soft_limit_min, limits[name].soft_limit_max
        hit = None
        k = int(np.argmax(values))
        if values[k] > hi + LIMIT_TOLERANCE:
            hit = k, f'above soft_limit_max {hi:g} m'
        k = int(np.argmin(values))
        if hit is None and values[k] < lo - LIMIT_TOLERANCE:
            hit = k, f'below soft_limit_min {lo:g} m'
        if hit is not None:
            k, side = hit
            return (f'{name}: the path reaches {values[k]:.9g} m at t={times[k]:.6g} s, '
                    f'{_between(seg[k], x, offset)}, {side} (the interpolation overshoots '
                    'between the points)')
    return None


def _plan(names, times, positions, velocities, accelerations, start, limits):
    """Trajectory or the reason it is refused (see the module docstring for the order)."""
    # (here: scipy.interpolate costs 0.5-0.7 s at load, -X importtime: see the top)
    from scipy.interpolate import PPoly
    reason = _names_reason(names, limits)
    if reason:
        return reason
    missing = [n for n in names if n not in start]
    if missing:
        return f'no start state for {", ".join(missing)}'
    try:
        r = _arrays(names, times, positions, velocities, accelerations)
    except (TypeError, ValueError) as exc:      # a number that is not one, a row that is not
        return f'the points are not arrays of numbers: {exc}'
    if isinstance(r, str):
        return r
    t, P, V, A = r
    own = [AxisState(*(float(v) for v in start[n])) for n in names]
    reason = (_times_reason(t) or _finite_reason(names, (P, V, A), own)
              or _ends_reason(names, t, (P, V, A), own)
              or _points_in_limits_reason(names, P, limits))
    if reason:
        return reason
    kind, x, poly, offset = _interpolant(t, P, V, A, own)
    pp = poly if isinstance(poly, PPoly) else PPoly.from_bernstein_basis(poly)
    ppolys = [PPoly(pp.c[..., j], pp.x) for j in range(len(names))]
    positions = [_candidates(q, 0) for q in ppolys]
    reason = _motion_reason(names, x, ppolys, positions, offset, limits)
    if reason:
        return reason
    extrema = {n: (float(v.min()), float(v.max())) for n, (_, v, _) in zip(names, positions)}
    return Trajectory(tuple(names), kind, x, poly, ppolys, extrema)


def check(names: Sequence[str], times, positions, velocities=None, accelerations=None, *,
          start: Mapping[str, Sequence[float]],
          limits: Mapping[str, AxisLimits]) -> str | None:
    """None if the trajectory would be accepted, else why not (see Trajectory.build)."""
    r = _plan(names, times, positions, velocities, accelerations, start, limits)
    return r if isinstance(r, str) else None


# ------------------------------------------------------------------------------ trajectory

class Trajectory:
    """A checked multi-axis trajectory, immutable; build it with Trajectory.build.

    names      axes, in the order of every per-axis array
    kind       'quintic' | 'cubic' | 'spline' (module docstring)
    knots      times of the polynomial's knots, s: 0 (the axis's state) and the points' times
    duration   the last point's time, s
    """
    __slots__ = ('names', 'kind', 'knots', 'duration', '_p', '_v', '_a', '_end', '_ppolys',
                 '_extrema')

    names: tuple[str, ...]
    kind: str
    knots: np.ndarray
    duration: float
    _p: PPoly | BPoly
    _v: PPoly | BPoly
    _a: PPoly | BPoly
    _end: np.ndarray
    _ppolys: tuple[PPoly, ...]
    _extrema: dict[str, tuple[float, float]]

    def __init__(self, names, kind, knots, poly, ppolys, extrema):
        """Internal: use Trajectory.build, which checks the points."""
        knots = np.array(knots, dtype=float)
        knots.flags.writeable = False
        for attr, value in (('names', tuple(names)), ('kind', kind), ('knots', knots),
                            ('duration', float(knots[-1])), ('_p', poly),
                            ('_v', poly.derivative(1)), ('_a', poly.derivative(2)),
                            ('_end', np.array(poly(knots[-1]), dtype=float)),
                            ('_ppolys', tuple(ppolys)), ('_extrema', dict(extrema))):
            object.__setattr__(self, attr, value)
        self._end.flags.writeable = False

    def __setattr__(self, name, value):
        raise AttributeError(f'Trajectory is immutable: cannot set {name}')

    @classmethod
    def build(cls, names: Sequence[str], times, positions, velocities=None,
              accelerations=None, *, start: Mapping[str, Sequence[float]],
              limits: Mapping[str, AxisLimits]) -> Trajectory:
        """Check and build; ValueError with the reason on a refusal (nothing built).

        names          joint_names (each a key of `limits`)
        times          time_from_start of each point, s (>= 0, strictly increasing)
        positions      (points, axes) m
        velocities     (points, axes) m/s, or None / [] / every row empty: none
        accelerations  (points, axes) m/s², likewise (only with velocities)
        start          per axis, its commanded (position, velocity, acceleration) now (an
                       AxisState, or a Trajectory.state of the one being replaced)
        limits         per known axis, its AxisLimits
        """
        r = _plan(names, times, positions, velocities, accelerations, start, limits)
        if isinstance(r, str):
            raise ValueError(r)
        return r

    @classmethod
    def from_points(cls, names: Sequence[str], points: Points, *,
                    start: Mapping[str, Sequence[float]],
                    limits: Mapping[str, AxisLimits]) -> Trajectory:
        """build() from a Points (circle, rounded_square)."""
        return cls.build(names, points.times, points.positions, points.velocities,
                         points.accelerations, start=start, limits=limits)

    def sample(self, t):
        """(position, velocity, acceleration) at time t (s from the start, >= 0): arrays of
        shape (axes,) for a scalar t, (len(t), axes) for an array. From the last time on:
        the last position, velocity and acceleration 0."""
        ts = np.asarray(t, dtype=float)
        if not np.all(ts >= 0):                 # also catches NaN
            raise ValueError(f'trajectory sampled at t < 0 or NaN: {t!r}')
        tc = np.minimum(ts, self.duration)
        p, v, a = self._p(tc), self._v(tc), self._a(tc)
        after = (ts >= self.duration)[..., np.newaxis]
        return (np.where(after, self._end, p), np.where(after, 0.0, v),
                np.where(after, 0.0, a))

    def state(self, t: float) -> dict[str, AxisState]:
        """Per axis, the commanded state at time t: the start of a replacing trajectory."""
        p, v, a = self.sample(float(t))
        return {n: AxisState(float(p[j]), float(v[j]), float(a[j]))
                for j, n in enumerate(self.names)}

    def paths(self) -> dict[str, AxisPath]:
        """Per axis, its share as `Profile.follow` samples it (profile.Path). The axes of one
        trajectory share one evaluation per servo time."""
        shared = _LastSample(self)
        extrema = self.position_extrema()
        return {n: AxisPath(shared, j, extrema[n], float(self._end[j]), self.duration)
                for j, n in enumerate(self.names)}

    def position_extrema(self) -> dict[str, tuple[float, float]]:
        """Per axis, (min, max) of the commanded position over the whole trajectory (exact:
        found by the soft-limit check when it was built)."""
        return dict(self._extrema)


class _LastSample:
    """The trajectory's state at the last time asked for: every axis asks at the same time.

    Evaluated from the piecewise polynomial's own coefficients (its power basis, and that of its
    first two derivatives) in plain Python: scipy's BPoly/PPoly __call__ costs ~15 µs each for
    one t, three of them a tick (benchmark: 2 axes following, before and after)."""
    __slots__ = ('t', 'values', '_x', '_coef', '_end', '_duration')

    def __init__(self, trajectory: Trajectory):
        ppolys = trajectory._ppolys               # per axis, the power basis
        self._x = ppolys[0].x.tolist()
        # per interval: for p, v, a: per axis, the coefficients, highest power first
        p, v, a = (np.stack([(pp.derivative(k) if k else pp).c for pp in ppolys])
                   .transpose(2, 0, 1).tolist() for k in range(3))       # [interval][axis][c]
        self._coef = list(zip(p, v, a))
        self._end = trajectory._end.tolist()
        self._duration = trajectory.duration
        self.t: float | None = None
        self.values: tuple[list[float], list[float], list[float]] = ([], [], [])

    def at(self, t: float) -> tuple[list[float], list[float], list[float]]:
        if t != self.t:
            if t >= self._duration:
                zeros = [0.0] * len(self._end)
                self.values = (self._end, zeros, zeros)
            else:
                i = min(max(bisect.bisect_right(self._x, t) - 1, 0), len(self._coef) - 1)
                d = t - self._x[i]
                out = []
                for per_axis in self._coef[i]:
                    row = []
                    for coefs in per_axis:
                        acc = 0.0
                        for c in coefs:               # Horner
                            acc = acc * d + c
                        row.append(acc)
                    out.append(row)
                self.values = (out[0], out[1], out[2])
            self.t = t
        return self.values


class AxisPath:
    """One axis's share of a Trajectory (profile.Path): duration, end, extrema, at(t)."""
    __slots__ = ('_shared', '_j', 'extrema', 'end', 'duration')

    def __init__(self, shared: _LastSample, index: int, extrema: tuple[float, float],
                 end: float, duration: float):
        self._shared, self._j = shared, index
        self.extrema, self.end, self.duration = extrema, end, duration

    def at(self, t: float) -> tuple[float, float, float]:
        p, v, a = self._shared.at(t)
        j = self._j
        return p[j], v[j], a[j]


# ------------------------------------------------------------------------- example paths

def _ramp_profile(length: float, speed: float, ramp_time: float):
    """Arc length s(t) along a path of `length`: the tangential speed rises from 0 to `speed`
    over ramp_time as v·(3τ² − 2τ³) (acceleration continuous, 0 at both ends of the ramp),
    cruises, and falls back to 0 the same way. Returns (duration, s(t) -> (s, s', s''))."""
    if not (speed > 0 and ramp_time > 0 and length > 0):
        raise ValueError('speed, ramp_time and the path length must be > 0')
    if length < speed * ramp_time:
        raise ValueError(f'the path ({length * 1e3:g} mm) is shorter than its two speed ramps '
                         f'need (speed × ramp_time = {speed * ramp_time * 1e3:g} mm): lower '
                         'ramp_time or speed')
    total = length / speed + ramp_time

    def s_of_t(t):
        t = np.asarray(t, dtype=float)
        up = np.clip(t / ramp_time, 0.0, 1.0)
        down = np.clip((total - t) / ramp_time, 0.0, 1.0)
        ramp_s = speed * ramp_time * (up ** 3 - up ** 4 / 2)
        s = np.where(t <= ramp_time, ramp_s, speed * (t - ramp_time / 2))
        s = np.where(t >= total - ramp_time,
                     length - speed * ramp_time * (down ** 3 - down ** 4 / 2), s)
        sd = speed * np.minimum(3 * up ** 2 - 2 * up ** 3, 3 * down ** 2 - 2 * down ** 3)
        sdd = (speed / ramp_time) * (6 * up * (1 - up) * (t < ramp_time)
                                     - 6 * down * (1 - down) * (t > total - ramp_time))
        return s, sd, sdd
    return total, s_of_t


def _grid(total: float, ramp_time: float, dt: float, start_time: float,
          extra=()) -> np.ndarray:
    """Times 0..total at most dt apart, with a point where each speed ramp ends (the jerk steps
    there; a segment across it would blur the path) and at `extra`; a grid time closer than
    dt/4 to one of those gives way to it."""
    if not (dt > 0 and start_time >= 0):
        raise ValueError(f'dt must be > 0 and start_time >= 0, got {dt!r}, {start_time!r}')
    t = np.linspace(0.0, total, int(math.ceil(total / dt - 1e-9)) + 1)
    keep = np.array([ramp_time, total - ramp_time, *extra], dtype=float)
    near = np.min(np.abs(t[:, None] - keep[None, :]), axis=1) < dt / 4
    return np.union1d(t[~near | (t == 0) | (t == total)], keep)


def circle(center: Sequence[float], radius: float, speed: float, *, turns: float = 1.0,
           ramp_time: float = 0.5, start_angle: float = 0.0, dt: float = 0.01,
           start_time: float = 0.0) -> Points:
    """Points (times, positions, velocities, accelerations) of `turns` counter-clockwise turns
    of a circle in (x, y), m, starting and ending at rest at `start_angle` (rad): the tangential
    speed ramps up to `speed` (m/s) over ramp_time (s), cruises, and ramps down (_ramp_profile),
    so velocity and acceleration are continuous. Every point lies on the circle with its exact
    velocity and acceleration (tangential s'' plus centripetal s'²/r): the quintic segments
    between them stay on it (within 1.2e-14 m for r = 10 mm at 20 mm/s, dt = 10 ms). Points
    at most dt (s) apart from start_time (s), and at the ends of the ramps: the first at rest
    on the circle, so with start_time 0 the axes must already be there."""
    if not radius > 0:
        raise ValueError(f'radius must be > 0, got {radius!r}')
    total, s_of_t = _ramp_profile(2 * math.pi * radius * turns, speed, ramp_time)
    t = _grid(total, ramp_time, dt, start_time)
    s, sd, sdd = s_of_t(t)
    theta = start_angle + s / radius
    c, n = np.cos(theta), np.sin(theta)
    tangent, inward = np.stack([-n, c], axis=1), -np.stack([c, n], axis=1)
    positions = np.asarray(center, dtype=float) + radius * np.stack([c, n], axis=1)
    velocities = sd[:, None] * tangent
    accelerations = sdd[:, None] * tangent + (sd ** 2 / radius)[:, None] * inward
    return Points(t + start_time, positions, velocities, accelerations)


def _square_geometry(s, half: float, r: float):
    """Point, unit tangent and curvature (1/m) at arc length s along a square of half-side
    `half` with corners rounded to radius r, counter-clockwise from the middle of the bottom
    side: each side is a straight run of 2(half − r) and a quarter circle, the next side the
    same turned 90°."""
    run = 2 * (half - r)
    side = run + math.pi * r / 2
    u = np.mod(np.asarray(s, dtype=float) + (half - r), 4 * side)
    k = np.minimum(np.floor(u / side), 3)
    u = u - k * side
    phi = np.clip((u - run) / r, 0.0, math.pi / 2)
    on_arc = u > run
    # the bottom side, then turned by k·90°
    px = np.where(on_arc, half - r + r * np.sin(phi), -half + r + u)
    py = np.where(on_arc, -half + r - r * np.cos(phi), -half)
    tx, ty = np.where(on_arc, np.cos(phi), 1.0), np.where(on_arc, np.sin(phi), 0.0)
    ang = k * (math.pi / 2)
    ca, sa = np.cos(ang), np.sin(ang)
    point = np.stack([ca * px - sa * py, sa * px + ca * py], axis=1)
    tangent = np.stack([ca * tx - sa * ty, sa * tx + ca * ty], axis=1)
    return point, tangent, np.where(on_arc, 1.0 / r, 0.0)


def rounded_square(center: Sequence[float], side: float, corner_radius: float, speed: float,
                   *, ramp_time: float = 0.5, dt: float = 0.01,
                   start_time: float = 0.0) -> Points:
    """Points (times, positions, velocities; no accelerations: cubic Hermite, PMAC PVT) of one
    counter-clockwise lap of a square of `side` (m) centred on `center`, corners rounded to
    corner_radius (0 < r <= side/2), from and back to rest at the middle of its bottom side,
    with the circle's speed ramps. The curvature steps where a straight run meets a corner, so
    a point is placed exactly at each of those 8 junctions: the cubic between two points then
    follows one piece only and stays within 0.3 nm of the path at 20 mm/s, dt = 10 ms,
    r = 3 mm (0.2 µm with the points on the time grid only, cutting the corners)."""
    half = side / 2
    if not 0 < corner_radius <= half:
        raise ValueError(f'corner_radius must be in (0, side/2 = {half:g} m], '
                         f'got {corner_radius!r}')
    r = corner_radius
    run, length = 2 * (half - r), 4 * (2 * (half - r) + math.pi * r / 2)
    total, s_of_t = _ramp_profile(length, speed, ramp_time)
    junctions = [j * (run + math.pi * r / 2) + d for j in range(4) for d in (0.0, run)]
    junctions = [a for a in np.mod(np.array(junctions) - (half - r), length) if 0 < a < length]
    # (here: scipy.optimize costs 0.4-0.6 s at load, 0.15-0.2 s after interpolate)
    from scipy.optimize import brentq
    times = [brentq(lambda t, a=a: float(s_of_t(t)[0]) - a, 0.0, total, xtol=1e-15)
             for a in junctions]
    t = _grid(total, ramp_time, dt, start_time, times)
    s, sd, _ = s_of_t(t)
    point, tangent, _ = _square_geometry(s, half, r)
    positions = np.asarray(center, dtype=float) + point
    return Points(t + start_time, positions, sd[:, None] * tangent, None)


def contour_error(path_xy, actual_xy) -> np.ndarray:
    """Distance (m) of each actual (x, y) from the commanded path, given as a polyline of
    finely sampled commanded points (e.g. Trajectory.sample every servo period): the distance
    to the nearest polyline segment, exactly.

    Not every segment is looked at: with d0 the distance to the nearest path point (a k-d
    tree) and L the longest segment, the nearest segment has an end within sqrt(d0² + L²/4)
    (the foot of the perpendicular is no farther than d0, and an end no farther than L/2 from
    the foot), so the segments next to the path points within that radius hold it."""
    path = np.asarray(path_xy, dtype=float)
    act = np.asarray(actual_xy, dtype=float)
    if path.ndim != 2 or path.shape[1] != 2 or act.ndim != 2 or act.shape[1] != 2:
        raise ValueError('path_xy and actual_xy must be (n, 2) arrays')
    # (here: scipy.spatial costs 0.4 s at load, -X importtime; interpolate loads it too)
    from scipy.spatial import cKDTree
    tree = cKDTree(path)
    d0 = tree.query(act)[0]
    if len(path) == 1 or len(act) == 0:
        return d0
    a, d = path[:-1], np.diff(path, axis=0)
    dd = np.einsum('ij,ij->i', d, d)
    radius = np.sqrt(d0 ** 2 + dd.max() / 4) * (1 + 1e-12) + 1e-300
    balls = tree.query_ball_point(act, radius)
    counts = np.array([len(b) for b in balls])
    vertex = np.concatenate([np.asarray(b, dtype=int) for b in balls])
    owner = np.repeat(np.arange(len(act)), counts)
    # the segments i-1 and i next to each path point i, as (owner, segment) pairs
    seg = np.clip(np.concatenate([vertex - 1, vertex]), 0, len(a) - 1)
    owner = np.concatenate([owner, owner])
    q = act[owner] - a[seg]
    u = np.clip(np.einsum('ij,ij->i', q, d[seg]) / np.where(dd[seg] > 0, dd[seg], 1.0), 0, 1)
    gap = q - u[:, None] * d[seg]
    dist = np.full(len(act), np.inf)
    np.minimum.at(dist, owner, np.einsum('ij,ij->i', gap, gap))
    return np.sqrt(dist)
