"""The shared kit of the tests of the product over DDS, split by interface (issue 31):
test_ros_parameters.py (the parameter services), test_ros_services.py (the per-axis services)
and test_ros_topics.py (targets, trajectories, status, diagnostics, malformed inputs and
floods; it ends with the clean stop on SIGINT). Plant and controller run as separate processes
(`python -m motion_ctrl.<node> --ros-args --params-file ...`, as `ros2 run` starts them) and the
tests drive them through the public contract only — topics, per-axis services and the
parameter services `ros2 param` uses — and check what a user would notice.

Each of those modules imports the `slide` and `axis` fixtures from here: one plant + controller
pair serves a whole module (start-up costs seconds; each module on its own ROS domain,
conftest.module_domain); every test starts from an enabled, unfaulted axis at rest (`axis`
fixture) and puts back any parameter it changed. Waits are on conditions with deadlines, never
fixed sleeps.

Not a test module (pytest collects test_*.py): test/ros is on sys.path as the folder of the
test modules that import it.
"""
from __future__ import annotations

import contextlib
import pathlib
import re
import time
from collections import deque

import pytest
from diagnostic_msgs.msg import DiagnosticArray
from rclpy.parameter import Parameter, parameter_value_to_python
from rclpy.parameter_client import AsyncParameterClient
from sensor_msgs.msg import JointState

import msg_defs as md
from msg_defs.status import Status
from kit import COUNT, note_link_stalls, running_slide
from motion_ctrl.ros.client import SlideClient

# The shipped parameters, the 20 ms encoder watchdog included (tested on its own at the end of
# test_ros_topics.py, when the plant stops). The `axis` fixture repairs a fault, so one costs one
# test, not the module.

FAULTS = Status.FOLLOWING_ERROR_FATAL | Status.FEEDBACK_FAULT


def _stamp(msg) -> float:
    return msg.header.stamp.sec + msg.header.stamp.nanosec * 1e-9


class Probe(SlideClient):
    """A ROS user in a process of its own: SlideClient plus logs of joint_states,
    reference_states and /diagnostics, the axis services and a parameter client."""

    def __init__(self, axis='x'):
        super().__init__(axes=(axis,), name='ros_test_probe', services=True)
        self.axis = axis
        self.joint_log = deque(maxlen=30000)   # (stamp, position, velocity, effort)
        self.joint_count = 0
        self.ref_log = deque(maxlen=30000)     # (stamp, position, velocity)
        self.command_log = deque(maxlen=30000) # (stamp, effort): every tick, read reliably
        self.diag = []                         # (monotonic, DiagnosticArray)
        self.joint = None                      # latest joint_states
        self.create_subscription(JointState, md.JOINT_STATES, self._on_joint,
                                 md.SERVO_READ_QOS)
        self.create_subscription(JointState, md.REFERENCE_STATES, self._on_reference,
                                 md.SERVO_QOS)
        self.create_subscription(
            JointState, md.COMMAND,
            lambda m: self.command_log.append((_stamp(m), m.effort[list(m.name).index(axis)])),
            md.SERVO_QOS)
        self.create_subscription(DiagnosticArray, md.DIAGNOSTICS,
                                 lambda m: self.diag.append((time.monotonic(), m)), 10)
        self.params = AsyncParameterClient(self, 'controller')
        self.plant_params = AsyncParameterClient(self, 'plant')

    # -- subscriptions ---------------------------------------------------------------------------
    def _on_joint(self, msg):
        self.joint = msg
        i = list(msg.name).index(self.axis)
        self.joint_log.append((_stamp(msg), msg.position[i], msg.velocity[i], msg.effort[i]))
        self.joint_count += 1

    def _on_status(self, axis, msg):
        super()._on_status(axis, msg)
        self.status_count = getattr(self, 'status_count', 0) + 1

    def _on_truth(self, msg):
        super()._on_truth(msg)
        self.truth_velocity = dict(zip(msg.name, msg.velocity))

    def slide_at_rest(self) -> bool:
        v = getattr(self, 'truth_velocity', {}).get(md.load_joint(self.axis))
        return v is not None and abs(v) < 1e-4

    def _on_reference(self, msg):
        i = list(msg.name).index(self.axis)
        self.ref_log.append((_stamp(msg), msg.position[i], msg.velocity[i]))

    # -- spinning --------------------------------------------------------------------------------
    def spin_for_messages(self, n: int, timeout: float = 2.0) -> list:
        """The next n joint_states samples."""
        start = self.joint_count
        assert self.spin_until(lambda: self.joint_count >= start + n, timeout), \
            f'joint_states stopped: {self.joint_count - start} of {n} in {timeout} s'
        return list(self.joint_log)[-(self.joint_count - start):]

    def assert_loop_running(self, n: int = 200) -> None:
        """The servo loop still ticks: n new joint_states, each stamped later than the last.
        (How fast it ticks is for the benchmark and /diagnostics, which a test checks against
        the stream itself.)"""
        stamps = [s[0] for s in self.spin_for_messages(n, timeout=10.0)]
        assert all(b > a for a, b in zip(stamps, stamps[1:])), \
            f'joint_states stamps do not advance; {self.loop_note()}'

    def samples_after(self, stamp: float, n: int = 50, timeout: float = 2.0) -> list:
        """The first n joint_states stamped after `stamp` (ROS time [s])."""
        def fresh():
            return [s for s in self.joint_log if s[0] > stamp]
        assert self.spin_until(lambda: len(fresh()) >= n, timeout), 'joint_states stopped'
        return fresh()[:n]

    def now(self) -> float:
        return self.get_clock().now().nanoseconds * 1e-9


    # -- status ----------------------------------------------------------------------------------
    @property
    def word(self) -> Status:
        return Status(self.status[self.axis] or 0)

    def wait_status(self, predicate, timeout=3.0) -> bool:
        return self.spin_until(lambda: self.status[self.axis] is not None
                               and predicate(self.word), timeout)

    def mark(self) -> int:
        return len(self.status_log[self.axis])

    def words_since(self, mark: int) -> list:
        return [Status(w) for _, w in self.status_log[self.axis][mark:]]

    def done_since(self, mark: int) -> bool:
        return self.move_done(self.axis, mark)

    # -- commands --------------------------------------------------------------------------------
    def publish_target(self, position, names=None) -> int:
        names = [self.axis] if names is None else names
        positions = position if isinstance(position, (list, tuple)) else [position]
        msg = JointState()
        msg.header.stamp = self.get_clock().now().to_msg()
        msg.name = list(names)
        msg.position = [float(v) for v in positions]
        mark = self.mark()
        self.pub_target.publish(msg)
        return mark

    def loop_note(self) -> str:
        """The controller's own last word on its loop rate, for failure messages: a VM too
        loaded to hold 1 kHz shows here."""
        if not self.diag:
            return 'no /diagnostics seen'
        loop = [s for s in self.diag[-1][1].status if s.name.endswith('servo loop')]
        return f'last /diagnostics: servo loop {loop[0].message}' if loop else ''

    def move_and_wait(self, target: float, timeout: float = 6.0) -> None:
        t0 = time.monotonic()
        mark = self.publish_target(target)
        assert self.spin_until(lambda: self.done_since(mark), timeout), (
            f'move to {target} m not done in {timeout} s; status words (s after the target '
            'was sent) '
            f'{[(round(t - t0, 3), hex(w)) for t, w in self.status_log[self.axis][mark:]]}'
            f'; {self.loop_note()}')

    def position(self) -> float:
        """Load (slide) position from joint_states."""
        self.spin_for_messages(1)
        return self.joint_log[-1][1]

    # -- parameters ------------------------------------------------------------------------------
    def set_params(self, params: dict) -> list:
        """One set_parameters call (each parameter judged alone, in order)."""
        return self.answer(lambda: self.params.set_parameters(_parameters(params))).results

    def set_atomically(self, params: dict):
        return self.answer(
            lambda: self.params.set_parameters_atomically(_parameters(params))).result

    def get_params(self, *names) -> dict:
        values = self.answer(lambda: self.params.get_parameters(list(names))).values
        return {n: parameter_value_to_python(v) for n, v in zip(names, values)}

    def describe(self, *names) -> list:
        return self.answer(lambda: self.params.describe_parameters(list(names))).descriptors


def _parameters(params: dict) -> list:
    out = []
    for name, value in params.items():
        out.append(value if isinstance(value, Parameter) else Parameter(name, value=value))
    return out


@contextlib.contextmanager
def changed(probe: Probe, params: dict):
    """Set `params` atomically for the body of the with-block, then put the old values back."""
    old = probe.get_params(*params)
    result = probe.set_atomically(params)
    assert result.successful, result.reason
    try:
        yield
    finally:
        result = probe.set_atomically(old)
        assert result.successful, f'restoring {old}: {result.reason}'


def on_grid(position: float) -> float:
    """The nearest whole linear count: only such a target can settle inside the default fine
    tolerance (1 um < half a count; see test_off_grid_target_settles)."""
    return round(position / COUNT) * COUNT


def far_target(position: float, distance: float) -> float:
    """A target `distance` away, towards the middle of the travel once beyond 0.2 m (so well
    inside the soft limits), on the load encoder's grid."""
    return on_grid(position - distance if position > 0.2 else position + distance)


class LogFile:
    def __init__(self, path):
        self.path = pathlib.Path(path)

    def text(self) -> str:
        return self.path.read_text(errors='replace') if self.path.exists() else ''

    def count(self, pattern: str) -> int:
        return len(re.findall(pattern, self.text()))


def wait_log(probe: Probe, log: LogFile, pattern: str, count: int, timeout=3.0) -> bool:
    last = [0.0]

    def seen():          # read the file at most every 20 ms, not at every spun callback
        now = time.monotonic()
        if now - last[0] < 0.02:
            return False
        last[0] = now
        return log.count(pattern) >= count
    return probe.spin_until(seen, timeout) or log.count(pattern) >= count


# -- fixtures ------------------------------------------------------------------------------------
# A test module imports axis_fixture and slide_fixture (unused names to the linter, F401): pytest
# finds them there under their fixture names, `axis` and `slide`, named apart from the functions
# so that a test's `axis` argument does not shadow an import (pyflakes F811).
class Slide:
    def __init__(self, plant, controller, probe, log_dir):
        self.plant, self.controller, self.probe = plant, controller, probe
        self.controller_log = LogFile(log_dir / 'controller.log')
        self.plant_log = LogFile(log_dir / 'plant.log')


@pytest.fixture(scope='module', name='slide')
def slide_fixture(rclpy_session, tmp_path_factory):
    with running_slide(tmp_path_factory.mktemp('slide'), Probe,
                       ready=lambda probe: probe.params.wait_for_services(10.0)) as s:
        yield Slide(s.plant, s.controller, s.client, s.log_dir)


def _ready(s: Status) -> bool:
    return bool(s & Status.ENABLED and s & Status.MOTION_DONE
                and not s & (Status.MOVING | FAULTS))


@pytest.fixture(name='axis')
def axis_fixture(slide, request):
    """The probe, with the axis enabled, unfaulted and at rest, within +-0.3 m (repaired if a
    test, or a stall of the VM, left it otherwise). A stall of the servo link during the test
    (conftest.pytest_runtest_protocol) is noted on the test."""
    p = _ready_axis(slide)
    logs = (slide.controller_log, slide.plant_log)
    start = [len(log.text()) for log in logs]
    yield p
    note_link_stalls(request, *(log.text()[n:] for log, n in zip(logs, start)))


def _ready_axis(slide):
    p = slide.probe
    assert slide.controller.proc.poll() is None, 'controller died:\n' + \
        slide.controller_log.text()[-3000:]
    for _ in range(3):
        if p.wait_status(_ready, 1.0) and abs(p.position()) <= 0.3:
            return p
        # Open the loop, let the slide come to rest, clear faults, close the loop there.
        p.call('abort')
        p.spin_until(p.slide_at_rest, 3.0)
        p.call('reset')
        p.call('enable', True)
        if p.wait_status(_ready, 3.0) and abs(p.position()) > 0.3:
            p.publish_target(0.0)
            p.spin_until(lambda: abs(p.joint_log[-1][1]) < 0.3 and _ready(p.word), 10.0)
    assert p.wait_status(_ready, 1.0), f'axis not ready: {p.word!r}'
    return p


# -- helpers of more than one module ---------------------------------------------------------------
def _efforts_now(p: Probe, n=50) -> set:
    """Efforts of joint_states computed from now on (older ones may still be queued)."""
    return {e for *_, e in p.samples_after(p.now(), n)}


def _publish_target_ahead(p: Probe, position: float, ahead: float) -> None:
    msg = JointState()
    t = p.get_clock().now().nanoseconds + round(ahead * 1e9)
    msg.header.stamp.sec, msg.header.stamp.nanosec = divmod(t, 1_000_000_000)
    msg.name, msg.position = [p.axis], [float(position)]
    p.pub_target.publish(msg)
