"""Issue 11: the servo loop keeps running while people use ROS on it.

`python -m motion_ctrl.tools.soak` (what `scripts/soak` runs) as a process of its own: plant and
controller with the shipped parameters (feedback_timeout 0.02 s) at real-time priority
(realtime_priority 30, README Notes), the axis moving 1 inch back and forth, while 50 short-lived
participants (motion_ctrl.ros.visitor: a node that reads a register, subscribes to joint_states and
x/status for a moment, and exits) join and leave, two at a time, and a recorder starts and
stops: no FEEDBACK_FAULT, every move within 1 count, the recorder exits cleanly.
"""
import os
import re
import subprocess
import sys

import pytest


# Not yet met in the full suite (issue 11 open): it passes alone (3 of 3 runs here), but run
# after test_amp_safety (a controller SIGKILLed, then SIGINTed) 2 of 50 visitors in each of 4
# runs stalled both servo streams for 333 ms even at real-time priority. Opt-in
# (MOTION_CTRL_CHURN=1 scripts/test test/test_ros_churn.py): in the suite, the tests after it
# then could not discover the nodes' parameter services.
@pytest.mark.skipif(not os.environ.get('MOTION_CTRL_CHURN'),
                    reason='opt-in (MOTION_CTRL_CHURN=1): expected to fail for now, and its 50 '
                           'participants disturbed the DDS tests after it')
@pytest.mark.xfail(reason='joining participants still stall the servo streams now and then '
                          '(README Notes, issue 11)', strict=False)
@pytest.mark.timeout(300)
def test_joining_tools_and_a_recorder_do_not_open_the_loop(tmp_path, node_env):
    run = subprocess.run(
        [sys.executable, '-m', 'motion_ctrl.tools.soak', '--visitors', '50', '--parallel', '2',
         '--interval', '0.5', '--busy', '0', '--record', '-o', str(tmp_path)],
        env=node_env, capture_output=True, text=True, timeout=280)
    out = run.stdout + run.stderr
    moves = re.search(r'moves (\d+), faults (\d+), within 1 count (\d+)/(\d+)', out)
    assert moves, out
    n, faults, within, _ = map(int, moves.groups())
    assert faults == 0 and within == n >= 20, out
    assert 'visitors 50 (0 failed)' in out and 'in the controller log: 0' in out, out
    assert 'recorder exit code 0' in out and 'nodes stopped (exit codes 0, 0)' in out, out
    assert run.returncode == 0, out
