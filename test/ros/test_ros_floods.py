"""Inputs cannot push the loop around (issue 27): floods of targets, oversized inputs and a stall
of the controller's loop process, against plant and controller as processes with the default
parameters. Behaviour only: the latest target wins and lands, the oversized inputs are refused
with their size (never echoed), the loop runs on, and a 50 ms freeze mid-move neither sprints
nor loses the move. What a flood costs the loop's rate is measured by `soak --floods`
(motion_ctrl/procedures/floods.py), not asserted here.
"""
from __future__ import annotations

import math
import os
import signal
import time

import pytest

rclpy = pytest.importorskip('rclpy')

from rclpy.parameter import Parameter  # noqa: E402
from rclpy.parameter_client import AsyncParameterClient  # noqa: E402
from rclpy.serialization import serialize_message  # noqa: E402
from builtin_interfaces.msg import Time  # noqa: E402

import msg_defs as md  # noqa: E402
from msg_defs.status import Status  # noqa: E402
from kit import COUNT, running_slide, spin_for  # noqa: E402
from motion_ctrl.core.registers import MAX_STRING_CHARS, MAX_TABLE_ENTRIES  # noqa: E402
from motion_ctrl.ros.client import FAULTS, SlideClient  # noqa: E402

try:
    import pytest_timeout  # noqa: F401
    pytestmark = pytest.mark.timeout(180)
except ImportError:
    pass

MAX_VELOCITY = 0.1          # m/s: the default max_velocity
OVERSPEED = 1.5 * MAX_VELOCITY   # the default overspeed_velocity (0: 1.5 x max_velocity)


def _stamp(msg) -> float:
    return msg.header.stamp.sec + msg.header.stamp.nanosec * 1e-9


class Watcher(SlideClient):
    """SlideClient keeping the true slide velocity (plant_states) and the loop's rate."""

    def __init__(self, context):
        super().__init__(name='floods', context=context, services=True)
        self.truth_log: list[tuple[float, float, float]] = []   # (stamp, position, velocity)
        self.params = AsyncParameterClient(self, 'controller')

    def _on_truth(self, msg):
        super()._on_truth(msg)
        i = list(msg.name).index(md.load_joint('x'))
        self.truth_log.append((_stamp(msg), msg.position[i], msg.velocity[i]))

    def set(self, parameter) -> str:
        """Set one parameter on the controller; '' when accepted, else the refusal."""
        assert self.params.wait_for_services(10.0)
        result = self.answer(lambda: self.params.set_parameters([parameter]), 20.0)
        r = result.results[0]
        return '' if r.successful else r.reason

    def unfaulted(self) -> bool:
        w = self.status['x']
        return w is not None and bool(w & Status.ENABLED) and not w & FAULTS


@pytest.fixture
def slide(own_domain, tmp_path):
    with running_slide(tmp_path, lambda: Watcher(own_domain), client_first=True) as s:
        spin_for(s.client, 1.0)
        assert s.client.call('reset').success and s.client.call('enable', True).success
        assert s.client.spin_until(s.client.unfaulted, 2.0), Status(s.client.status['x'])
        yield s


def _moves_to(client, target: float) -> float:
    """A move to `target`; the true slide error after it [counts]."""
    assert client.move({'x': target}, timeout=10.0) is not None, \
        f'no MOTION_DONE: {Status(client.status["x"])!r}'
    return (client.load_position() - target) / COUNT


def test_a_50_ms_freeze_mid_move_neither_sprints_nor_loses_the_move(slide):
    """The controller's loop process frozen 50 ms (SIGSTOP, SIGCONT) while the slide cruises
    at max_velocity: the plant's amplifier brakes the slide after its 10 ms watchdog; when the
    loop runs again it plans the move on from where the slide is (core.axis STALL_PERIODS)
    instead of driving the output to its limit to catch up (before: 328 mm/s, 3.3 x
    max_velocity). The true slide speed stays within overspeed_velocity and the move lands
    within a count, or the axis faults with OVERSPEED."""
    client = slide.client
    start = client.load_position()
    target = start + 0.1
    mark = len(client.status_log['x'])
    client.pub_target.publish(md.joint_state(client.get_clock().now().to_msg(), ['x'], [target]))
    assert client.spin_until(lambda: client.truth_log[-1][2] >= 0.99 * MAX_VELOCITY, 5.0), \
        f'slide not cruising: {client.truth_log[-1]}'
    spin_for(client, 0.1)
    loop = slide.controller.servo_pid()
    t_freeze = time.time()
    os.kill(loop, signal.SIGSTOP)
    time.sleep(0.05)
    os.kill(loop, signal.SIGCONT)
    assert client.wait_moves({'x': mark}, time.monotonic(), 10.0) is not None or \
        client.status['x'] & Status.OVERSPEED, f'{Status(client.status["x"])!r}'
    spin_for(client, 0.2)
    after = [v for t, _, v in client.truth_log if t > t_freeze]
    peak = max(abs(v) for v in after)
    word = Status(client.status['x'])
    error = (client.load_position() - target) / COUNT
    print(f'50 ms freeze: peak slide speed after it {peak * 1e3:.1f} mm/s '
          f'(max_velocity {MAX_VELOCITY * 1e3:g}), final error {error:+.2f} counts, {word!r}')
    assert peak <= OVERSPEED, f'{peak:.4f} m/s'
    if word & Status.OVERSPEED:
        assert 'OVERSPEED' in slide.log('controller')
    else:
        assert not word & FAULTS and abs(error) <= 1.0, (error, word)


def test_a_5_khz_target_flood_the_latest_target_wins_and_lands(slide):
    """10,000 targets at 5 kHz (a sweep of +-2 mm, five a servo tick; slower where this
    process cannot publish as fast): the loop takes the latest per tick, keeps running and
    lands the last one within a count, unfaulted."""
    client = slide.client
    start = client.load_position()
    raws = [serialize_message(md.joint_state(
        Time(), ['x'], [start + 0.002 * math.sin(2 * math.pi * k / 5000)])) for k in range(5000)]
    rate, total = 5000.0, 10000
    n, t0 = 0, time.monotonic()
    while n < total:                 # paced at `rate`, in bursts of what is due
        due = min(total, int((time.monotonic() - t0) * rate) + 1)
        while n < due:
            client.pub_target.publish(raws[n % len(raws)])
            n += 1
        time.sleep(0.001)
    seconds = time.monotonic() - t0
    last = start + 0.002 * math.sin(2 * math.pi * ((n - 1) % 5000) / 5000)
    spin_for(client, 0.5)
    assert client.spin_until(lambda: client.status['x'] & Status.MOTION_DONE, 5.0)
    spin_for(client, 0.1)
    error = (client.load_position() - last) / COUNT
    print(f'{n} targets in {seconds:.1f} s: the last lands {error:+.2f} counts off')
    assert client.unfaulted(), Status(client.status['x'])
    assert abs(error) <= 1.0
    assert abs(_moves_to(client, start)) <= 1.0


def test_oversized_inputs_are_refused_by_their_size_and_the_loop_runs_on(slide, tmp_path):
    """A 10,000-point JointTrajectory, a 100,000-entry table, a 1 MB string value and a
    `ros2 param load` of a 900 kB file: each refused naming its size and the limit (a refusal
    of a few dozen characters: the megabyte is not echoed), nothing changed, the axis
    unfaulted, and a move after them lands within a count."""
    client = slide.client
    traj = md.joint_trajectory(Time(), ['x'], [0.001 * (k + 1) for k in range(10000)],
                               [[client.load_position()]] * 10000)
    client.pub_trajectory.publish(traj)
    expected = 'joint_trajectory refused: 10000 points for 1 axes (at most 1500 points'
    assert client.spin_until(lambda: expected in slide.log('controller'), 5.0), \
        slide.log('controller')[-2000:]

    reason = client.set(Parameter('x.leadscrew_table', Parameter.Type.DOUBLE_ARRAY,
                                  [1e-6] * 100_000))
    assert reason == f'x.leadscrew_table: 100000 entries (at most {MAX_TABLE_ENTRIES})'

    reason = client.set(Parameter('x.feedback', Parameter.Type.STRING, 'm' * 1_000_000))
    assert reason == f'x.feedback: a 1000000-character string (at most {MAX_STRING_CHARS})'

    path = tmp_path / 'big.yaml'
    entries = ', '.join(['-1.0e-06'] * 90_000)
    path.write_text(f'controller:\n  ros__parameters:\n    x.leadscrew_table: [{entries}]\n')
    assert path.stat().st_size > 900_000
    future = client.params.load_parameter_file(str(path))
    assert client.spin_until(future.done, 20.0)
    [result] = future.result().results
    assert not result.successful
    assert result.reason == f'x.leadscrew_table: 90000 entries (at most {MAX_TABLE_ENTRIES})'

    assert client.unfaulted(), Status(client.status['x'])
    assert abs(_moves_to(client, client.load_position() + 0.002)) <= 1.0


def test_trajectory_counts_read_from_the_wire():
    """msg_defs.trajectory_counts, which refuses an oversized trajectory before it is decoded,
    reads (names, points) as rclpy's serializer writes them, frame ids and names of any
    length (CDR alignment), and gives None for what is not such a message."""
    for frame, names, points in (('', ['x'], 3), ('map', ['x', 'yy', 'zzz'], 0),
                                 ('a' * 7, [f'j{i}' * (i + 1) for i in range(9)], 17)):
        msg = md.joint_trajectory(Time(), names, [0.1 * (k + 1) for k in range(points)],
                                  [[0.0] * len(names)] * points)
        msg.header.frame_id = frame
        assert md.trajectory_counts(serialize_message(msg)) == (len(names), points)
    assert md.trajectory_counts(b'') is None
    assert md.trajectory_counts(b'\x00\x01\x00\x00' + b'\xff' * 40) is None
