"""Issue 11: the servo loop keeps running while people use ROS on it.

Plant and controller with the shipped parameters (feedback_timeout 0.02 s) at real-time priority
(realtime_priority 30, README Notes), the axis moving
1 inch back and forth, while 50 short-lived participants (motion_ctrl.visitor: a node that reads
a register, subscribes to joint_states and x/status for a moment, and exits) join and leave and
a recorder starts and stops: no FEEDBACK_FAULT, no refusal, every move within 1 count.
"""
import signal

import pytest

from motion_ctrl.client import SlideClient
from motion_ctrl.processes import start_slide
from motion_ctrl.soak import Soak, Visitors
from test_record_report import RecorderProcess

VISITORS = 50


@pytest.mark.timeout(300)
def test_joining_tools_and_a_recorder_do_not_open_the_loop(rclpy_session, tmp_path, node_env):
    rt = {'realtime_priority': 30}
    plant, controller = start_slide(rt, rt, log_dir=tmp_path)
    client = SlideClient(name='churn', services=True)
    recorder = None
    try:
        assert client.wait_ready(30.0), f'nodes did not come up ({client.not_ready()})'
        soak = Soak(client)
        visitors = Visitors(interval=0.5, count=VISITORS, parallel=2, env=node_env).start()
        while not visitors.done():
            soak.move()
            if recorder is None and visitors.started >= VISITORS // 3:
                recorder = RecorderProcess(['-o', str(tmp_path / 'bag')])
            elif recorder is not None and recorder.proc.poll() is None \
                    and visitors.started >= 2 * VISITORS // 3:
                rc, _, err = recorder.stop(signal.SIGINT)
                assert rc == 0, err
        soak.move()
    finally:
        client.destroy_node()
        if recorder is not None:
            recorder.kill()
        assert controller.stop() == 0 and plant.stop() == 0
    log = (tmp_path / 'controller.log').read_text()
    assert visitors.finished == VISITORS and not visitors.failed, visitors.failed
    assert recorder is not None and recorder.proc.returncode == 0
    assert not soak.faults, f'{soak.summary()}: {soak.faults}\n{log}'
    assert 'FEEDBACK_FAULT' not in log and 'refused' not in log, log
    assert soak.within_1_count == soak.moves >= 20, soak.summary()
