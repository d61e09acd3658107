"""The controller's /diagnostics messages (ros.diagnostics) without a node: the servo loop's
status and every axis's, the axes of a large controller spread over the ticks after it."""
from builtin_interfaces.msg import Time

from motion_ctrl.core.axis import Axis
from motion_ctrl.core.diagnostics import LoopStats
from motion_ctrl.core.registers import axis_defaults
from motion_ctrl.ros.diagnostics import AXES_PER_MESSAGE, Diagnostics

T = 0.001


class _Stream:
    def __init__(self):
        self.sent = []

    def send(self, msg):
        self.sent.append(msg)
        return True


def _diagnostics(n_axes: int):
    axes = {f'a{i}': Axis(f'a{i}', axis_defaults(), T) for i in range(n_axes)}
    stream = _Stream()
    return Diagnostics(stream, 'controller', axes), stream


def _names(msg):
    return [st.name for st in msg.status]


def test_a_few_axes_are_one_message_with_the_loop():
    diag, stream = _diagnostics(6)
    diag.start(Time(), LoopStats(T))
    diag.tick(Time())
    assert len(stream.sent) == 1
    assert _names(stream.sent[0]) == ['controller: servo loop'] + [
        f'controller: axis a{i}' for i in range(6)]


def test_many_axes_follow_the_loop_a_part_a_tick_each_axis_once():
    n = 2 * AXES_PER_MESSAGE + 5
    diag, stream = _diagnostics(n)
    diag.start(Time(), LoopStats(T))
    assert len(stream.sent) == 1 and len(stream.sent[0].status) == 1 + AXES_PER_MESSAGE
    for _ in range(5):
        diag.tick(Time())
    sizes = [len(m.status) for m in stream.sent]
    assert sizes == [1 + AXES_PER_MESSAGE, AXES_PER_MESSAGE, 5]
    names = [n for m in stream.sent for n in _names(m)]
    assert names == ['controller: servo loop'] + [f'controller: axis a{i}' for i in range(n)]


def test_a_part_still_pending_goes_out_before_the_next_second():
    n = 3 * AXES_PER_MESSAGE
    diag, stream = _diagnostics(n)
    diag.start(Time(), LoopStats(T))
    diag.start(Time(), LoopStats(T))           # no tick between: the rest is sent first
    names = [n for m in stream.sent for n in _names(m)]
    assert names[:1 + n] == ['controller: servo loop'] + [
        f'controller: axis a{i}' for i in range(n)]
    assert names[1 + n] == 'controller: servo loop'
