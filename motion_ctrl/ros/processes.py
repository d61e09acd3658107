"""Start the nodes as separate processes and stop them cleanly (demo, tests, benchmark).

Nodes run as `python -m motion_ctrl.<node>` with the interpreter running this code, so the same
source tree or install is used; SIGINT stops them (they shut down after the current callback).
"""
from __future__ import annotations

import ctypes
import os
import pathlib
import signal
import subprocess
import sys
import time
from typing import Any

from ament_index_python.packages import get_package_share_directory

from motion_ctrl.core.registers import shipped_tuning

ROOT = pathlib.Path(__file__).resolve().parents[2]     # the source tree, or site-packages
REPO_PARAMS = ROOT / 'params'


def params_dir() -> pathlib.Path:
    """params/ of the source tree, else the installed share/motion_ctrl/params."""
    if REPO_PARAMS.is_dir():
        return REPO_PARAMS
    return pathlib.Path(get_package_share_directory('motion_ctrl')) / 'params'


def source_env(env: dict | None = None) -> dict:
    """`env` (default: this process's environment) with the code this process runs, a source
    tree or an install, first on PYTHONPATH: a node started from it runs the same code."""
    env = dict(os.environ if env is None else env)
    env['PYTHONPATH'] = os.pathsep.join(p for p in (str(ROOT), env.get('PYTHONPATH')) if p)
    return env


def child_preexec():
    """preexec_fn of a node process: SIGINT at its default, SIGTERM when its parent dies."""
    # A process started in the background of a non-interactive shell inherits SIGINT ignored.
    signal.signal(signal.SIGINT, signal.SIG_DFL)
    # A node must not outlive a starting process that dies without stop() (a killed or
    # timed-out test run, a crashed demo): an orphan loads the machine and publishes on the
    # domain for ever. Linux: the kernel sends the node SIGTERM (a clean stop) when its parent
    # dies. (The signal follows the thread that started the node: start nodes from a thread
    # that outlives them, as the demo and tests do.)
    if sys.platform.startswith('linux'):
        try:
            ctypes.CDLL(None, use_errno=True).prctl(1, signal.SIGTERM)   # PR_SET_PDEATHSIG
        except (OSError, AttributeError):
            pass


class NodeProcess:
    """A node run as `python -m motion_ctrl.ros.<module> --ros-args ...`."""

    def __init__(self, module: str, params_file=None, params: dict | None = None,
                 log_path=None, env=None):
        """`params_file`: a file, a list of them (applied in order) or None."""
        args = [sys.executable, '-m', f'motion_ctrl.ros.{module}', '--ros-args']
        files = params_file if isinstance(params_file, (list, tuple)) else [params_file]
        for f in files:
            if f:
                args += ['--params-file', str(f)]
        for k, v in (params or {}).items():
            args += ['-p', f'{k}:={v}']
        self.args = args
        self.log_path = log_path
        self.log = open(log_path, 'w') if log_path else subprocess.DEVNULL
        self.proc = subprocess.Popen(args, stdout=self.log, stderr=subprocess.STDOUT,
                                     env=source_env(env), preexec_fn=child_preexec)

    def servo_pid(self) -> int:
        """The pid of the node itself: its process on the servo bus (ros.servo_bus), a child
        of this one; this one's pid when there is no bus."""
        try:
            with open(f'/proc/{self.proc.pid}/task/{self.proc.pid}/children') as f:
                children = [int(c) for c in f.read().split()]
        except OSError:
            children = []
        return children[0] if children else self.proc.pid

    def stop(self, timeout: float = 5.0) -> int:
        """SIGINT, wait; SIGABRT (a stack dump in the log), then SIGKILL, only if it does not
        stop. Returns the exit code."""
        if self.proc.poll() is None:
            self.proc.send_signal(signal.SIGINT)
            try:
                self.proc.wait(timeout)
            except subprocess.TimeoutExpired:
                # SIGABRT first: faulthandler (the EventsExecutor enables it) writes where
                # every thread of the hung node is to its log; then SIGKILL.
                self.proc.send_signal(signal.SIGABRT)
                try:
                    self.proc.wait(2.0)
                except subprocess.TimeoutExpired:
                    self.proc.kill()
                    self.proc.wait()
        if not isinstance(self.log, int):        # (subprocess.DEVNULL)
            self.log.close()
        return self.proc.returncode


def first_fault(nodes) -> str:
    """The first line the nodes logged that says an axis faulted (a loop opened, an amplifier
    tripped), from their log files; '' when none did or they log nowhere."""
    for n in nodes:
        if n.log_path is None:
            continue
        with open(n.log_path, errors='replace') as f:
            for line in f:
                if ('[ERROR]' in line or '[WARN]' in line) and 'fault' in line.lower():
                    return line.strip()
    return ''


def log_file(log_dir, node: str) -> pathlib.Path | None:
    """Where node `node` (plant, controller) of a run logs: `log_dir`/<node>.log, or nowhere."""
    return pathlib.Path(log_dir) / f'{node}.log' if log_dir else None


def start_slide(controller_params: dict | None = None, plant_params: dict | None = None,
                log_dir=None, params_files: bool = True, env: dict | None = None,
                plant_env: dict | None = None):
    """Plant and controller with the default params files (which set the registers of axis x;
    the other axes named in `controller_params`' `axes` get x's shipped tuning, doc/gains.md;
    params_files=False: the register table's defaults, for any axis names) plus overrides, in
    `env` (default: this process's environment), the plant with `plant_env` added (e.g.
    MOTION_CTRL_SERVO_DOMAIN=off: off the servo bus, as a plant of another make); returns
    both."""
    d = params_dir()
    file = (lambda n: d / f'{n}.yaml') if params_files else (lambda n: None)
    if params_files:
        controller_params = _other_axes_tuned(controller_params)
    plant = NodeProcess('plant_node', file('plant'), plant_params, log_file(log_dir, 'plant'),
                        env=dict(os.environ if env is None else env) | (plant_env or {}))
    controller = NodeProcess('controller_node', file('controller'), controller_params,
                             log_file(log_dir, 'controller'), env=env)
    return plant, controller


def axis_names(value) -> list[str]:
    """The names of an `axes` parameter given as a list or as its text (`['x', 'y']`, `x,y`)."""
    if isinstance(value, (list, tuple)):
        return [str(v) for v in value]
    return [n.strip().strip('\'"') for n in str(value).strip().strip('[]').split(',')
            if n.strip()]


def _other_axes_tuned(controller_params: dict | None) -> dict | None:
    """The overrides, under them the shipped slide's tuning for the axes they name that the
    shipped params file does not (it tunes x): every default slide tuned alike."""
    if not controller_params or 'axes' not in controller_params:
        return controller_params
    others = [a for a in axis_names(controller_params['axes']) if a != 'x']
    return shipped_tuning(others) | controller_params


# The plant node's own parameters that mean nothing to a controller running the slide itself.
PLANT_NODE_ONLY = ('axes', 'publish_rate', 'lockstep', 'realtime_priority')


def start_sim(controller_params: dict | None = None, plant_params: dict | None = None,
              log_dir=None, params_files: bool = True, env: dict | None = None):
    """The controller alone, with the slide simulated inside its loop (`hardware: sim`): the
    default params files of both nodes (the plant's `plant:` section configures its slides;
    other axes tuned as start_slide's; params_files=False: the register table's defaults) plus
    overrides, the plant's as the controller's own parameters (start_slide's plant parameters,
    those of the plant node alone dropped). Returns (controller,), the processes to stop."""
    d = params_dir()
    files = [d / 'controller.yaml', d / 'plant.yaml'] if params_files else None
    if params_files:
        controller_params = _other_axes_tuned(controller_params)
    plant = {k: v for k, v in (plant_params or {}).items() if k not in PLANT_NODE_ONLY}
    controller = NodeProcess('controller_node', files,
                             (controller_params or {}) | plant | {'hardware': 'sim'},
                             log_file(log_dir, 'controller'), env=env)
    return (controller,)


# `hardware: canopen` between processes: python-can's udp_multicast bus, in a network namespace
# of its own (PRIVATE_NET) so that no frame leaves the machine.
CAN_BUS: dict[str, Any] = {'can_interface': 'udp_multicast', 'can_channel': '239.74.163.2',
           'can_bitrate': 1_000_000}
PRIVATE_NET = 'MOTION_CTRL_PRIVATE_NET'     # set (to 1) inside private_network's namespace


def private_network(argv: list[str]) -> list[str]:
    """`argv` as a command that runs in a new network namespace, made for it and gone with it
    (unshare: as root, or an unprivileged user with user namespaces): only its loopback, up,
    with a route for multicast on it, so udp_multicast's datagrams stay inside. `PRIVATE_NET`
    is set there."""
    unshare = ['unshare', '--net'] + ([] if os.geteuid() == 0 else ['--map-root-user'])
    setup = ('ip link set lo up && ip route add 224.0.0.0/4 dev lo && '
             f'{PRIVATE_NET}=1 exec "$@"')
    return unshare + ['sh', '-c', setup, 'sh'] + list(argv)


def interfaces() -> list[str]:
    """The network interfaces of this process's namespace, sorted (/proc/self/net/dev)."""
    with open('/proc/self/net/dev') as f:
        return sorted(line.split(':')[0].strip() for line in f.read().splitlines()[2:])


def only_loopback() -> bool:
    """Whether this process's network namespace has no interface but `lo` (what
    `private_network` makes): a datagram sent here cannot leave the machine."""
    return interfaces() == ['lo']


DRIVE_BOOT = 60.0        # s the emulated drives may take to be heard on the bus


def heard(bus: dict, first: int, last: int, timeout: float) -> bool:
    """Whether a frame with a CAN-ID in [first, last] (heartbeats: 701h-77Fh) comes on the bus
    `bus` (CAN_BUS's keys) within `timeout` s."""
    # python-can is imported here, not at the top: about 0.1 s (python -X importtime; 0.2-0.3 s
    # on the loaded 2-core VM) that every importer of this module would pay, each node's
    # processes (through servo_bus) and the launch file among them.
    import can
    with can.Bus(interface=bus['can_interface'], channel=bus['can_channel']) as listener:
        end = time.monotonic() + timeout
        while (left := end - time.monotonic()) > 0:
            msg = listener.recv(min(left, 0.5))
            if msg is not None and first <= msg.arbitration_id <= last:
                return True
    return False


def start_canopen(controller_params: dict | None = None, drive_params: dict | None = None,
                  log_dir=None, env: dict | None = None, bus: dict | None = None,
                  params_files: bool = True):
    """The emulated drives (`virtual_drive`) and a controller with `hardware: canopen` on one
    CAN bus (default CAN_BUS: udp_multicast, refused outside a namespace with only a loopback:
    run inside `private_network`), the default
    params files of both (which set axis x; params_files=False: the register table's defaults,
    for any axis names) plus overrides; returns (virtual_drive, controller). The controller
    starts once the drives' heartbeat is on the bus (a loaded machine can take longer than the
    master's 5 s for a node to boot to start a ROS node)."""
    can = CAN_BUS | (bus or {})
    if can['can_interface'] == 'udp_multicast' and not only_loopback():
        raise RuntimeError('start_canopen: a udp_multicast CAN bus here would send on this '
                           "machine's own interfaces: run inside processes.private_network")
    d = params_dir()
    file = (lambda n: d / f'{n}.yaml') if params_files else (lambda n: None)
    drive = NodeProcess('virtual_drive_node', file('virtual_drive'),
                        can | (drive_params or {}), log_file(log_dir, 'virtual_drive'), env=env)
    heard(can, 0x701, 0x77F, DRIVE_BOOT)
    controller = NodeProcess('controller_node', file('controller'),
                             {'hardware': 'canopen'} | can | (controller_params or {}),
                             log_file(log_dir, 'controller'), env=env)
    return drive, controller
