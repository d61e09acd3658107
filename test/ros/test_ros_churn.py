"""Issue 11: the servo loop keeps running while people use ROS on it.

`python -m motion_ctrl.tools.soak` (what `scripts/soak` runs) as a process of its own: plant and
controller with the shipped parameters (feedback_timeout 0.02 s, the servo bus) at soak's
realtime_priority 30, the axis moving 1 inch back and forth, while 20 short-lived participants
(motion_ctrl.ros.visitor: a node that reads a register, subscribes to joint_states and x/status
for a moment, and exits) join and leave, two at a time, and a recorder starts and stops: no
FEEDBACK_FAULT, every move within 1 count, the recorder exits cleanly. With
MOTION_CTRL_SERVO_DOMAIN=off (no servo bus) it fails: doc/design_notes.md, "ROS tools joining".
"""
import re
import subprocess
import sys

import pytest

from kit import long_run

# No rerun on a stall of the servo link (a fault under the churn is what the soak counts).
pytestmark = pytest.mark.servo_link_under_test


@long_run('1-2 min; a soak: scripts/soak runs it for as long as you like')
@pytest.mark.timeout(300)          # (about a minute here; scripts/soak for a long run)
def test_joining_tools_and_a_recorder_do_not_open_the_loop(tmp_path, node_env):
    run = subprocess.run(
        [sys.executable, '-m', 'motion_ctrl.tools.soak', '--visitors', '20', '--parallel', '2',
         '--interval', '0.5', '--busy', '0', '--record', '-o', str(tmp_path)],
        env=node_env, capture_output=True, text=True, timeout=280)
    out = run.stdout + run.stderr
    print(out)
    moves = re.search(r'moves (\d+), faults (\d+), within 1 count (\d+)/(\d+)', out)
    assert moves, out
    n, faults, within, _ = map(int, moves.groups())
    assert faults == 0 and within == n >= 20, out
    assert 'visitors 20 (0 failed)' in out and 'in the controller log: 0' in out, out
    assert 'recorder exit code 0' in out and 'nodes stopped (exit codes 0, 0)' in out, out
    assert run.returncode == 0, out
