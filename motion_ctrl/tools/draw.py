"""The coordinated-motion example (issue 16): two axes draw a circle and a rounded square.

Starts plant and controller with two axes, x and y (each the default backlash slide), sends each
shape as one trajectory_msgs/JointTrajectory on `joint_trajectory` (PMAC PVT: both axes on one
time base), and judges the path the way a ballbar test does: the contour error, the distance of
the true slide position (XY, from `plant_states`, the simulation's ground truth) from the
commanded path, in linear counts; the first quarter of the path (the speed ramp) is left out of
the figures, as the issue asks. Prints the figures, writes a PNG: the path and, magnified, the
deviation from it, and the contour error along the path.

The controller runs `feedback: dual` with friction feedforward (PMAC Ixx68) set to the slide's
Coulomb friction in volts (--friction-ff, 0.24 V: motor 0.004 N·m plus slide 10 N through the
5.08 mm lead, over 0.1 N·m/A × 0.5 A/V): without it each axis stalls for a moment where its
velocity reverses (the quadrant glitch of every contouring machine), 19 counts on the circle in
the in-process harness. Both axes have the shipped slide's gains (doc/gains.md) but integrate
always (PMAC Ixx34 = 0): on a path each axis is commanding a move most of the time, and with the
shipped Ixx34 = 1 the integrator held through it left the square's corners 11-17 counts out
over DDS (RMS 3.7-4.2 counts; integrating always, 1.1).
"""
from __future__ import annotations

import argparse
import datetime
import pathlib
import sys
import time

import numpy as np
import rclpy
from action_msgs.msg import GoalStatus
from builtin_interfaces.msg import Time
from control_msgs.action import FollowJointTrajectory
from rclpy.action import ActionClient
from sensor_msgs.msg import JointState

import msg_defs as md
from msg_defs.status import Status
from motion_ctrl.analysis.contour import AXES, judge, shape_points
from motion_ctrl.core import trajectory as tj
from motion_ctrl.core.registers import LOAD_COUNTS_PER_M
from motion_ctrl.plotting.contour import plot
from motion_ctrl.ros import ros_env
from motion_ctrl.ros.client import SlideClient
from motion_ctrl.ros.processes import first_fault, start_slide


def commanded(client, timeout: float = 5.0) -> dict | None:
    """Where the controller commands the axes now ({axis: m}, a reference_states sample), or
    None. Read when needed, not followed: a 1 kHz stream more in this process would queue its
    events ahead of the status words the example waits on."""
    command: dict = {}
    sub = client.create_subscription(JointState, md.REFERENCE_STATES,
                                     lambda m: command.update(zip(m.name, m.position)),
                                     md.SERVO_READ_QOS)
    try:
        client.spin_until(lambda: all(a in command for a in AXES), timeout)
    finally:
        client.destroy_subscription(sub)
    return {a: command[a] for a in AXES} if all(a in command for a in AXES) else None


class _ActionSender:
    """The shapes as FollowJointTrajectory goals (control_msgs), as MoveIt's trajectory
    execution sends them: the goal, then its result."""

    def __init__(self, client):
        self.client = client
        self.Goal = FollowJointTrajectory.Goal
        self.action = ActionClient(client, FollowJointTrajectory,
                                   '/controller/follow_joint_trajectory')
        if not client.spin_until(self.action.server_is_ready, 10.0):
            raise RuntimeError('/controller/follow_joint_trajectory is not offered')

    def follow(self, names, points: tj.Points) -> str:
        """Send the goal, wait for its result; the outcome's name (or why none came)."""
        goal = self.Goal(trajectory=md.joint_trajectory(
            Time(), names, points.times, points.positions, points.velocities,
            points.accelerations))
        sent = self.action.send_goal_async(goal)
        if not self.client.spin_until(sent.done, 10.0) or not sent.result().accepted:
            return 'not accepted'
        result = sent.result().get_result_async()
        if not self.client.spin_until(result.done, float(points.times[-1]) + 10.0):
            return 'no result'
        r = result.result()
        if r.status != GoalStatus.STATUS_SUCCEEDED:
            print(f'draw: the goal ended ({r.result.error_code}): {r.result.error_string}',
                  file=sys.stderr)
        return {GoalStatus.STATUS_SUCCEEDED: 'SUCCEEDED', GoalStatus.STATUS_ABORTED: 'ABORTED',
                GoalStatus.STATUS_CANCELED: 'CANCELED'}.get(r.status, str(r.status))


def parser() -> argparse.ArgumentParser:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument('--shapes', default='circle,square',
                    help='comma-separated: circle, square (default both)')
    ap.add_argument('--radius', type=float, default=0.010,
                    help='circle radius; the square has sides of twice it [m] (default 0.01)')
    ap.add_argument('--speed', type=float, default=0.020, help='path speed [m/s] (0.02)')
    ap.add_argument('--feedback', default='dual', choices=('motor', 'load', 'dual', 'sampled'))
    ap.add_argument('--friction-ff', type=float, default=0.24,
                    help='friction feedforward of both axes [V] (0.24: the slide\'s friction)')
    ap.add_argument('--realtime-priority', type=int, default=30,
                    help='realtime_priority of both nodes (0: normal scheduling; '
                         'doc/several_axes.md: '
                         'with this example running beside them on two cores, normal '
                         'scheduling lets the nodes wait)')
    ap.add_argument('-p', '--param', action='append', default=[], metavar='NAME:=VALUE',
                    help='another controller parameter (repeatable), e.g. x.kp:=20000')
    ap.add_argument('--action', action='store_true',
                    help='send each shape as a control_msgs FollowJointTrajectory goal to '
                         '/controller/follow_joint_trajectory (as MoveIt does) instead of on '
                         'joint_trajectory; the last column is then the goal\'s result')
    ap.add_argument('-o', '--out', default=None, help='directory (default out/draw-<time>)')
    return ap


def main(argv=None) -> int:
    """Start plant and controller with axes x and y, draw each shape, print its figures, plot
    them; exit 0 when every shape finished."""
    ap = parser()
    args = ap.parse_args(argv)
    shapes = [s.strip() for s in args.shapes.split(',') if s.strip()]
    extra = dict(p.split(':=', 1) for p in args.param if ':=' in p)
    if len(extra) != len(args.param):
        ap.error('--param takes NAME:=VALUE')
    if not shapes or any(s not in ('circle', 'square') for s in shapes):
        ap.error(f'--shapes: circle and/or square, got {args.shapes!r}')
    domain = ros_env.private_domain()

    out = pathlib.Path(args.out or datetime.datetime.now().strftime('out/draw-%Y%m%d-%H%M%S'))
    out.mkdir(parents=True, exist_ok=True)
    print(f'draw: starting plant and controller for axes x, y (ROS_DOMAIN_ID={domain}, logs in '
          f'{out})')
    nodes = _start_nodes(args, extra, out)
    rclpy.init()
    client = SlideClient(axes=AXES)
    truth = _follow_truth(client)
    results: dict = {}
    code = 0
    try:
        if not client.wait_ready(20.0) or commanded(client) is None:
            print(f'draw: the nodes did not come up ({client.not_ready()}); see the logs',
                  file=sys.stderr)
            return 1
        client.spin_until(lambda: client.pub_trajectory.get_subscription_count() > 0, 5.0)
        action = _ActionSender(client) if args.action else None
        done_column = 'result' if action else 'MOTION_DONE'
        print(f'{"shape":<8}{"points":>7}{"time [s]":>9}{"contour RMS":>13}{"peak":>8}'
              f'{"x error":>9}{"y error":>9}{done_column:>13}   (counts; after 1st quarter)')
        for shape in shapes:
            row, r = _draw_shape(client, action, shape, args, truth, nodes, out)
            print(row)
            if r is None:
                code = 1
            else:
                results[shape] = r
    finally:
        client.destroy_node()
        rclpy.try_shutdown()
        rcs = [n.stop() for n in reversed(nodes)]
        print('draw: nodes stopped (exit codes ' + ', '.join(map(str, rcs)) + ')')
    if results:
        png = out / 'draw.png'
        plot(results, png)
        print(f'draw: plot in {png}')
    return code


def _start_nodes(args, extra: dict, out: pathlib.Path) -> list:
    """Plant and controller for axes x and y: each axis on --feedback with --friction-ff,
    integrating always (PMAC Ixx34 = 0), both nodes at --realtime-priority."""
    axes = '[' + ', '.join(f"'{a}'" for a in AXES) + ']'     # quoted: y is a YAML boolean
    ctrl = {'axes': axes} | {f'{a}.{k}': v for a in AXES for k, v in
                             (('feedback', args.feedback), ('friction_ff', args.friction_ff),
                              ('integration_mode', 'always'))}
    rt = {'realtime_priority': args.realtime_priority}
    ctrl |= rt | extra
    return start_slide(ctrl, {'axes': axes} | rt, log_dir=out)


def _follow_truth(client) -> list:
    """The true XY (plant_states' load positions) as (epoch s, x, y), appended as they come."""
    truth: list = []

    def on_truth(msg):
        d = dict(zip(msg.name, msg.position))
        if all(md.load_joint(a) in d for a in AXES):
            truth.append((time.time(), d[md.load_joint('x')], d[md.load_joint('y')]))
    client.create_subscription(JointState, md.PLANT_STATES, on_truth, md.SERVO_READ_QOS)
    return truth


def _draw_shape(client, action, shape: str, args, truth: list, nodes,
                out: pathlib.Path) -> tuple[str, dict | None]:
    """One shape drawn from where the axes are and judged: its row of the table and its
    figures, or why it did not finish and None."""
    start = commanded(client)
    if start is None:
        return f'{shape:<8}no reference_states from the controller (the logs are in {out})', None
    points, _ = shape_points(shape, start, args.radius, args.speed)
    truth.clear()
    t0 = time.time()
    if action is not None:
        outcome = action.follow(list(AXES), points)
        done = outcome == 'SUCCEEDED'
    else:
        outcome = 'yes'
        done = client.follow(list(AXES), points.times, points.positions,
                             points.velocities, points.accelerations) is not None
    # the user's copy of plant_states can lag a loaded machine (doc/design_notes.md): the
    # final figures from a sample of after the end
    client.truth_since(time.time())
    client.spin_for(0.05)
    samples = np.array(truth).reshape(-1, 3)
    if not done or len(samples) == 0:
        why = first_fault(nodes) or 'no fault logged; ' + ', '.join(
            f'{a} {Status(client.status[a] or 0)!r}' for a in AXES)
        return f'{shape:<8}did not finish: {why} (the logs are in {out})', None
    r = judge(points, start, samples[:, 0] - t0, samples[:, 1:])
    r['truth'] = samples[:, 1:]
    end = points.positions[-1]
    errs = [(samples[-1, 1 + j] - end[j]) * LOAD_COUNTS_PER_M for j in range(2)]
    return (f'{shape:<8}{len(points.times):>7}{points.times[-1]:>9.2f}{r["rms"]:>13.2f}'
            f'{r["peak"]:>8.2f}{errs[0]:>+9.2f}{errs[1]:>+9.2f}'
            f'{outcome:>13}'), r


if __name__ == '__main__':
    sys.exit(main())
