"""Issue 28 on the servo loop itself (in-process harness, no ROS): a FollowJointTrajectory goal
checked, started and judged by motion_ctrl.core.follow_goal as the action server drives it, on
two axes of the default slide (dual feedback): success within a count on the true slides, the
refusals and their codes, path and goal tolerance violations, cancel, preemption, and the
commands that end a goal."""
import math
import re

import numpy as np
import pytest

import kit

from motion_ctrl.core import follow_goal as fg
from motion_ctrl.core.registers import LOAD_COUNTS_PER_M
from msg_defs.status import Status as S

REGISTERS = kit.DUAL_REGISTERS
COUNT = 1 / LOAD_COUNTS_PER_M


@pytest.fixture
def xy():
    return kit.enabled_xy()


class Driver:
    """The action server's part, in process: check, submit, tick after every servo tick."""

    def __init__(self, h):
        self.h = h
        self.runner = fg.GoalRunner(h.axes, lambda job, now: h.loop.trajectory(job, None, now))
        self.ended: list[fg.Ended] = []
        self.feedback: list[fg.Feedback] = []

    def check(self, spec, **request):
        return fg.check(fg.GoalRequest(spec, **request), self.h.axes,
                        {a: x.r for a, x in self.h.axes.items()}, self.h.loop.prepare,
                        self.h.time)

    def send(self, spec, handle='goal', **request):
        checked = self.check(spec, **request)
        self.ended += self.runner.submit(handle, checked, self.h.time)
        return checked

    def _tick(self, h):
        self.ended += self.runner.tick(h.time)
        fb = self.runner.feedback(h.time)
        if fb is not None:
            self.feedback.append(fb)

    def run(self, seconds, until=None):
        return self.h.run(seconds, until=until, disturbance=self._tick)

    def until_ended(self, timeout=10.0, handle='goal'):
        self.run(timeout, until=lambda h: any(e.handle == handle for e in self.ended))
        return next(e for e in self.ended if e.handle == handle)


def here(h) -> dict:
    return {a: h.axes[a].path_state[0] for a in h.axes}


def spec(names, times, positions, velocities=(), accelerations=()) -> dict:
    return {'names': list(names), 'times': list(times), 'positions': [list(p) for p in positions],
            'velocities': [list(v) for v in velocities],
            'accelerations': [list(a) for a in accelerations]}


def zigzag(h, dx=0.004, dy=0.002, seconds=1.6, point0=True):
    """Both axes through four points (positions only: a C2 spline), first point at t=0 where
    the axes are (as MoveIt sends it)."""
    s = here(h)
    times = [0.0, seconds / 3, 2 * seconds / 3, seconds]
    pos = [[s['x'], s['y']], [s['x'] + dx / 2, s['y'] + dy], [s['x'] + dx, s['y'] + dy / 2],
           [s['x'] + dx, s['y'] + dy]]
    if not point0:
        times, pos = times[1:], pos[1:]
    return spec(('x', 'y'), times, pos)


# ----------------------------------------------------------------------------------- checks

def test_refusals_have_the_codes_and_name_joint_point_and_limit(xy):
    d = Driver(xy)
    ok = zigzag(xy)
    cases = [
        (ok | {'names': ['x', 'q']}, {}, fg.INVALID_JOINTS, "'q' is not an axis of this "
                                                           'controller (axes: x, y)'),
        (ok | {'names': ['x', 'x']}, {}, fg.INVALID_JOINTS, "'x' is given twice"),
        (ok | {'names': []}, {}, fg.INVALID_JOINTS, 'joint_names is empty'),
        (ok, {'multi_dof_names': ('base',)}, fg.INVALID_JOINTS, 'no multi-DOF joints'),
        (ok, {'path_tolerance': (('z', 0.001, 0.0, 0.0),)}, fg.INVALID_JOINTS,
         "path_tolerance names 'z'"),
        (ok, {'goal_tolerance': (('x', -0.5, 0.0, 0.0),)}, fg.INVALID_GOAL,
         'goal_tolerance of x: position -0.5: a tolerance is > 0, 0 (the default) or -1'),
        (ok, {'goal_time_tolerance': -2.0}, fg.INVALID_GOAL, 'goal_time_tolerance -2'),
        (ok | {'times': [0.0, 0.01, 0.02, 0.03]}, {}, fg.INVALID_GOAL, 'exceeds max_velocity 0.1 '
                                                                   'm/s'),
        (ok | {'positions': ok['positions'][:2] + [[0.6, 0.0]] + ok['positions'][3:]}, {},
         fg.INVALID_GOAL, 'x: point 2 position 0.6 m is above soft_limit_max 0.5 m'),
        (ok | {'positions': [[0.001, 0.0]] + ok['positions'][1:]}, {}, fg.INVALID_GOAL,
         'x: point 0 (t=0) is at 0.001 m, 0.001 m from the commanded position'),
        (ok, {'stamp': xy.time - 5.0}, fg.OLD_HEADER_TIMESTAMP, 'ended 3.400 s ago'),
        (ok, {'stamp': xy.time + 100.0}, fg.INVALID_GOAL, 'at most 60 s'),
    ]
    for s, request, code, text in cases:
        r = d.check(s, **request)
        assert isinstance(r, fg.Refusal) and r.code == code and text in r.text, (r, text)


def test_a_first_point_at_t0_near_the_axis_stands_for_its_commanded_state(xy):
    """MoveIt's first point is the measured state: within coarse_position_tolerance it takes
    the axis's own commanded state, and the trajectory starts there without a jump."""
    d = Driver(xy)
    s = zigzag(xy)
    s['positions'][0] = [p + 3 * COUNT for p in s['positions'][0]]     # 7.6 um off, tol 25.4
    r = d.check(s)
    assert isinstance(r, fg.CheckedGoal), r
    assert r.job.spec['times'] == s['times']
    assert r.job.spec['positions'][0] == [xy.axes[a].path_state[0] for a in 'xy']


def test_tolerances_come_from_the_registers_and_the_goal_overrides_them(xy):
    d = Driver(xy)
    r = d.check(zigzag(xy))
    t = r.tolerances['x']
    assert t == fg.Tolerances(fg.Tolerance(0.001), fg.Tolerance(0.0, 0.01), 2.0)
    r = d.check(zigzag(xy), path_tolerance=(('x', 0.0005, 0.0, 0.02), ('y', -1.0, 0.0, 0.0)),
                goal_tolerance=(('y', 3e-6, -1.0, 0.0),), goal_time_tolerance=0.5)
    assert r.tolerances['x'] == fg.Tolerances(fg.Tolerance(0.0005, 0.0, 0.02),
                                              fg.Tolerance(0.0, 0.01), 0.5)
    assert r.tolerances['y'] == fg.Tolerances(fg.Tolerance(0.0), fg.Tolerance(3e-6, 0.0), 0.5)


# ---------------------------------------------------------------------------- running goals

@pytest.mark.core_slow
def test_a_goal_through_several_points_succeeds_within_a_count(xy):
    d = Driver(xy)
    s = zigzag(xy)
    d.send(s)
    e = d.until_ended()
    assert (e.outcome, e.code) == (fg.SUCCEEDED, fg.SUCCESSFUL), e
    # (reached after the last point at 1.6 s: 21 ms later since a coordinate standing still on
    # the path no longer flips friction_ff's sign, servo_law.REST_VELOCITY; after 2 s before)
    m = re.fullmatch(r'reached at t=(\d\.\d{3}) s: x at 0\.00400\d\d m \(error [+-]\d\.\d\d µm\), '
                     r'y at 0\.00\d{5} m \(error [+-]\d\.\d\d µm\)', e.text)
    assert m and 1.6 <= float(m.group(1)) <= 1.7, e.text
    for j, a in enumerate('xy'):
        assert abs(xy.plants[a].x_l - s['positions'][-1][j]) <= COUNT, a
        assert xy.axes[a].status & S.MOTION_DONE
    # feedback all along: the index passes every point, the desired path is continuous
    assert d.feedback[0].next_point == 1 and d.feedback[-1].next_point == 4
    # and the result carries the last feedback: the state at the end, past the last point
    assert e.last is not None and e.last.next_point == 4 and e.last.time >= 1.6
    assert abs(e.last.actual[0][0] - xy.axes['x'].actual_pos) < 1e-12
    desired_x = np.array([fb.desired[0][0] for fb in d.feedback])
    assert np.abs(np.diff(desired_x)).max() <= 0.1 * xy.T * 1.01
    assert max(abs(fb.error[0][0]) for fb in d.feedback) < 20 * COUNT


@pytest.mark.core_slow
def test_a_moveit_like_goal_succeeds(xy):
    """As MoveIt's time parameterization sends it: points every 0.1 s with positions,
    velocities and accelerations (quintic segments), point 0 at t=0 the measured state (here a
    count off the commanded position)."""
    d = Driver(xy)
    s = here(xy)
    tau = np.linspace(0.0, 1.0, 11)
    shape = (10 * tau ** 3 - 15 * tau ** 4 + 6 * tau ** 5, (30 * tau ** 2 - 60 * tau ** 3
             + 30 * tau ** 4), 60 * tau - 180 * tau ** 2 + 120 * tau ** 3)
    dist = {'x': 0.004, 'y': -0.002}
    rows = [[[s[a] * (k == 0) + dist[a] * q[i] for a in 'xy'] for i in range(11)]
            for k, q in enumerate(shape)]
    rows[0][0] = [s['x'] + COUNT, s['y']]
    d.send(spec(('x', 'y'), tau, *rows))
    e = d.until_ended()
    assert e.outcome == fg.SUCCEEDED, e
    for a in 'xy':
        assert abs(xy.plants[a].x_l - s[a] - dist[a]) <= COUNT, a


@pytest.mark.core_slow
def test_the_slide_braked_part_way_violates_the_path_tolerance(xy):
    d = Driver(xy)
    d.send(zigzag(xy))
    d.run(0.5)
    xy.plants['x'].configure(brake=1)
    e = d.until_ended()
    assert (e.outcome, e.code) == (fg.ABORTED, fg.PATH_TOLERANCE_VIOLATED), e
    assert e.text.startswith('x: position error +') and 'exceeds the path tolerance 0.001 m' \
        in e.text, e.text
    d.run(1.0)
    for a in 'xy':                    # stopped at their STOP deceleration, loops closed
        word = xy.axes[a].status
        assert word & S.STOPPED and word & S.ENABLED and not word & S.MOVING, (a, repr(word))


@pytest.mark.core_slow
def test_an_unreachable_goal_tolerance_is_violated_after_goal_time(xy):
    """The last point half a count between two encoder counts: the loop holds one of them, half
    a count (1.27 um) off, which a 0.5 um goal tolerance never admits."""
    d = Driver(xy)
    s = zigzag(xy, point0=False)
    s['positions'][-1][0] += 0.5 * COUNT
    d.send(s, goal_tolerance=(('x', 0.5e-6, 0.0, 0.0),), goal_time_tolerance=0.3)
    e = d.until_ended()
    assert (e.outcome, e.code) == (fg.ABORTED, fg.GOAL_TOLERANCE_VIOLATED), e
    assert e.text.startswith('x: position error ') and 'exceeds the goal tolerance 5e-07 m' \
        in e.text and '0.3 s (goal_time)' in e.text, e.text


@pytest.mark.core_slow
def test_cancel_stops_the_axes_and_reports_where_they_came_to_rest(xy):
    d = Driver(xy)
    d.send(zigzag(xy))
    d.run(0.6)
    d.runner.cancel('goal')
    e = d.until_ended()
    assert (e.outcome, e.code) == (fg.CANCELED, fg.SUCCESSFUL), e
    for a in 'xy':
        axis = xy.axes[a]
        assert not axis.profile.moving and axis.status & S.STOPPED
        assert f'{a} at {axis.actual_pos:.7f} m' in e.text, e.text


@pytest.mark.core_slow
def test_a_new_goal_preempts_the_running_one(xy):
    d = Driver(xy)
    d.send(zigzag(xy))
    d.run(0.5)
    s = here(xy)
    d.send(spec(('x',), [1.0], [[s['x'] - 0.002]]), handle='second')
    first = next(e for e in d.ended if e.handle == 'goal')
    assert (first.outcome, first.code) == (fg.ABORTED, fg.INVALID_GOAL), first
    assert first.text == 'preempted by a new goal'
    e = d.until_ended(handle='second')
    assert e.outcome == fg.SUCCEEDED, e
    # y, which the new goal does not take, was stopped where it was, not left on the old path
    assert xy.axes['y'].status & S.STOPPED


@pytest.mark.core_slow
def test_a_refused_goal_leaves_the_running_one_alone(xy):
    d = Driver(xy)
    d.send(zigzag(xy))
    d.run(0.5)
    d.send(zigzag(xy) | {'names': ['x', 'q']}, handle='bad')
    bad = next(e for e in d.ended if e.handle == 'bad')
    assert bad.code == fg.INVALID_JOINTS
    assert d.until_ended().outcome == fg.SUCCEEDED


@pytest.mark.core_slow
@pytest.mark.parametrize('cause', ['estop', 'target', 'abort'])
def test_what_else_ends_a_goal_is_named(xy, cause):
    d = Driver(xy)
    d.send(zigzag(xy))
    d.run(0.5)
    x = xy.axes['x']
    if cause == 'estop':
        assert x.stop('estop')[0]
        expect = 'x: ESTOP, y: STOP ended the goal at t='    # (y: the coordinate system)
    elif cause == 'abort':
        assert x.abort()[0]
        expect = 'x: ABORT, y: STOP ended the goal at t='
    else:
        assert x.move_to(x.command_position)[0]
        expect = 'x: another command (joint_trajectory, target_position or target_velocity) ' \
                 'took the axis off the goal\'s path at t='
    e = d.until_ended()
    assert (e.outcome, e.code) == (fg.ABORTED, fg.INVALID_GOAL) and e.text.startswith(expect), e
    d.run(1.0)
    assert not xy.axes['y'].profile.moving         # the other axis does not run on unwatched


@pytest.mark.core_slow
def test_a_stamped_goal_starts_at_its_stamp_and_query_gives_the_desired_state(xy):
    d = Driver(xy)
    s = zigzag(xy, point0=False)
    stamp = xy.time + 0.3
    checked = d.send(s, stamp=stamp)
    assert checked.start == stamp
    assert d.runner.feedback(xy.time) is None
    names, states = d.runner.desired_at(stamp + 1.6)
    assert names == ('x', 'y') and states[0][0] == pytest.approx(s['positions'][-1][0])
    assert 'before the trajectory' in d.runner.desired_at(stamp - 0.1)
    start = here(xy)
    d.run(0.25)
    assert here(xy) == start
    d.run(0.2)
    assert here(xy)['x'] > start['x']
    mid = d.runner.desired_at(stamp + 0.8)[1][0]
    assert start['x'] < mid[0] < s['positions'][-1][0]
    assert d.until_ended().outcome == fg.SUCCEEDED
    assert d.runner.desired_at(xy.time) == 'no follow_joint_trajectory goal is active'


def test_tolerance_excess_reports_the_first_quantity_beyond():
    t = fg.Tolerance(0.001, 0.0, 2.0)
    assert t.excess((0.0005, 99.0, 1.0)) is None               # velocity not checked
    assert t.excess((-0.0015, 0.0, 3.0)) == ('position', -0.0015, 0.001)
    assert t.excess((0.0, 0.0, -math.inf)) == ('acceleration', -math.inf, 2.0)
