"""The session the tools that work on one axis share (calibrate, identify, autotune): their
common options, the simulated slide started when asked (--spawn, --lockstep, --hardware), the
tool's ROS client, ready, and `AxisUnderTest`: one axis of a running controller driven as any
ROS user drives it (targets on `target_position`, MOTION_DONE from `<axis>/status`, readings
from `joint_states`, registers through the parameter services `ros2 param` uses).

rclpy, the message packages and motion_ctrl.ros are imported inside the functions that use them:
`--help` and a tool's offline modes (autotune --from) start without them, and the ROS-free tests
run autotune's offline mode where ROS refuses to import (test/analysis/test_autotune.py).
"""
from __future__ import annotations

import argparse
import contextlib
import datetime
import pathlib

import numpy as np

import msg_defs as md
from msg_defs.status import Status


class SessionError(RuntimeError):
    """What stops a tool's run on an axis: the controller not ready, a register refused, a move
    that did not end; the tools print it and exit 1."""


class AxisUnderTest:
    """One axis of a running controller, driven through a SlideClient (topics, services) and
    the controller's parameter services."""

    def __init__(self, client, axis: str = 'x', controller: str = 'controller'):
        from rclpy.parameter_client import AsyncParameterClient
        from sensor_msgs.msg import JointState
        self.client, self.axis = client, axis
        self.params = AsyncParameterClient(client, controller)
        # joint_states arrive at the servo rate: taken raw (no Python message per sample, the
        # tool must not load the machine whose loop it measures) and only while a reading is
        # being taken. Subscribed once, now: a reader joining later stalls the controller's
        # publishers while Fast DDS health-checks it (doc/design_notes.md).
        self._raw: list[bytes] = []
        self._collect = False
        self._type = JointState
        client.create_subscription(JointState, md.JOINT_STATES, self._on_joint,
                                   md.SERVO_READ_QOS, raw=True)

    def _on_joint(self, data: bytes) -> None:
        if self._collect:
            self._raw.append(data)

    # -- registers ---------------------------------------------------------------------------
    def get(self, *names) -> dict:
        from rclpy.parameter import parameter_value_to_python
        full = [f'{self.axis}.{n}' for n in names]
        if not self.client.spin_until(self.params.services_are_ready, 10.0):
            raise SessionError('the controller\'s parameter services are not there')
        values = self.client.answer(lambda: self.params.get_parameters(full)).values
        return {n: parameter_value_to_python(v) for n, v in zip(names, values)}

    def set(self, values: dict) -> None:
        """Set registers together (set_parameters_atomically); raise with the refusal."""
        from rclpy.parameter import Parameter
        params = []
        for n, v in values.items():
            name = f'{self.axis}.{n}'
            if isinstance(v, (list, tuple)):     # typed: an empty list has no type of its own
                params.append(Parameter(name, Parameter.Type.DOUBLE_ARRAY, [float(x) for x in v]))
            else:
                params.append(Parameter(name, value=v))
        result = self.client.answer(
            lambda: self.params.set_parameters_atomically(params)).result
        if not result.successful:
            raise SessionError(f'controller refused {sorted(values)}: {result.reason}')

    def load_file(self, path) -> None:
        """`ros2 param load` of a YAML file, all of it at once (load_parameter_file_atomically),
        so a table and its spacing change together."""
        response = self.client.answer(
            lambda: self.params.load_parameter_file_atomically(str(path)))
        if not response.result.successful:
            raise SessionError(f'controller refused {path}: {response.result.reason}')

    def not_ready(self) -> str:
        """Why the axis cannot be moved, measured or tuned now ('' when it can): a fault, or
        not enabled."""
        from motion_ctrl.ros.client import FAULTS
        word = self.client.status[self.axis] or 0
        if word & FAULTS or not word & Status.ENABLED:
            return (f'axis {self.axis} is not ready ({Status(word)!r}): reset and enable it '
                    f'first ({self.axis}/reset, {self.axis}/enable)')
        return ''

    # -- motion and readings -----------------------------------------------------------------
    def move(self, position: float, timeout: float) -> None:
        if self.client.move({self.axis: position}, timeout=timeout) is None:
            word = self.client.status[self.axis]
            raise SessionError(f'move to {position:.6f} m: no MOTION_DONE within '
                                   f'{timeout:g} s (status {Status(word or 0)!r})')

    def approach(self, position: float, direction: int, distance: float, duration: float,
                 timeout: float) -> None:
        """Reach `position` moving in `direction` (+1/-1) the way a repeatable reading needs:
        a move to `distance` short of it, then the last `distance` as a slow PVT segment of
        `duration` s (joint_trajectory, ending at rest). A motor loop that arrives at speed
        overshoots by an amount that varies with the servo latency (over DDS, 0-2 ms) and the
        slide, carried along, stays there across the backlash: harness, 2 ticks of latency,
        six approaches land 6-16 counts long; with a 0.5 mm, 0.5 s final segment 1.6-1.9.
        `distance` 0: a plain move."""
        if distance > 0.0:
            self.move(position - direction * distance, timeout)
            if self.client.follow([self.axis], [duration], [[position]],
                                  timeout=timeout) is not None:
                return
            word = self.client.status[self.axis]
            raise SessionError(f'final approach to {position:.6f} m: no MOTION_DONE '
                                   f'(status {Status(word or 0)!r})')
        self.move(position, timeout)

    def samples(self, count: int, timeout: float = 10.0) -> list:
        """The next `count` joint_states messages (decoded)."""
        from rclpy.serialization import deserialize_message
        self._raw.clear()
        self._collect = True
        try:
            if not self.client.spin_until(lambda: len(self._raw) >= count, timeout):
                raise SessionError(f'joint_states: {len(self._raw)} of {count} '
                                       f'samples in {timeout:g} s')
        finally:
            self._collect = False
        return [deserialize_message(data, self._type) for data in self._raw[:count]]

    def read_load(self, dwell: int, average: int, timeout: float = 10.0) -> float:
        """The load encoder at rest: `dwell` joint_states samples skipped after MOTION_DONE,
        the mean of the next `average` [m]. Counted in samples, not seconds, so the reading is
        the same in real time and in lockstep simulation."""
        values = [msg.position[list(msg.name).index(self.axis)]
                  for msg in self.samples(dwell + average, timeout)[dwell:]]
        return float(np.mean(values))


def pair(text: str) -> tuple[float, float]:
    """A 'LO,HI' option as two floats (argparse reports a bad one)."""
    lo, _, hi = text.partition(',')
    return float(lo), float(hi)


def spawned_hardware(args) -> str:
    """The hardware of the slide --spawn starts: --hardware, else sim in lockstep (one process,
    the fastest) and topics in real time (plant and controller, as the demo)."""
    return args.hardware or ('sim' if args.lockstep else 'topics')


def spawn(args, out: pathlib.Path):
    """The simulated slide's processes (lockstep.start_slide, processes.start_slide or
    start_sim)."""
    from motion_ctrl.ros import lockstep
    from motion_ctrl.ros.processes import start_sim, start_slide
    plant_params = dict(p.split(':=', 1) for p in args.plant)
    controller_params = dict(p.split(':=', 1) for p in args.controller)
    hardware = spawned_hardware(args)
    if args.lockstep:
        return lockstep.start_slide(controller_params, plant_params, log_dir=out,
                                    hardware=hardware)
    start = start_sim if hardware == 'sim' else start_slide
    return start(controller_params, plant_params, log_dir=out)


def session_arguments(ap: argparse.ArgumentParser, tool: str, plant_example: str) -> None:
    """The options of a tool run on one axis (axis_session): output folder, --spawn,
    --lockstep, plant and controller parameters for the spawned slide."""
    ap.add_argument('-o', '--out', default=None,
                    help=f'output directory (default out/{tool}-<time>)')
    ap.add_argument('--spawn', action='store_true',
                    help='start the simulated slide (plant + controller processes) for the run')
    ap.add_argument('--lockstep', action='store_true',
                    help='with --spawn: the deterministic lockstep simulation')
    ap.add_argument('--hardware', choices=('sim', 'topics'), default=None,
                    help='with --spawn: the slide inside the controller\'s loop (sim: one '
                         'process; the default with --lockstep) or a plant node beside it '
                         '(topics: two processes; the default in real time)')
    ap.add_argument('--plant', action='append', default=[], metavar='NAME:=VALUE',
                    help=f'with --spawn: a plant parameter, e.g. {plant_example}')
    ap.add_argument('--controller', action='append', default=[], metavar='NAME:=VALUE',
                    help='with --spawn: a controller parameter')


@contextlib.contextmanager
def axis_session(args, tool: str, services: bool = False, truth: bool = False):
    """The ROS side of a tool run on one axis (calibrate, identify, autotune): its output
    folder, the nodes when asked (--spawn, --lockstep), the tool's client, ready (`truth`: it
    reads the simulated plant's plant_states too, for a tool that reports the true slide beside
    what the controller saw). Yields (client, AxisUnderTest, out); stops everything after.
    Raises SessionError when the controller is not ready."""
    from motion_ctrl.ros import ros_env
    domain = ros_env.private_domain()
    import rclpy
    from motion_ctrl.ros.client import SlideClient
    out = pathlib.Path(args.out or datetime.datetime.now().strftime(
        f'out/{tool}-%Y%m%d-%H%M%S'))
    out.mkdir(parents=True, exist_ok=True)
    # The nodes first, then this participant, as the demo does (why: doc/design_notes.md, "A
    # client that starts before the nodes").
    nodes = spawn(args, out) if args.spawn else ()
    if args.lockstep:
        from motion_ctrl.ros.lockstep import client_context
        context = client_context(domain)
    else:
        rclpy.init()
        context = None
    client = SlideClient(axes=(args.axis,), name=tool, truth=truth, services=services,
                         context=context)
    try:
        if not client.wait_ready(30.0):
            raise SessionError(f'the controller is not ready ({client.not_ready()})')
        if nodes and spawned_hardware(args) == 'topics':
            # Just started: the controller closes its loop on the first encoder samples, maybe
            # before its `command` reaches the plant (a move then runs into
            # FOLLOWING_ERROR_FATAL on a motor that does not turn). Wait until the graph shows
            # the plant reading `command`, and a moment for the controller's side of the match.
            client.spin_until(lambda: client.count_subscribers(md.COMMAND) > 0, 20.0)
            client.spin_for(1.0)
        yield client, AxisUnderTest(client, args.axis), out
    finally:
        client.destroy_node()
        rclpy.try_shutdown(context=context)
        for n in reversed(nodes):
            n.stop()
