"""The headline over ROS (issues 4 and 5): plant and controller as two processes, targets on
`target_position`, the true slide read from `plant_states`, the status word from `x/status`."""
import pytest

from motion_ctrl.ros import servo_bus
from motion_ctrl.ros.servo_bus import commander

from kit import COUNT, INCH, note_link_stalls, running_slide, spin_for
from msg_defs.status import Status
from motion_ctrl.ros.client import SlideClient


@pytest.fixture
def slide(rclpy_session, tmp_path, request, monkeypatch):
    feedback, *plant = request.param.split(',')
    if plant:
        # 'foreign': the controller on the servo bus, the plant off it, answering on the user's
        # domain as a plant of another make does, named as the controller's peer; the
        # controller's bridge carries its streams (ros.servo_bus.bridge, commander).
        monkeypatch.setenv(servo_bus.ENV, 'auto')
        monkeypatch.setenv(commander.PEER_ENV, '/plant')
    with running_slide(tmp_path, lambda: SlideClient(name=f'headline_{feedback}'),
                       {'x.feedback': feedback}, exit_zero=True,
                       plant_env={servo_bus.ENV: 'off'} if plant else None) as s:
        yield s.client
        note_link_stalls(request, s.log('controller'), s.log('plant'))
        if plant:
            assert 'copied in' in s.log('controller'), s.log('controller')


@pytest.mark.timeout(120)
@pytest.mark.parametrize('slide', ['dual', 'sampled', 'dual,foreign'], indirect=True)
def test_one_inch_after_a_reversal_lands_within_a_count(slide):
    assert slide.move({'x': 2 * INCH}, timeout=10.0) is not None, \
        f'no MOTION_DONE, status {Status(slide.status["x"])!r}'
    t = slide.move({'x': INCH}, timeout=10.0)
    assert t is not None, f'no MOTION_DONE, status {Status(slide.status["x"])!r}'
    spin_for(slide, 0.05)                # the latest truth after MOTION_DONE
    error = (slide.load_position() - INCH) / COUNT
    assert abs(error) <= 1.0, f'slide {error:+.2f} counts from the target'


@pytest.mark.timeout(120)
@pytest.mark.parametrize('slide', ['dual'], indirect=True)
def test_status_transitions_of_a_move_arrive_in_order(slide):
    mark = len(slide.status_log['x'])
    assert slide.move({'x': INCH}, timeout=10.0) is not None
    words = [w for _, w in slide.status_log['x'][mark:]]

    def first(bit):
        return next(i for i, w in enumerate(words) if w & bit)
    moving = first(Status.MOVING)
    at_target, coarse = first(Status.AT_TARGET), first(Status.IN_COARSE_POSITION)
    fine, done = first(Status.IN_FINE_POSITION), first(Status.MOTION_DONE)
    assert moving == 0                   # the first change the subscriber sees is MOVING
    assert moving < min(at_target, coarse) <= max(at_target, coarse) <= fine <= done
    assert words[done] & Status.IN_FINE_POSITION          # settled and done together
    assert not words[done] & Status.MOVING
