"""Node processes start and stop as a user expects: SIGTERM (and SIGINT, see test_ros_topics.py)
ends them cleanly, and a bad parameter file ends the node at once with one readable line.
"""
from __future__ import annotations

import os
import signal
import subprocess
import sys
import time

import pytest

pytest.importorskip('rclpy')

from motion_ctrl.ros.client import SlideClient  # noqa: E402
from motion_ctrl.ros.processes import params_dir, start_slide  # noqa: E402

try:                            # the project venv has pytest-timeout: a hung wait fails, not hangs
    import pytest_timeout  # noqa: F401
    pytestmark = pytest.mark.timeout(60)
except ImportError:
    pass


def _clean(text: str) -> bool:
    """No traceback, no error, and not nanobind's list of ruckig objects "leaked" (the node
    alive at the interpreter's exit: held by its worker threads and by gc.freeze)."""
    return 'Traceback' not in text and 'Error' not in text and 'leaked' not in text


def test_nodes_stop_cleanly_on_sigterm(rclpy_session, tmp_path):
    """SIGTERM (what systemd, docker stop and launch send) ends both nodes with exit code 0 and
    no traceback, like SIGINT."""
    plant, controller = start_slide(log_dir=tmp_path)
    client = SlideClient(name='lifecycle_probe')
    try:
        assert client.wait_ready(30.0), f'nodes did not come up: {client.not_ready()}'
    finally:
        client.destroy_node()
        for node in (plant, controller):
            if node.proc.poll() is None:
                node.proc.send_signal(signal.SIGTERM)
        codes = {}
        for name, node in (('plant', plant), ('controller', controller)):
            try:
                codes[name] = node.proc.wait(5.0)
            except subprocess.TimeoutExpired:
                codes[name] = 'hung'
            node.stop()                      # SIGKILL if hung; closes the log
    assert codes == {'plant': 0, 'controller': 0}, (
        codes, {n: (tmp_path / f'{n}.log').read_text()[-3000:] for n, c in codes.items() if c})
    for log in ('plant.log', 'controller.log'):
        text = (tmp_path / log).read_text()
        assert _clean(text), text[-3000:]


STUCK_TEARDOWN = """
import rclpy, sys, time
from rclpy.node import Node
from rclpy.signals import SignalHandlerOptions
from motion_ctrl.ros.node_runner import spin
class Stuck(Node):
    def destroy_node(self):          # a teardown that never ends
        time.sleep(60)
rclpy.init(signal_handler_options=SignalHandlerOptions.NO)
node = Stuck('stuck')
node.create_timer(0.1, lambda: print('up', flush=True))
spin(node)
"""


def _sigterm_when_up(script: str, env: dict, wait: float) -> tuple[int, float, str]:
    """Run `script` (it prints 'up' when its node spins), SIGTERM it then, and wait up to `wait`
    s for it to end: (exit code, seconds from the signal, stderr)."""
    proc = subprocess.Popen([sys.executable, '-c', script], stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True, env=env)
    assert proc.stdout is not None and proc.stderr is not None
    try:
        assert proc.stdout.readline().strip() == 'up'
        t0 = time.monotonic()
        proc.send_signal(signal.SIGTERM)
        code = proc.wait(wait)
        return code, time.monotonic() - t0, proc.stderr.read()
    finally:
        if proc.poll() is None:
            proc.kill()


def test_stop_does_not_wait_for_a_stuck_teardown(node_env):
    """A node whose ROS teardown hangs still leaves STOP_DEADLINE after SIGTERM, exit code 0,
    saying why and where it was stuck (once in CI a plant was still there 5 s after it)."""
    from motion_ctrl.ros.node_runner import STOP_DEADLINE
    code, elapsed, err = _sigterm_when_up(STUCK_TEARDOWN, node_env, STOP_DEADLINE + 5.0)
    assert code == 0, err
    assert STOP_DEADLINE - 0.1 < elapsed < STOP_DEADLINE + 2.0, elapsed
    assert 'stuck: stop took over' in err and 'destroy_node' in err, err


STUCK_LOOP = """
import ctypes, rclpy
from rclpy.signals import SignalHandlerOptions
from motion_ctrl.ros.node_runner import spin
rclpy.init(signal_handler_options=SignalHandlerOptions.NO)
node = rclpy.create_node('wedged')
libc = ctypes.PyDLL(None)                  # (PyDLL: its calls keep the GIL)
mutex = ctypes.create_string_buffer(64)    # a pthread mutex, taken once already
libc.pthread_mutex_lock(mutex)
def wedge():
    print('up', flush=True)
    libc.pthread_mutex_lock(mutex)   # waits for good, keeping the GIL, as a stuck publish() did
node.create_timer(0.5, wedge)
spin(node)
"""


def test_a_wedged_loop_ends_its_process(node_env):
    """The process watchdog: a spin loop that stands still WATCHDOG s (here in a C call holding
    the GIL, where neither a signal handler nor the stop deadline can run) ends the process,
    exit code 1, with every thread's stack on stderr; a SIGTERM meanwhile changes nothing."""
    from motion_ctrl.ros.node_runner import WATCHDOG
    code, elapsed, err = _sigterm_when_up(STUCK_LOOP, node_env, WATCHDOG + 10.0)
    assert code == 1, err
    assert elapsed < WATCHDOG + 1.0, elapsed
    assert 'Timeout' in err and 'wedge' in err, err


FROZEN = """
import gc, os, signal
import rclpy
from rclpy.signals import SignalHandlerOptions
from motion_ctrl.ros.node_runner import spin
rclpy.init(signal_handler_options=SignalHandlerOptions.NO)
node = rclpy.create_node('frozen')
def first_tick():
    print(gc.get_freeze_count(), flush=True)
    os.kill(os.getpid(), signal.SIGTERM)
node.create_timer(0.05, first_tick)
spin(node)
"""


def test_spin_freezes_what_start_up_made(node_env):
    """Before the loop runs, the objects of start-up (imports, the node) are frozen out of the
    cyclic collector: its full passes held the servo thread ~20 ms (doc/design_notes.md)."""
    r = subprocess.run([sys.executable, '-c', FROZEN], capture_output=True, text=True,
                       timeout=60, env=node_env)
    assert r.returncode == 0, r.stderr
    assert int(r.stdout.split()[0]) > 10000, r.stdout


FIRST_USE = """
import sys
import rclpy
from motion_ctrl.core import excitation
from motion_ctrl.ros.controller_node import ControllerNode
rclpy.init()
node = ControllerNode()
before = set(sys.modules)
job = node.loop.prepare({'names': ['x'], 'times': [1.0, 2.0], 'positions': [[0.005], [0.01]],
                         'velocities': [[], []], 'accelerations': [[], []]})
assert not isinstance(job, str), job
for kind in excitation.SIGNALS:
    excitation.from_registers(node.loop.values['x'] | {'excitation_signal': kind,
                                                       'excitation_duration': 20.0}, 1000.0)
print(sorted(set(sys.modules) - before), flush=True)
"""


def test_a_controller_imports_what_a_trajectory_needs_before_its_loop_runs(node_env):
    """A made controller builds its first trajectory and every excitation signal without an
    import: imported by the first trajectory, on the trajectories thread, scipy held the GIL
    ~0.4 s in long C calls and both loops stood still 50-105 ms (the plant "held up" in 15 of 16
    `draw` starts at real-time priority)."""
    r = subprocess.run([sys.executable, '-c', FIRST_USE], capture_output=True, text=True,
                       timeout=60, env=node_env)
    assert r.returncode == 0, r.stderr
    assert r.stdout.strip() == '[]', r.stdout[:400]


EARLY_SIGNAL = """
import os, signal
import rclpy
from rclpy.signals import SignalHandlerOptions
from motion_ctrl.ros.node_runner import spin, stop_on_signals
stop_on_signals('early')               # as run() does before it makes the node
os.kill(os.getpid(), signal.SIGINT)    # Ctrl-C while the node is still being made
rclpy.init(signal_handler_options=SignalHandlerOptions.NO)
node = rclpy.create_node('early')
node.create_timer(0.01, lambda: print('ticked', flush=True))
spin(node)
print('left', flush=True)
"""


def test_a_signal_while_the_node_is_made_stops_it_cleanly(node_env):
    """SIGINT before the node spins (a Ctrl-C or a bridge's stop during start-up): the node is
    made, spins not once, leaves with exit code 0 and no traceback (was KeyboardInterrupt)."""
    r = subprocess.run([sys.executable, '-c', EARLY_SIGNAL], capture_output=True, text=True,
                       timeout=60, env=node_env)
    assert (r.returncode, r.stdout.split()) == (0, ['left']), r.stdout + r.stderr
    assert 'Traceback' not in r.stderr, r.stderr


NESTED_SIGNALS = """
import os, signal, sys, threading
from motion_ctrl.ros.node_runner import stop_on_signals
stop_on_signals('nested')
handler = signal.getsignal(signal.SIGTERM)
raised = [0]
def profiler(frame, event, arg):     # another SIGTERM as each of the handler's first 200 calls
    if event in ('return', 'c_return') and raised[0] < 200:    # returns (a lock taken, say)
        raised[0] += 1
        signal.raise_signal(signal.SIGTERM)
sys.setprofile(profiler)
handler(signal.SIGTERM, None)
sys.setprofile(None)
print(raised[0], sum(t.name.endswith('(leave)') for t in threading.enumerate()), flush=True)
os._exit(0)
"""


def test_signals_inside_the_signal_handler_stop_the_node_once(node_env):
    """A burst of signals runs the stop handler inside itself: it must take no lock (a
    controller deadlocked in threading.Event.set so, its stop left to the process watchdog) and
    start one stop deadline. Here a signal is raised as each call in the handler returns."""
    r = subprocess.run([sys.executable, '-c', NESTED_SIGNALS], capture_output=True, text=True,
                       timeout=20, env=node_env)
    assert r.returncode == 0, r.stderr
    raised, deadlines = map(int, r.stdout.split())
    assert raised > 1 and deadlines == 1, r.stdout


BAD_FILES = {
    # id: (node module, node name, YAML lines, parameter the message must name)
    'kp-negative': ('controller_node', 'controller', ['x.kp: -5.0'], 'x.kp'),
    'mode-bogus': ('controller_node', 'controller', ['x.mode: bogus'], 'x.mode'),
    'kp-integer': ('controller_node', 'controller', ['x.kp: 2'], 'x.kp'),
    'kp-nan': ('controller_node', 'controller', ['x.kp: .nan'], 'x.kp'),
    'coarse-below-fine': ('controller_node', 'controller',
                          ['x.coarse_position_tolerance: 1.0e-7'],
                          'x.coarse_position_tolerance'),
    'plant-backlash-negative': ('plant_node', 'plant', ['x.backlash: -1.0e-5'], 'x.backlash'),
    # rclpy would ignore these without a word: a typo, and a register of an axis not configured
    'unknown-register': ('controller_node', 'controller', ['x.kpp: 1.0'], 'x.kpp'),
    'unknown-axis': ('plant_node', 'plant', ['y.backlash: 1.0e-5'], 'y.backlash'),
}


@pytest.fixture(scope='module')
def bad_runs(tmp_path_factory, node_env):
    """Every BAD_FILES case started at once (start-up dominates; in parallel the cases cost
    about one): {case: (exit code, seconds to exit, stdout, stderr, bad file)}."""
    d = tmp_path_factory.mktemp('bad_params')
    procs = {}
    for case, (module, node, lines, _) in BAD_FILES.items():
        bad = d / f'{case}.yaml'
        bad.write_text(f'{node}:\n  ros__parameters:\n'
                       + ''.join(f'    {ln}\n' for ln in lines))
        args = [sys.executable, '-m', f'motion_ctrl.ros.{module}', '--ros-args',
                '--params-file', str(params_dir() / f'{node}.yaml'), '--params-file', str(bad)]
        procs[case] = (subprocess.Popen(args, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                                        text=True, env=node_env), time.monotonic(), bad)
    runs = {}
    for case, (proc, t0, bad) in procs.items():
        try:
            out, err = proc.communicate(timeout=30)
        except subprocess.TimeoutExpired:
            proc.kill()
            out, err = proc.communicate()
        runs[case] = (proc.returncode, time.monotonic() - t0, out, err, bad)
    return runs


@pytest.mark.parametrize('case', list(BAD_FILES))
def test_bad_params_file_exits_with_one_line(bad_runs, case):
    """A params file with a bad value, loaded on top of the defaults (as `ros2 run ...
    --ros-args --params-file` would): the node exits non-zero within seconds, with ONE line on
    stderr naming the parameter and the file, and no traceback."""
    code, elapsed, out, err, bad = bad_runs[case]
    parameter = BAD_FILES[case][3]
    stderr = [ln for ln in err.splitlines() if ln.strip()]
    assert code not in (0, None, -9), (code, err)
    assert elapsed < 20.0       # ~1.5 s alone (mostly imports); 6 at once on a loaded 2-core VM
    assert 'Traceback' not in err + out, err
    assert len(stderr) == 1, (code, err, out)
    assert parameter in stderr[0] and str(bad) in stderr[0], stderr[0]


def test_malformed_params_file_exits_naming_the_file(tmp_path, node_env):
    """A params file that is not valid YAML: rcl refuses it while rclpy starts; the node exits
    2 at once with a line naming the file (after rcl's own log line), no traceback."""
    bad = tmp_path / 'broken.yaml'
    bad.write_text('controller:\n  ros__parameters:\n    x.kp: [16000.0\n')
    r = subprocess.run([sys.executable, '-m', 'motion_ctrl.ros.controller_node', '--ros-args',
                        '--params-file', str(bad)], capture_output=True, text=True, timeout=30,
                       env=node_env)
    assert r.returncode == 2, (r.returncode, r.stderr)
    assert 'Traceback' not in r.stderr + r.stdout, r.stderr
    last = r.stderr.strip().splitlines()[-1]
    assert last.startswith('ControllerNode: bad arguments') and str(bad) in last, r.stderr


@pytest.mark.parametrize('how', ['params-file', '-p'])
def test_unquoted_axis_names_that_are_yaml_booleans_are_refused_with_the_fix(tmp_path,
                                                                            node_env, how):
    """Issue 16: `axes: [x, y]` is a string and a bool to rcl's YAML parser (y, n, on, off are
    booleans); the node exits 2 and says to quote them, as the shipped files do."""
    f = tmp_path / 'two_axes.yaml'
    f.write_text('controller:\n  ros__parameters:\n    axes: [x, y]\n')
    extra = ['--params-file', str(f)] if how == 'params-file' else ['-p', 'axes:=[x,y]']
    r = subprocess.run([sys.executable, '-m', 'motion_ctrl.ros.controller_node', '--ros-args',
                        *extra], capture_output=True, text=True, timeout=30, env=node_env)
    assert r.returncode == 2, (r.returncode, r.stderr)
    last = r.stderr.strip().splitlines()[-1]
    assert 'Traceback' not in r.stderr and 'quote them' in last, r.stderr
    assert "axes: ['x', 'y']" in last and """-p 'axes:=["x", "y"]'""" in last, last


def _alive(pid: int) -> bool:
    try:
        with open(f'/proc/{pid}/stat') as f:
            return f.read().rsplit(')', 1)[1].split()[0] != 'Z'
    except FileNotFoundError:
        return False


@pytest.mark.skipif(not sys.platform.startswith('linux'), reason='PR_SET_PDEATHSIG is Linux')
def test_nodes_do_not_outlive_a_killed_starter(node_env, tmp_path):
    """A test run or demo killed with SIGKILL cannot stop its nodes: they must not run on as
    orphans (loading the machine, publishing on the domain) — NodeProcess has the kernel stop
    them when their starter dies."""
    log = tmp_path / 'plant.log'
    starter = subprocess.Popen(
        [sys.executable, '-c',
         'import sys, time\n'
         'from motion_ctrl.ros.processes import NodeProcess, params_dir\n'
         f"node = NodeProcess('plant_node', params_dir() / 'plant.yaml', log_path={str(log)!r})\n"
         'print(node.proc.pid, flush=True)\n'
         'time.sleep(60)\n'],
        stdout=subprocess.PIPE, text=True, env=node_env)
    try:
        node_pid = int(starter.stdout.readline())
        deadline = time.monotonic() + 20.0   # the node up and spinning (past rclpy's re-exec)
        while 'backlash slide' not in (log.read_text() if log.exists() else '') \
                and time.monotonic() < deadline:
            time.sleep(0.05)
        assert _alive(node_pid)
    finally:
        starter.kill()
        starter.wait()
    deadline = time.monotonic() + 10.0
    while _alive(node_pid) and time.monotonic() < deadline:
        time.sleep(0.05)
    if _alive(node_pid):                     # don't leave it behind either way
        os.kill(node_pid, signal.SIGKILL)
        pytest.fail('the node outlived its killed starter')
    assert 'Traceback' not in log.read_text()


# Start-up that cannot work stops the node with one line saying where the bad input came from
# (issue 12): a file that configures nothing for the node ran it on defaults without a word.
STARTUP_CASES = {
    'file-with-a-wrong-node-key': ('controller_node', 'ctrl:\n  ros__parameters:\n    x.kp: 1.0\n',
                                   [], "configures nothing for node 'controller'"),
    'empty-file': ('plant_node', '', [], 'is empty'),
    'feedback-timeout-0': ('controller_node', None, ['-p', 'feedback_timeout:=0.0'],
                           'from -p feedback_timeout:=0.0'),
    'bad-value-from-p': ('controller_node', None, ['-p', 'x.kp:=-1.0'], 'from -p x.kp:=-1.0'),
    'servo-rate-0': ('controller_node', None, ['-p', 'servo_rate:=0.0'], 'servo_rate'),
}


@pytest.fixture(scope='module')
def startup_runs(tmp_path_factory, node_env):
    d = tmp_path_factory.mktemp('startup')
    procs = {}
    for case, (module, text, extra, _) in STARTUP_CASES.items():
        node = module.split('_')[0]
        f = params_dir() / f'{node}.yaml'
        if text is not None:
            f = d / f'{case}.yaml'
            f.write_text(text)
        args = [sys.executable, '-m', f'motion_ctrl.ros.{module}', '--ros-args',
                '--params-file', str(f)] + extra
        procs[case] = (subprocess.Popen(args, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                                        text=True, env=node_env), f)
    runs = {}
    for case, (proc, f) in procs.items():
        try:
            out, err = proc.communicate(timeout=30)
        except subprocess.TimeoutExpired:
            proc.kill()
            out, err = proc.communicate()
        runs[case] = (proc.returncode, out, err, f)
    return runs


@pytest.mark.parametrize('case', list(STARTUP_CASES))
def test_startup_that_cannot_work_exits_2_with_one_line(startup_runs, case):
    code, out, err, f = startup_runs[case]
    expected = STARTUP_CASES[case][3]
    lines = [ln for ln in err.splitlines() if ln.strip()]
    assert code == 2, (code, err)
    assert 'Traceback' not in err + out and len(lines) == 1, err
    assert expected in lines[0], lines[0]
    if STARTUP_CASES[case][1] is not None:
        assert str(f) in lines[0], lines[0]
    elif case == 'bad-value-from-p':
        assert str(f) not in lines[0], lines[0]          # not blamed on the defaults file
