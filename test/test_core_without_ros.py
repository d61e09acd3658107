"""The servo core imports and runs on a machine without ROS (issue 13): in a fresh interpreter
where every ROS package refuses to import, the core modules import and the harness lands a
1-inch move. Fails if a core module (or what it imports) pulls in rclpy or a message package."""
import subprocess
import sys
import textwrap

from conftest import REPO_ROOT

CORE = ['axis', 'backlash', 'deadband', 'diagnostics', 'dual_loop', 'feedback_sync', 'harness',
        'notch', 'plant', 'profile', 'registers', 'scenarios', 'servo_law', 'settling', 'tuning']
ROS = ['rclpy', 'rcl_interfaces', 'sensor_msgs', 'std_msgs', 'std_srvs', 'diagnostic_msgs',
       'rosgraph_msgs', 'builtin_interfaces', 'rosbags', 'mcap']

PROGRAM = textwrap.dedent('''
    import importlib, sys
    ROS = set(%r)

    class NoRos:
        def find_spec(self, name, path=None, target=None):
            if name.split('.')[0] in ROS:
                raise ImportError(f'{name}: no ROS on this machine')
            return None

    sys.meta_path.insert(0, NoRos())
    for m in %r:
        importlib.import_module('motion_ctrl.' + m)
    import msg_defs.status, msg_defs.topics
    from motion_ctrl.harness import Harness
    h = Harness()
    assert h.move(0.0254) is not None
    assert not any(name.split('.')[0] in ROS for name in sys.modules)
''') % (ROS, CORE)


def test_core_imports_and_moves_without_ros():
    r = subprocess.run([sys.executable, '-c', PROGRAM], cwd=REPO_ROOT, capture_output=True,
                       text=True, timeout=120)
    assert r.returncode == 0, r.stderr[-3000:]
