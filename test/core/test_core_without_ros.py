"""The servo core imports and runs on a machine without ROS (issue 13): in a fresh interpreter
where every ROS package refuses to import, the core modules import and the harness lands a
1-inch move. Fails if a core module (or what it imports) pulls in rclpy or a message package.
The core tests (conftest.CORE_FOLDERS, `scripts/test -m core`) import there too.

Every module of the package lives in a layer (core, sim, analysis, canopen, plotting: ROS-free;
ros, bags, procedures, tools: the shell); every module of the ROS-free layers is imported by the
check, so a new one cannot slip past it."""
import os
import subprocess
import sys
import textwrap

import pytest

from conftest import REPO_ROOT, ROS_PACKAGES, core_files, core_only

# The layout is the architecture: these subpackages are plain Python (numpy, scipy, ruckig,
# matplotlib, canopen) and must import without ROS: the servo core, the simulated machine, the
# measurement maths, the fieldbus and the figures. The ROS shell (ros/), the recordings (bags/),
# what the tools do over ROS (procedures/) and the programs (tools/) may import ROS.
ROS_FREE = ['core', 'sim', 'analysis', 'canopen', 'plotting']
SHELL = ['ros', 'bags', 'procedures', 'tools']
PACKAGE = os.path.join(REPO_ROOT, 'motion_ctrl')


def modules(sub):
    return sorted(f'{sub}.{f[:-3]}' for f in os.listdir(os.path.join(PACKAGE, sub))
                  if f.endswith('.py') and f != '__init__.py')


CORE = [m for sub in ROS_FREE for m in modules(sub)]
TEST_DIR = os.path.join(REPO_ROOT, 'test')

PROGRAM = textwrap.dedent('''
    import importlib, sys
    ROS = set(%r)

    class NoRos:
        def find_spec(self, name, path=None, target=None):
            if name.split('.')[0] in ROS:
                raise ImportError(f'{name}: no ROS on this machine')
            return None

    sys.meta_path.insert(0, NoRos())
    try:
        import rclpy
    except ImportError:
        pass
    else:
        raise SystemExit('the ROS block does not work: rclpy imported')
    for m in %r:
        importlib.import_module('motion_ctrl.' + m)
    import msg_defs, msg_defs.status, msg_defs.topics
    assert msg_defs.Status is msg_defs.status.Status and msg_defs.COMMAND == 'command'
    try:
        msg_defs.SERVO_QOS                 # the ROS half: loaded on use, and it needs rclpy
    except ImportError:
        pass
    else:
        raise SystemExit('msg_defs.SERVO_QOS without rclpy')
    from motion_ctrl.sim.harness import Harness
    h = Harness()
    assert h.move(0.0254) is not None, 'no MOTION_DONE'
    err = h.load_error_counts(0.0254)
    assert abs(err) < 3.0, err
    sys.path.insert(0, %r)                 # conftest, kit
    for folder, t in %r:                   # the core tests' own imports
        sys.path[:0] = [folder]
        importlib.import_module(t)
    assert not any(name.split('.')[0] in ROS for name in sys.modules)
''') % (ROS_PACKAGES, CORE, TEST_DIR, [(str(f.parent), f.stem) for f in core_files()])


def test_every_module_is_in_a_layer():
    loose = [f for f in os.listdir(PACKAGE) if f.endswith('.py') and f != '__init__.py']
    assert not loose, f'modules outside the layers: {loose}'
    layers = sorted(d for d in os.listdir(PACKAGE) if os.path.isfile(
        os.path.join(PACKAGE, d, '__init__.py')))
    assert layers == sorted(ROS_FREE + SHELL), layers
    assert {'core.servo_loop', 'core.axis', 'sim.plant', 'sim.harness'} <= set(CORE)


@pytest.mark.fresh_interpreter
def test_core_imports_and_moves_without_ros(request):
    if core_only(request.config) and not any(m.split('.')[0] in ROS_PACKAGES
                                             for m in sys.modules):
        # `scripts/test -m core`: ROS packages have refused to import since the run began
        # (conftest) and none is loaded, so this process is such an interpreter: the same
        # program here, without starting another (1-2 s of imports).
        meta_path = list(sys.meta_path)
        try:
            exec(PROGRAM, {'__name__': 'core_without_ros'})
        except SystemExit as e:
            pytest.fail(str(e))
        finally:
            sys.meta_path[:] = meta_path
        return
    r = subprocess.run([sys.executable, '-c', PROGRAM], cwd=REPO_ROOT, capture_output=True,
                       text=True, timeout=120)
    assert r.returncode == 0, r.stdout[-3000:] + r.stderr[-3000:]
