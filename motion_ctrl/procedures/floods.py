"""Floods and oversized inputs against the running slide (`soak --floods`): what each costs the
servo loop, measured, never asserted (doc/input_limits.md). Run it on a quiet machine.

For each case it prints the loop's rate (/diagnostics `rate_hz`, one value a second) in the
seconds before the case and while it runs, their ratio (the target: >= 98 %), and after it a
valid target's landing error on the true slide in linear counts; the refusal the controller gave
is printed as it came (its length too: a refusal quotes a size, never the value).

* `unread 5 kHz`: the flooder alone, publishing JointState targets at 5 kHz on a topic nobody
  reads: the machine's own spread and the flooder's CPU;
* `target_position 5 kHz`: valid targets at 5 kHz for 10 s (a target sweeping +-5 mm, as a
  teleoperation stream would), the loop takes the latest one per tick; the last one must land;
* `trajectory 10,000 points`: a JointTrajectory of 10,000 points, once a second, refused by its
  count before it is decoded;
* `table 100,000 entries`: x.leadscrew_table set to 100,000 entries, once a second: refused by
  its size;
* `param load 900 kB`: what `ros2 param load` of a 900 kB params file (a table) sends
  (AsyncParameterClient.load_parameter_file: the file read by the client, then one
  set_parameters request), once a second;
* `string 1 MB`: x.feedback set to a 1,000,000-character string, once a second.
"""
from __future__ import annotations

import datetime
import math
import os
import pathlib
import statistics
import tempfile
import time

import rclpy
from builtin_interfaces.msg import Time
from diagnostic_msgs.msg import DiagnosticArray
from rclpy.parameter import Parameter, parameter_dict_from_yaml_file
from rclpy.parameter_client import AsyncParameterClient
from rclpy.serialization import serialize_message
from sensor_msgs.msg import JointState

import msg_defs as md
from motion_ctrl.core.registers import LOAD_COUNTS_PER_M
from motion_ctrl.ros import ros_env, servo_bus
from motion_ctrl.ros.client import SlideClient
from motion_ctrl.ros.processes import start_slide
from msg_defs.status import Status

FLOOD_RATE = 5000.0       # Hz of the target floods
FLOOD_SECONDS = 10.0      # s each target flood lasts
REPEAT_SECONDS = 5.0      # s of an oversized input sent once a second
QUIET_SECONDS = 3.0       # s of quiet before each case (its /diagnostics are the "before")
SWEEP = 0.005             # m: the flood's targets sweep +- this around the start
SWEEP_HZ = 0.5


def _stamp(msg) -> float:
    return msg.header.stamp.sec + msg.header.stamp.nanosec * 1e-9


class Floods:
    """The cases, on a SlideClient of a running slide (plant and controller started)."""

    def __init__(self, client, axis: str = 'x', print_=print, log_path=None):
        self.client, self.axis, self.print = client, axis, print_
        self.log_path = log_path          # the controller's log: refusals not answered to us
        self.diag: list[tuple[float, float]] = []       # (stamp, rate_hz)
        client.create_subscription(DiagnosticArray, md.DIAGNOSTICS, self._on_diag, 10)
        self.unread = client.create_publisher(JointState, 'floods_unread_target', 10)
        self.params = AsyncParameterClient(client, 'controller')
        self.rows: list[tuple] = []

    def _on_diag(self, msg) -> None:
        for st in msg.status:
            if st.name.endswith('servo loop'):
                values = {kv.key: kv.value for kv in st.values}
                if 'rate_hz' in values:
                    self.diag.append((_stamp(msg), float(values['rate_hz'])))

    def _now(self) -> float:
        return self.client.get_clock().now().nanoseconds * 1e-9

    def _rates(self, t0: float, t1: float) -> list[float]:
        """rate_hz of the /diagnostics whose second lies within [t0, t1] (ROS time)."""
        return [r for s, r in self.diag if t0 + 1.0 <= s <= t1 + 0.05]

    # -- the cases ----------------------------------------------------------------------------
    def run(self) -> list[tuple]:
        c, a = self.client, self.axis
        self.params.wait_for_services(10.0)
        start = c.load_position(a)
        sweep = [start + SWEEP * math.sin(2 * math.pi * SWEEP_HZ * k / FLOOD_RATE)
                 for k in range(int(FLOOD_RATE / SWEEP_HZ))]
        raws = [serialize_message(md.joint_state(_zero_stamp(), [a], [p])) for p in sweep]
        self._case('unread 5 kHz', lambda: self._flood(self.unread, raws), target=None)
        self._case('target_position 5 kHz', lambda: self._flood(c.pub_target, raws),
                   target=None, last=lambda: sweep[(self.sent - 1) % len(sweep)])
        traj = serialize_message(md.joint_trajectory(
            _zero_stamp(), [a], [0.001 * (k + 1) for k in range(10000)],
            [[start + 1e-6 * (k % 10)] for k in range(10000)]))
        self._case('trajectory 10,000 points', lambda: self._repeat(
            lambda: c.pub_trajectory.publish(traj)), log='joint_trajectory refused')
        table = Parameter(f'{a}.leadscrew_table', Parameter.Type.DOUBLE_ARRAY,
                          [1e-6] * 100_000)
        self._case('table 100,000 entries', lambda: self._repeat(
            lambda: self._set(table)))
        with tempfile.TemporaryDirectory() as d:
            path = pathlib.Path(d) / 'big.yaml'
            entries = ', '.join(['-1.0e-06'] * 90_000)
            path.write_text(f'controller:\n  ros__parameters:\n    {a}.leadscrew_table: '
                            f'[{entries}]\n')
            size = path.stat().st_size
            # What `ros2 param load` sends (AsyncParameterClient.load_parameter_file: the file
            # read here, then one set_parameters request), the file read once, beforehand:
            # PyYAML takes seconds for it, in this process, not the controller's.
            loaded = list(parameter_dict_from_yaml_file(
                str(path), False, target_nodes=['controller']).values())
        self._case(f'param load {size / 1000:.0f} kB', lambda: self._repeat(
            lambda: self._set(*loaded)))
        string = Parameter(f'{a}.feedback', Parameter.Type.STRING, 'm' * 1_000_000)
        self._case('string 1 MB', lambda: self._repeat(lambda: self._set(string)))
        return self.rows

    def _case(self, name: str, act, target=None, last=None, log=None) -> None:
        c, a = self.client, self.axis
        self.reason = ''
        self.sent = 0
        c.spin_for(QUIET_SECONDS)
        t0 = self._now()
        act()
        t1 = self._now()
        c.spin_for(1.5)                         # the last /diagnostics of the case
        before = self._rates(t0 - QUIET_SECONDS, t0)
        during = self._rates(t0, t1)
        landing = math.nan
        if last is not None:                    # the flood's last target: wait for it to land
            c.spin_for(0.5)
            c.spin_until(lambda: bool(c.status[a] & Status.MOTION_DONE), 5.0)
            landing = (c.load_position(a) - last()) * LOAD_COUNTS_PER_M
        else:                                   # a valid move after it lands
            here = c.load_position(a)
            target = here + (0.002 if here < 0.01 else -0.002)
            if c.move({a: target}) is not None:
                landing = (c.load_position(a) - target) * LOAD_COUNTS_PER_M
        if log and self.log_path is not None:     # the controller's last line saying so
            lines = [ln for ln in pathlib.Path(self.log_path).read_text().splitlines()
                     if log in ln]
            self.reason = lines[-1].split(': ', 1)[-1] if lines else ''
        row = (name, before, during, landing, self.reason)
        self.rows.append(row)
        self.print(format_row(row), flush=True)

    def _flood(self, publisher, raws) -> None:
        """Publish at FLOOD_RATE for FLOOD_SECONDS, in bursts of what is due (no spinning: on
        two cores the flooder must leave the nodes their CPU)."""
        period, n, start = 1.0 / FLOOD_RATE, 0, time.monotonic()
        while (now := time.monotonic()) < start + FLOOD_SECONDS:
            due = int((now - start) / period) + 1
            while n < due:
                publisher.publish(raws[n % len(raws)])
                n += 1
            time.sleep(max(0.0, start + n * period - time.monotonic()))
        self.sent = n

    def _repeat(self, send) -> None:
        """`send()` once a second for REPEAT_SECONDS, spinning between."""
        start = time.monotonic()
        for k in range(int(REPEAT_SECONDS)):
            send()
            self.client.spin_until(lambda: False, max(0.0, start + k + 1 - time.monotonic()))

    def _set(self, *parameters) -> None:
        future = self.params.set_parameters(list(parameters))
        self.client.spin_until(future.done, 5.0)
        result = future.result() if future.done() else None
        if result is not None:
            self.reason = result.results[0].reason


def _zero_stamp():
    return Time()


HEADER = (f'{"case":<28} {"before [Hz]":>12} {"during [Hz]":>12} {"ratio":>7} '
          f'{"landing [counts]":>17}  refusal (its length)')


def format_row(row) -> str:
    name, before, during, landing, reason = row
    b = statistics.mean(before) if before else math.nan
    d = statistics.mean(during) if during else math.nan
    shown = (reason[:110] + ' ...') if len(reason) > 110 else reason
    return (f'{name:<28} {b:>12.1f} {d:>12.1f} {100 * d / b:>6.1f}% {landing:>+17.2f}  '
            f'{shown}' + (f' ({len(reason)} chars)' if reason else '') +
            f'\n{"":<28} {" ".join(f"{r:.0f}" for r in before):>12} '
            f'{" ".join(f"{r:.0f}" for r in during)}')


def log_dir(out, name: str) -> pathlib.Path:
    """`out`, or out/<name>-<date>-<time> when None, made."""
    out = pathlib.Path(out or datetime.datetime.now().strftime(f'out/{name}-%Y%m%d-%H%M%S'))
    out.mkdir(parents=True, exist_ok=True)
    return out


def start_nodes(realtime_priority: int, servo_bus_setting: str, out: pathlib.Path) -> list:
    """Plant and controller as `soak` and the floods run them: both at `realtime_priority`, on
    the servo bus as `servo_bus_setting` says (MOTION_CTRL_SERVO_DOMAIN), their logs in `out`."""
    os.environ[servo_bus.ENV] = servo_bus_setting
    rt = {'realtime_priority': realtime_priority}
    return start_slide(rt, rt, log_dir=out)


def main(realtime_priority: int = 0, servo_bus_setting: str = 'auto', out=None) -> int:
    """Start the slide, run the cases, print the table; exit 0 when every case kept >= 98 % of
    the loop's rate and landed within a count (a measurement: run it on a quiet machine)."""
    domain = ros_env.private_domain()
    out = log_dir(out, 'floods')
    print(f'floods: ROS_DOMAIN_ID={domain}, servo bus {servo_bus_setting}, realtime_priority '
          f'{realtime_priority}, logs in {out}', flush=True)
    nodes = start_nodes(realtime_priority, servo_bus_setting, out)
    rclpy.init()
    client = SlideClient(services=True)
    try:
        if not client.wait_ready(30.0):
            print(f'floods: the nodes did not come up ({client.not_ready()})')
            return 1
        floods = Floods(client, log_path=out / 'controller.log')
        print(HEADER, flush=True)
        rows = floods.run()
    finally:
        client.destroy_node()
        rclpy.try_shutdown()
        rcs = [n.stop() for n in reversed(nodes)]
    print(f'floods: nodes stopped (exit codes {", ".join(map(str, rcs))})')
    ok = all(before and during and statistics.mean(during) >= 0.98 * statistics.mean(before)
             and abs(landing) <= 1.0 for _, before, during, landing, _ in rows)
    return 0 if ok else 1
