"""The servo bus: plant and controller exchange `encoders` and `command` (and `/clock` in
lockstep) on a ROS domain of their own that no tool joins; each node's ROS interface is mirrored
onto the user's domain by a bridge (motion_ctrl.ros.servo_bus.bridge). Why: doc/design_notes.md.

    user's domain      `controller` process (bridge)       `plant` process (bridge)
    ---------------------------|-------------------------------------|------------------
    servo bus          controller loop process  --command-->  plant loop process
    (ROS_DOMAIN_ID+50)                          <--encoders--

`supervise` is what each node's `run` calls first: in the process the user started it opens the
bridge and starts the node again as a child process on the bus (INSIDE set), which runs the loop.

Why a domain of its own: a participant joining a domain makes every participant there send to
its shared-memory port, and Fast DDS sends all of a participant's messages under one lock, so a
newcomer that the scheduler holds off the CPU while it owns its port's mutex stops the sender,
both servo streams with it, for tens to hundreds of ms, past the 20 ms feedback_timeout. rclpy
keeps the GIL through `publish()` and a service's response, so the loop stalls with any thread of
its process that sends to a newcomer. The loop therefore runs in a process whose only participant
is on the servo bus; the process the user started (`controller`, `plant`, `ros2 launch`) holds
the bridge, and a tool can hold up only that (measured: doc/design_notes.md, "ROS tools joining
the graph, and the servo bus").

MOTION_CTRL_SERVO_DOMAIN chooses the bus: unset or `auto` (the default), the domain 50 above
ROS_DOMAIN_ID (wrapping in 1..101, as motion_ctrl's own domains do, below Linux's ephemeral
ports); a number, that domain (plant and controller must agree); `off`, no bus: the node runs on
the user's domain itself (and takes its servo streams from any publisher there). A plant (or
controller) of another make answers on the user's domain: named by MOTION_CTRL_SERVO_PEER, the
bridge copies its stream in and the node's out (servo_bus.bridge, commander), a hop more each
way; any other source of `command` or `encoders` there is refused (one commander). Every
participant of the bus's processes talks loopback UDP only, its sockets bound to 127.0.0.1
(servo_bus.xml).
"""
from __future__ import annotations

import os
import re
import signal
import subprocess
import sys
import threading
import time

import rclpy
from rclpy.context import Context
from rclpy.executors import MultiThreadedExecutor, SingleThreadedExecutor
from rclpy.task import Future

from motion_ctrl.ros import ros_env
from motion_ctrl.ros.processes import child_preexec, source_env
from motion_ctrl.ros.servo_bus import commander, relay
from motion_ctrl.ros.servo_bus.bridge import POLL, Bridge

ENV = 'MOTION_CTRL_SERVO_DOMAIN'
INSIDE = 'MOTION_CTRL_SERVO_PROCESS'     # set in the node's own process on the bus
STOP_WAIT = 10.0                         # s the node gets to command 0 V and leave
STOP_WAIT_BRIDGE = 3.0                   # s the bridge gets to close after its node has gone


def servo_domain(environ=os.environ) -> int | None:
    """The servo bus's domain for this environment, or None for no bus (`off`). Raises
    ValueError with the reason on a value that is not a domain."""
    value = environ.get(ENV, '').strip().lower()
    if value == 'off':
        return None
    user = int(environ.get('ROS_DOMAIN_ID') or 0)
    if value in ('', 'auto'):
        return (user + 50) % 101 + 1
    if not value.isdigit() or not 0 <= int(value) <= 232:
        raise ValueError(f'{ENV}={value!r}: a ROS domain id (0..232), auto or off')
    if int(value) == user:
        raise ValueError(f'{ENV}={value}: the servo bus needs a domain of its own, not '
                         f'ROS_DOMAIN_ID {user}')
    return int(value)


def servo_process_env(domain: int) -> dict:
    return source_env() | {'ROS_DOMAIN_ID': str(domain), INSIDE: '1'}


_REMAP = re.compile(r'^(?:[^:=]+:)?__(node|name|ns):=(.+)$')


def node_name(default: str, argv: list[str]) -> tuple[str, str]:
    """The node's name and namespace as the remappings in `argv` make them (`-r __node:=`,
    `-r __ns:=`, as a launch file's name= and namespace= pass them); the node itself judges
    its arguments and says what is wrong with them."""
    name, namespace = default, '/'
    for flag, rule in zip(argv, argv[1:]):
        m = _REMAP.match(rule) if flag in ('-r', '--remap') else None
        if m and m.group(1) == 'ns':
            namespace = '/' + m.group(2).strip('/')
        elif m:
            name = m.group(2)
    return name, namespace


def supervise(module: str, name: str, argv: list[str]) -> int | None:
    """In the process the user started: run node `module` (python -m; default node name
    `name`) on the servo bus and bridge it here until SIGINT/SIGTERM or until the node ends;
    returns its exit code. None when there is no servo bus or this is the node's process."""
    if os.environ.get(INSIDE):
        return None
    try:
        domain = servo_domain()
    except ValueError as e:
        print(f'{module}: {e}', file=sys.stderr)
        return 2
    if domain is None:
        return None
    user_env = dict(os.environ)
    transport, local = _bus_environment()
    stop: list[int] = []
    started: list[subprocess.Popen] = []
    # The node is told SIGTERM: it stops as on SIGINT once it runs, and while it still imports
    # it ends without a word (SIGINT there is a KeyboardInterrupt traceback).

    def on_signal(sig, _frame):
        stop.append(sig)
        for child in started:        # at once: a Ctrl-C mid-move commands 0 V now
            child.send_signal(signal.SIGTERM)
    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, on_signal)
    names = node_name(name, argv)
    bus = _Bus.open(domain, *names, public_domain=local)
    if not transport:
        bus.bridge.log('the servo bus runs on your Fast DDS profile file, not on servo_bus.xml: '
                       'a node killed on the bus can hold up the other for a second, and other '
                       'hosts may reach the bus')
    relayed = relay.start(*names, local, user_env) if local is not None else None
    if relayed is not None:
        started.append(relayed)
    # The bridge's participant is on the bus before the node starts: a participant joining
    # later would disturb a running loop (why the bus exists).
    node = subprocess.Popen([sys.executable, '-m', module, *argv[1:]],
                            env=servo_process_env(domain), preexec_fn=child_preexec)
    started.append(node)
    if stop:
        for child in started:
            child.send_signal(signal.SIGTERM)
    try:
        bus.run(node, stop)
    finally:
        # the node first, which commands 0 V and disables with the bridge still up (on a
        # signal, on_signal has told it: once), then the relay
        _stop(node, STOP_WAIT, tell=not stop)
        if relayed is not None:
            _stop(relayed, STOP_WAIT_BRIDGE, tell=True)
        rc = node.returncode if node.returncode >= 0 else 128 - node.returncode
        # (its node gone, the bridge leaves with its code even if ROS's teardown hangs:
        # doc/design_notes.md, "The servo bus as the default")
        ros_env.leave_if_stuck(name, STOP_WAIT_BRIDGE, rc, 'closing the bridge')
        bus.close()
    return rc


def _bus_environment() -> tuple[dict, int | None]:
    """Put the servo bus's environment into this process's, for the bridge and (inherited)
    the node: every participant talks loopback UDP only, its sockets bound to 127.0.0.1, so a
    process killed on the bus leaves no shared-memory port for the other to wait on and no
    other host reaches the bus (servo_bus.xml; before the bridge's first node makes its
    participant). Returns that environment ({} under a profile file of the user's) and the
    local domain when the user's reaches other hosts: the bridge's side goes there, and a
    relay with the user's environment mirrors it onto theirs (servo_bus.relay); else None."""
    transport = ros_env.servo_bus()
    local = relay.local_domain() if transport and relay.reaches_other_hosts() else None
    os.environ.update(transport)
    if local is not None:
        for k in relay.PEER_VARS:
            os.environ.pop(k, None)
    return transport, local


def _stop(child: subprocess.Popen, wait: float, tell: bool) -> None:
    """SIGTERM to `child` (if `tell` and it runs), then wait `wait` s for it, then SIGKILL."""
    if child.poll() is None and tell:
        child.send_signal(signal.SIGTERM)
    try:
        child.wait(wait)
    except subprocess.TimeoutExpired:
        child.kill()
        child.wait()


class _Bus:
    """The bridge and its executors, spinning on threads of their own."""

    @classmethod
    def open(cls, domain: int, name: str, namespace: str, *, public_domain: int | None = None,
             servo_env: dict | None = None, relay: bool = False) -> _Bus:
        """The bridge of node `name` from `domain` onto `public_domain` (default: ROS_DOMAIN_ID);
        `servo_env`: the environment the `domain` side is made in; `relay`: a relay's
        (servo_bus.relay)."""
        public_ctx, servo_ctx = Context(), Context()
        with ros_env.environ(servo_env or {}):
            rclpy.init(args=[], context=servo_ctx, domain_id=domain)
        rclpy.init(args=[], context=public_ctx, domain_id=public_domain)
        bridge = Bridge(name, namespace, public_ctx, servo_ctx, log=lambda m: print(
            f'[{name}] {m}', file=sys.stderr, flush=True), servo_env=servo_env,
            peer=None if relay else commander.named_peer(), relay=relay)
        return cls(bridge, public_ctx, servo_ctx)

    def __init__(self, bridge: Bridge, public_ctx, servo_ctx):
        self.contexts = (public_ctx, servo_ctx)
        self.bridge = bridge
        # The servo side copies every watched stream sample: the lighter executor (ros_env).
        # The servo streams read on the user's side are told apart by their publisher
        # (commander), which rclpy's EventsExecutor does not pass: a SingleThreaded one.
        self.executors = [ros_env.executor(servo_ctx), SingleThreadedExecutor(context=servo_ctx),
                          MultiThreadedExecutor(num_threads=4, context=public_ctx),
                          SingleThreadedExecutor(context=public_ctx),
                          ros_env.executor(servo_ctx)]
        # The bridge looks at the graph on the servo side's thread: rclpy entities are made and
        # destroyed safely only on the thread of the executor that waits on them.
        self.bridge.servo.create_timer(POLL, self.bridge.poll)
        for executor, node in zip(self.executors, (
                self.bridge.servo, self.bridge.calls, self.bridge.public, self.bridge.servo_in,
                self.bridge.servo_out)):
            executor.add_node(node)
        self.running = True
        self.closing: Future = Future()
        self.threads = [threading.Thread(target=self._spin, args=(e,), daemon=True)
                        for e in self.executors]
        for t in self.threads:
            t.start()

    def run(self, node: subprocess.Popen, stop: list) -> None:
        while not stop and node.poll() is None:
            time.sleep(0.1)

    @staticmethod
    def _waits_for_work(executor) -> bool:
        """rclpy's own executors build their wait set anew, in Python, over every entity of
        their nodes each time they wake (~40 ms for 256 axes' services here): they wait for
        work only, and close() wakes them."""
        return isinstance(executor, (SingleThreadedExecutor, MultiThreadedExecutor))

    def _spin(self, executor) -> None:
        if self._waits_for_work(executor):
            executor.spin_until_future_complete(self.closing)
            return
        # (spin_once: EventsExecutor.spin() busy-waits in rclpy 9.1, ros_env says so)
        while self.running:
            executor.spin_once(timeout_sec=0.05)

    def close(self) -> None:
        self.running = False         # the threads leave their executors before these go
        self.closing.set_result(True)
        for e in self.executors:
            if self._waits_for_work(e):
                e.wake()
        for t in self.threads:
            t.join(2.0)
        for e in self.executors:
            e.shutdown(timeout_sec=1.0)
        self.bridge.destroy()
        for ctx in self.contexts:
            rclpy.try_shutdown(context=ctx)

