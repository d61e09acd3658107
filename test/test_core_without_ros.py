"""The servo core imports and runs on a machine without ROS (issue 13): in a fresh interpreter
where every ROS package refuses to import, the core modules import and the harness lands a
1-inch move. Fails if a core module (or what it imports) pulls in rclpy or a message package.

Every module of the package is either core or shell (below); a new module fails
test_every_module_is_core_or_shell until it is put in one of the two lists, so a new core
module cannot slip past the import check."""
import os
import subprocess
import sys
import textwrap

from conftest import REPO_ROOT

# Plain Python (numpy, scipy, ruckig): the servo laws, compensation, profile, settling, the
# tick, the plant physics, and what is built on them in process (harness, tuning, scenarios,
# identification).
CORE = ['axis', 'backlash', 'deadband', 'diagnostics', 'dual_loop', 'excitation',
        'feedback_sync', 'gather', 'harness', 'identify', 'iso230', 'notch', 'plant', 'profile',
        'registers', 'scenarios', 'servo_law', 'servo_loop', 'settling', 'trajectory', 'tuning']
# The ROS shell and the tools around it: nodes, parameters, clients, processes, recording.
# These may import ROS (some do only inside functions).
SHELL = ['bag_repair', 'benchmark', 'calibrate', 'client', 'controller_node', 'demo', 'draw',
         'lockstep',
         'plant_node', 'processes', 'record', 'report', 'ros_env', 'ros_params', 'soak',
         'visitor']
ROS = ['rclpy', 'rcl_interfaces', 'sensor_msgs', 'std_msgs', 'std_srvs', 'diagnostic_msgs',
       'trajectory_msgs',
       'rosgraph_msgs', 'builtin_interfaces', 'ament_index_python', 'rosbags', 'mcap']

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
    from motion_ctrl.harness import Harness
    h = Harness()
    assert h.move(0.0254) is not None, 'no MOTION_DONE'
    err = h.load_error_counts(0.0254)
    assert abs(err) < 3.0, err
    assert not any(name.split('.')[0] in ROS for name in sys.modules)
''') % (ROS, CORE)


def test_every_module_is_core_or_shell():
    package = os.path.join(REPO_ROOT, 'motion_ctrl')
    modules = {f[:-3] for f in os.listdir(package) if f.endswith('.py') and f != '__init__.py'}
    core, shell = set(CORE), set(SHELL)
    assert not core & shell, f'both core and shell: {sorted(core & shell)}'
    assert modules == core | shell, (
        f'not classified: {sorted(modules - core - shell)}, '
        f'gone: {sorted((core | shell) - modules)}')


def test_core_imports_and_moves_without_ros():
    r = subprocess.run([sys.executable, '-c', PROGRAM], cwd=REPO_ROOT, capture_output=True,
                       text=True, timeout=120)
    assert r.returncode == 0, r.stdout[-3000:] + r.stderr[-3000:]
