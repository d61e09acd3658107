"""Tests for motion_ctrl.core.trajectory (issue 16: JointTrajectory as PVT; PMAC PVT mode, the
joint_trajectory_controller's splines).

Numbers: the axes' default registers (soft limits ±0.5 m, max_velocity 0.1 m/s, max_acceleration
1.5 m/s²) unless a test says otherwise; millimetre-sized moves over about a second.
"""
import math

import numpy as np
import pytest
from scipy.interpolate import BPoly

from motion_ctrl.core.registers import axis_defaults
from motion_ctrl.core.trajectory import (AxisLimits, AxisState, Trajectory, check, circle,
                                    contour_error, rounded_square)

MM = 1e-3
DEFAULT = AxisLimits.from_registers(axis_defaults())
LIMITS = {'x': DEFAULT, 'y': DEFAULT}
AT_REST = {'x': AxisState(0.0), 'y': AxisState(0.0)}


def build(names, times, positions, velocities=None, accelerations=None, start=None,
          limits=None):
    return Trajectory.build(names, times, positions, velocities, accelerations,
                            start=AT_REST if start is None else start,
                            limits=LIMITS if limits is None else limits)


def reason(names, times, positions, velocities=None, accelerations=None, start=None,
           limits=None):
    r = check(names, times, positions, velocities, accelerations,
              start=AT_REST if start is None else start,
              limits=LIMITS if limits is None else limits)
    assert r is not None, 'accepted'
    with pytest.raises(ValueError) as exc:      # build refuses with the same reason
        build(names, times, positions, velocities, accelerations, start, limits)
    assert str(exc.value) == r
    return r


# Two axes, three points after the implicit start, every kind of data on them.
TIMES = [0.4, 0.9, 1.5]
POS = [[2 * MM, -1 * MM], [5 * MM, 1 * MM], [4 * MM, 3 * MM]]
VEL = [[10 * MM, 2 * MM], [-2 * MM, 5 * MM], [0.0, 0.0]]
ACC = [[-20 * MM, 5 * MM], [-30 * MM, -10 * MM], [0.0, 0.0]]
START = {'x': AxisState(1 * MM, 3 * MM, 40 * MM), 'y': AxisState(-2 * MM, -1 * MM, 0.0)}


# ------------------------------------------------------------------------- segment types

@pytest.mark.parametrize('kind, vel, acc', [('quintic', VEL, ACC), ('cubic', VEL, None)])
def test_hermite_segments_hit_every_point_exactly(kind, vel, acc):
    traj = build('xy', TIMES, POS, vel, acc, start=START)
    assert traj.kind == kind
    assert traj.duration == 1.5
    assert list(traj.knots) == [0.0, *TIMES]     # the axis's state is the point at t=0
    p, v, a = traj.sample(0.0)
    assert p == pytest.approx([1 * MM, -2 * MM], abs=1e-12)
    assert v == pytest.approx([3 * MM, -1 * MM], abs=1e-12)
    if kind == 'quintic':                        # a cubic starts from p, v only
        assert a == pytest.approx([40 * MM, 0.0], abs=1e-12)
    for i, t in enumerate(TIMES):
        p, v, a = traj.sample(t)
        assert p == pytest.approx(POS[i], abs=1e-12)
        assert v == pytest.approx(VEL[i], abs=1e-12)
        if kind == 'quintic':
            assert a == pytest.approx(ACC[i], abs=1e-12)


def test_quintic_is_scipys_quintic_hermite():
    # The module computes the Bernstein coefficients of all segments at once; scipy's
    # BPoly.from_derivatives (segment by segment) must give the same polynomial.
    traj = build('xy', TIMES, POS, VEL, ACC, start=START)
    knots = [0.0, *TIMES]
    yi = [[[START[n][k] for n in 'xy'] for k in range(3)]]
    yi += [[POS[i], VEL[i], ACC[i]] for i in range(3)]
    ref = BPoly.from_derivatives(knots, np.array(yi))
    t = np.linspace(0.0, 1.5, 301)[:-1]
    p, v, a = traj.sample(t)
    assert p == pytest.approx(ref(t), abs=1e-15)
    assert v == pytest.approx(ref.derivative(1)(t), abs=1e-14)
    assert a == pytest.approx(ref.derivative(2)(t), abs=1e-12)


def test_cubic_segment_is_the_hand_worked_cubic():
    # p0 = 0, v0 = 0, p1 = 1 mm, v1 = 0, T = 1 s. Hermite: p(t) = p0 + (3t² - 2t³)(p1 - p0)
    # = 3t² - 2t³ mm, v(t) = 6t - 6t² mm/s, a(t) = 6 - 12t mm/s².
    # t = 0.5: p = 0.75 - 0.25 = 0.5 mm, v = 3 - 1.5 = 1.5 mm/s, a = 0.
    # t = 0.25: p = 0.1875 - 0.03125 = 0.15625 mm, v = 1.5 - 0.375 = 1.125 mm/s, a = 3 mm/s².
    # t = 0: a = 6 mm/s²; t = 1: a = -6 mm/s² (from the left), then the hold: 0.
    traj = build('x', [1.0], [[1 * MM]], [[0.0]])
    assert traj.kind == 'cubic'
    p, v, a = traj.sample(np.array([0.0, 0.25, 0.5, 1 - 1e-12]))
    assert p[:, 0] / MM == pytest.approx([0.0, 0.15625, 0.5, 1.0], abs=1e-9)
    assert v[:, 0] / MM == pytest.approx([0.0, 1.125, 1.5, 0.0], abs=1e-9)
    assert a[:, 0] / MM == pytest.approx([6.0, 3.0, 0.0, -6.0], abs=1e-9)


def test_positions_only_is_a_c2_spline_clamped_to_rest_at_the_end():
    times = [0.5, 1.0, 1.6, 2.0]
    pos = [[1 * MM], [4 * MM], [2 * MM], [3 * MM]]
    start = {'x': AxisState(0.0, 5 * MM, 0.0)}
    traj = build('x', times, pos, start=start)
    assert traj.kind == 'spline'
    p, v, _ = traj.sample(np.array(times))
    assert p[:, 0] == pytest.approx([q[0] for q in pos], abs=1e-12)     # through every point
    assert traj.sample(0.0)[1][0] == pytest.approx(5 * MM, abs=1e-12)    # clamped: the axis's v
    assert traj.sample(2.0 - 1e-12)[1][0] == pytest.approx(0.0, abs=1e-12)   # clamped: at rest
    # C2: position, velocity and acceleration the same on both sides of every inner point
    # (within what the jerk moves them in 2 eps: a few mm/s³ × 1e-7 s).
    eps = 1e-7
    for t in times[:-1]:
        left, right = traj.sample(t - eps), traj.sample(t + eps)
        for q_left, q_right in zip(left, right):
            assert q_left[0] == pytest.approx(q_right[0], abs=1e-8)
    # (a cubic Hermite through the same points, stopping at each, steps its acceleration
    # there: the check above tells them apart)
    stops = build('x', times, pos, [[0.0]] * 4, start=start)
    jump = stops.sample(1.0 + eps)[2][0] - stops.sample(1.0 - eps)[2][0]
    assert abs(jump) > 10 * MM


def test_after_the_last_point_it_holds_at_rest_and_before_zero_is_refused():
    traj = build('xy', TIMES, POS, VEL, start=START)
    p, v, a = traj.sample([1.5, 2.0, 100.0])
    assert p == pytest.approx(np.array([POS[-1]] * 3), abs=1e-12)
    assert (v == 0).all() and (a == 0).all()
    with pytest.raises(ValueError, match='t < 0'):
        traj.sample(-0.001)
    with pytest.raises(ValueError, match='NaN'):
        traj.sample(math.nan)


def test_a_first_point_at_t0_where_the_axis_is_starts_there():
    traj = build('x', [0.0, 1.0], [[2 * MM + 5e-10], [3 * MM]],
                 start={'x': AxisState(2 * MM)})
    assert list(traj.knots) == [0.0, 1.0]        # no point inserted before it
    assert traj.sample(0.0)[0][0] == 2 * MM      # the axis's own position, not the point's
    assert traj.sample(1.0)[0][0] == pytest.approx(3 * MM, abs=1e-12)


def test_trajectory_is_immutable():
    traj = build('x', [1.0], [[1 * MM]])
    with pytest.raises(AttributeError):
        traj.duration = 2.0
    with pytest.raises(ValueError):
        traj.knots[0] = 1.0


# -------------------------------------------------------------------------- replacement

@pytest.mark.parametrize('vel, acc', [(VEL, ACC), (VEL, None), (None, None)])
def test_a_replacement_starts_from_the_old_trajectorys_state(vel, acc):
    old = build('xy', TIMES, POS, vel, acc, start=START)
    state = old.state(0.37)
    new = build('xy', [0.8, 1.6], [[-3 * MM, 2 * MM], [0.0, 0.0]],
                None if vel is None else [[1 * MM, 0.0], [0.0, 0.0]],
                None if acc is None else [[0.0, 0.0], [0.0, 0.0]], start=state)
    p_old, v_old, a_old = old.sample(0.37)
    p, v, a = new.sample(0.0)
    assert p == pytest.approx(p_old, abs=1e-12)
    assert v == pytest.approx(v_old, abs=1e-12)
    assert abs(v_old[0]) > 1 * MM                # (a moving axis, else the test says little)
    if acc is not None:
        assert a == pytest.approx(a_old, abs=1e-12)
    assert new.sample(1.6)[0] == pytest.approx([0.0, 0.0], abs=1e-12)


# ----------------------------------------------------------------------------- refusals

def test_refused_joint_names():
    assert reason([], [1.0], [[]]) == 'joint_names is empty'
    assert reason(['x', 'x'], [1.0], [[0.0, 0.0]]) == "joint_names: 'x' is given twice"
    assert reason(['x', 'z'], [1.0], [[0.0, 0.0]]) == (
        "joint_names: 'z' is not an axis of this controller (axes: x, y)")


def test_refused_array_lengths():
    assert reason('xy', [1.0, 2.0], [[0.0, 0.0], [1 * MM]]) == (
        'point 1: 1 positions for 2 joint_names (x, y)')
    assert reason('xy', [1.0], [[0.0, 0.0]], [[0.0]]) == (
        'point 0: 1 velocities for 2 joint_names (x, y)')
    assert reason('x', [1.0, 2.0], [[0.0], [0.0]], [[1 * MM], []]) == (
        'velocities on some points only (point 0 has them, point 1 has none): give velocities '
        'on every point or on none')
    assert reason('x', [1.0], [[0.0]], None, [[0.0]]) == (
        'accelerations without velocities: give velocities with them')
    assert reason('x', [1.0, 2.0], [[0.0]]) == '2 times for 1 points'
    assert reason('x', [], []) == 'the trajectory has no points'
    assert reason('x', [1.0], [['a']]) == (
        "the points are not arrays of numbers: could not convert string to float: 'a'")


def test_refused_times():
    assert reason('x', [1.0, 1.0], [[0.0], [0.0]]) == (
        "point 1: time_from_start 1 s is not after point 0's 1 s (times must increase strictly)")
    assert reason('x', [1.0, 0.5], [[0.0], [0.0]]).startswith('point 1: time_from_start 0.5 s')
    assert reason('x', [-1.0], [[0.0]]) == 'point 0: time_from_start -1 s is negative'
    assert reason('x', [1.0, math.nan], [[0.0], [0.0]]) == (
        'point 1: time_from_start nan s is not finite')


def test_refused_non_finite_numbers():
    assert reason('xy', [1.0, 2.0], [[0.0, 0.0], [0.0, math.nan]]) == (
        'y: point 1 position nan m is not finite')
    assert reason('xy', [1.0, 2.0], [[0.0, 0.0]] * 2, [[0.0, math.inf], [0.0, 0.0]]) == (
        'y: point 0 velocity inf m/s is not finite')
    assert reason('x', [1.0], [[0.0]], [[0.0]], [[-math.inf]]) == (
        'x: point 0 acceleration -inf m/s² is not finite')


def test_refused_first_point_at_t0_away_from_the_axis():
    assert reason('xy', [0.0, 1.0], [[0.0, 1 * MM], [0.0, 0.0]]) == (
        'y: point 0 at t=0 has position 0.001 m, the axis is at 0 m: the trajectory starts '
        'away from the axis: give the first point a time_from_start > 0')
    # a point at t=0 also carries the axis's velocity: a step in it is refused the same way
    moving = {'x': AxisState(0.0, 2 * MM)}
    assert reason('x', [0.0, 1.0], [[0.0], [1 * MM]], [[0.0], [0.0]], start=moving) == (
        'x: point 0 at t=0 has velocity 0 m/s, the axis is at 0.002 m/s: the trajectory starts '
        'away from the axis: give the first point a time_from_start > 0')
    assert reason('x', [0.0], [[0.0]]) == (
        'the only point is at t=0, where the axis already is: nothing to move')
    # the same point 1 s later is a smooth approach from where the axis is
    assert check('xy', [1.0, 2.0], [[0.0, 1 * MM], [0.0, 0.0]], start=AT_REST,
                 limits=LIMITS) is None


def test_refused_last_point_not_at_rest():
    assert reason('x', [1.0, 2.0], [[1 * MM], [2 * MM]], [[1 * MM], [1 * MM]]) == (
        'x: the last point (1) has velocity 0.001 m/s: the last point must have velocity 0 '
        '(a trajectory ends at rest)')
    assert reason('x', [1.0], [[1 * MM]], [[0.0]], [[0.5]]) == (
        'x: the last point (0) has acceleration 0.5 m/s²: the last point must have '
        'acceleration 0 (a trajectory ends at rest)')


def test_refused_point_outside_a_soft_limit():
    assert reason('xy', [1.0, 9.0, 20.0], [[0.0, 0.0], [0.0, 0.6], [0.0, 0.0]]) == (
        'y: point 1 position 0.6 m is above soft_limit_max 0.5 m')
    assert reason('xy', [9.0], [[-0.51, 0.0]]) == (
        'x: point 0 position -0.51 m is below soft_limit_min -0.5 m')


def test_refused_spline_overshooting_a_soft_limit_between_points():
    # Every point inside [-0.5, 0.5], but the spline rises into the last two points at the
    # limit (0.4 -> 0.5 -> 0.5, to rest at the end) and bulges above 0.5 on its way: 0.50528 m
    # at t = 1.696 s, 5.3 mm past the limit. Velocity and acceleration limits out of the way.
    loose = {'x': AxisLimits(-0.5, 0.5, 10.0, 100.0)}
    assert reason('x', [1.0, 2.0, 3.0], [[0.4], [0.5], [0.5]], limits=loose) == (
        'x: the path reaches 0.505281529 m at t=1.69619 s, between point 0 (t=1 s) and '
        'point 1 (t=2 s), above soft_limit_max 0.5 m (the interpolation overshoots between '
        'the points)')
    # with the top points 5.3 mm lower it passes
    assert check('x', [1.0, 2.0, 3.0], [[0.4 - 0.005282], [0.494718], [0.494718]],
                 start=AT_REST, limits=loose) is None


def test_refused_segment_over_max_velocity_between_points():
    # The hand-worked cubic: 1 mm in 1 s from rest to rest peaks at 1.5 mm/s at t = 0.5 s,
    # half-way between the points (both at velocity 0): only an exact search finds it.
    slow = {'x': AxisLimits(-0.5, 0.5, 1.4 * MM, 1.5)}
    assert reason('x', [1.0], [[1 * MM]], [[0.0]], limits=slow) == (
        'x: velocity 0.0015 m/s at t=0.5 s, between the start (t=0) and point 0 (t=1 s), '
        'exceeds max_velocity 0.0014 m/s')
    # planned exactly at the limit: accepted
    exact = {'x': AxisLimits(-0.5, 0.5, 1.5 * MM, 6 * MM)}
    assert check('x', [1.0], [[1 * MM]], [[0.0]], start=AT_REST, limits=exact) is None


def test_refused_segment_over_max_acceleration():
    # the same cubic: a(0) = 6 mm/s², a(1 s) = -6 mm/s²
    gentle = {'x': AxisLimits(-0.5, 0.5, 0.1, 5 * MM)}
    r = reason('x', [1.0], [[1 * MM]], [[0.0]], limits=gentle)
    assert r.startswith('x: acceleration ')
    assert r.endswith('between the start (t=0) and point 0 (t=1 s), exceeds max_acceleration '
                      '0.005 m/s²')
    assert abs(float(r.split()[2])) == pytest.approx(6 * MM, abs=1e-12)
    # a later segment is named by its points
    r = reason('x', [1.0, 2.0], [[1 * MM], [11 * MM]], [[0.0], [0.0]], limits=gentle)
    assert 'between point 0 (t=1 s) and point 1 (t=2 s)' in r
    assert abs(float(r.split()[2])) == pytest.approx(60 * MM, abs=1e-12)


# ------------------------------------------------------------------------ example paths

def test_circle_radius_speed_rest_and_limits():
    pts = circle((0.05, -0.02), 10 * MM, 20 * MM)
    assert pts.positions[0] == pytest.approx([0.06, -0.02], abs=1e-15)
    start = {'x': AxisState(0.06), 'y': AxisState(-0.02)}
    traj = Trajectory.build('xy', *pts, start=start, limits=LIMITS)
    assert traj.kind == 'quintic'
    # one turn of 62.83 mm at 20 mm/s plus half of each 0.5 s ramp: 3.1416 + 0.5 s
    assert traj.duration == pytest.approx(2 * math.pi * 10 * MM / (20 * MM) + 0.5, abs=1e-12)
    t = np.arange(0.0, traj.duration, 1e-3)
    p, v, a = traj.sample(t)
    radius = np.hypot(p[:, 0] - 0.05, p[:, 1] + 0.02)
    assert np.abs(radius - 10 * MM).max() < 1e-9          # on the circle between points too
    speed = np.hypot(*v.T)
    middle = (t > 0.5) & (t < traj.duration - 0.5)
    assert speed[middle] == pytest.approx(20 * MM, abs=1e-9)
    assert speed.max() < 20 * MM + 1e-9
    # starts and ends at rest, where it started
    assert np.abs(np.concatenate(traj.sample(0.0)[1:])).max() < 1e-15
    p_end, v_end, a_end = traj.sample(traj.duration - 1e-9)
    assert p_end == pytest.approx([0.06, -0.02], abs=1e-12)
    assert np.abs(v_end).max() < 1e-9 and np.abs(a_end).max() < 1e-6
    # in the middle the acceleration is the centripetal v²/r = 40 mm/s²; acceleration has
    # no steps (C2 quintics through exact p, v, a): 1 ms apart it moves by at most ~jerk·1 ms
    assert np.hypot(*a[middle].T) == pytest.approx(40 * MM, abs=1e-6)
    assert np.abs(np.diff(a, axis=0)).max() < 1e-3


def test_circle_too_short_for_its_ramps_is_refused():
    with pytest.raises(ValueError, match='shorter than its two speed ramps'):
        circle((0.0, 0.0), 1 * MM, 20 * MM, turns=0.05, ramp_time=0.5)


def test_rounded_square_stays_on_its_path():
    pts = rounded_square((0.0, 0.0), 20 * MM, 3 * MM, 20 * MM)
    assert pts.accelerations is None and pts.velocities is not None
    assert pts.positions[0] == pytest.approx([0.0, -10 * MM], abs=1e-15)
    start = {'x': AxisState(0.0), 'y': AxisState(-10 * MM)}
    traj = Trajectory.build('xy', *pts, start=start, limits=LIMITS)
    assert traj.kind == 'cubic'
    t = np.arange(0.0, traj.duration, 1e-3)
    p, v, _ = traj.sample(t)
    # The exact path, finely: straight runs of 14 mm on the lines x, y = ±10 mm, quarter
    # circles of 3 mm around (±7, ±7) mm.
    phi = np.linspace(0, math.pi / 2, 2001)
    arc = 3 * MM * np.stack([np.cos(phi), np.sin(phi)], axis=1) + 7 * MM
    run = np.stack([np.full(2001, 10 * MM), np.linspace(-7 * MM, 7 * MM, 2001)], axis=1)
    quarter = np.vstack([run, arc])
    turn = np.array([[0.0, -1.0], [1.0, 0.0]])
    path = np.vstack([quarter @ np.linalg.matrix_power(turn, k).T for k in range(4)]
                     + [run[:1]])
    # every sampled command within 5 nm of the exact square (the fine polyline's own chord
    # error on the arcs is 3 mm · (π/4000)²/8 = 0.2 nm)
    assert contour_error(path, p).max() < 5e-9
    assert np.hypot(*v.T).max() == pytest.approx(20 * MM, abs=1e-9)
    assert traj.position_extrema()['x'] == pytest.approx((-10 * MM, 10 * MM), abs=1e-9)
    assert np.abs(traj.sample(traj.duration)[1]).max() == 0.0


def test_contour_error_is_the_distance_to_the_polyline():
    path = np.array([[0.0, 0.0], [10 * MM, 0.0], [10 * MM, 10 * MM]])
    actual = np.array([[5 * MM, 3e-6],        # 3 µm beside the first line
                       [11 * MM, 5 * MM],     # 1 mm outside the second
                       [13 * MM, -4 * MM],    # beyond the corner: 5 mm from the vertex
                       [-1 * MM, 0.0]])       # before the start: 1 mm from it
    assert contour_error(path, actual) == pytest.approx([3e-6, 1 * MM, 5 * MM, 1 * MM],
                                                        abs=1e-15)
    # a path folding back on itself: the nearer of the two passes counts
    hairpin = np.array([[0.0, 0.0], [1.0, 0.0], [1.0, 1 * MM], [0.0, 1 * MM]])
    assert contour_error(hairpin, [[0.5, 0.4 * MM]]) == pytest.approx([0.4 * MM], abs=1e-15)


@pytest.mark.core_slow
def test_paths_follow_the_trajectory_exactly():
    """What the servo loop samples per tick (Trajectory.paths, evaluated from the polynomial
    coefficients) is the trajectory itself, in every segment kind, and holds at the end."""
    lim = {a: AxisLimits(-1.0, 1.0, 1.0, 10.0) for a in 'xy'}
    start = {'x': (0.0, 0.0, 0.0), 'y': (0.0, 0.0, 0.0)}
    ring = circle((-0.01, 0.0), 0.01, 0.02)
    kinds = [Trajectory.from_points(['x', 'y'], ring, start={'x': (0.0, 0.0, 0.0),
                                                                   'y': (0.0, 0.0, 0.0)},
                                       limits=lim),
             Trajectory.build(['x', 'y'], [0.5, 1.0], [[0.01, 0.0], [0.02, 0.01]],
                                 [[0.02, 0.0], [0.0, 0.0]], start=start, limits=lim),
             Trajectory.build(['x', 'y'], [0.5, 1.0, 1.5], [[0.01, 0.0], [0.02, 0.01],
                                                               [0.0, 0.0]],
                                 start=start, limits=lim)]
    assert [t.kind for t in kinds] == ['quintic', 'cubic', 'spline']
    for traj in kinds:
        paths = traj.paths()
        for t in np.linspace(0.0, traj.duration + 0.1, 997):
            p, v, a = traj.sample(t)
            for j, name in enumerate(['x', 'y']):
                got = paths[name].at(float(t))
                # (the power basis rounds differently: a few 1e-12 m/s² here and there)
                assert got == pytest.approx((p[j], v[j], a[j]), rel=1e-9, abs=1e-10), \
                    (traj.kind, t)
