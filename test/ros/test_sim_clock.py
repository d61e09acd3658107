"""The controller as the clock (ros.sim_clock, `hardware: sim` with `use_sim_time`): `sim_speed`
bounds the sim seconds per wall second, 0 unbounds it, and a change counts from when it is
made. Ticks that cost nothing, so that only the bound holds the clock back."""
import time

from motion_ctrl.ros.sim_clock import SimClock

PERIOD_NS = 1_000_000


class _Node:
    """What SimClock uses of a node."""

    class _TimeSource:
        def detach_node(self):
            pass

        def clock_callback(self, msg):
            self.now = msg.clock

    class _Publisher:
        def publish(self, msg):
            pass

    def __init__(self):
        self._time_source = self._TimeSource()

    def create_publisher(self, *args):
        return self._Publisher()


class _Executor:
    def spin_once(self, timeout_sec=None):
        if timeout_sec:
            time.sleep(timeout_sec)


def _run(clock: SimClock, seconds: float) -> float:
    """Sim seconds per wall second over `seconds` of wall time."""
    executor = _Executor()
    sim0, t0 = clock.sim_ns, time.perf_counter()
    while time.perf_counter() - t0 < seconds:
        clock.spin_step(executor)
    return (clock.sim_ns - sim0) * 1e-9 / (time.perf_counter() - t0)


def _clock(speed: float) -> SimClock:
    return SimClock(_Node(), PERIOD_NS, lambda stamp: None, lambda: None, speed)


def test_sim_speed_bounds_the_clock_and_zero_unbounds_it():
    clock = _clock(2.0)
    held = _run(clock, 0.5)
    assert held <= 2.0 * 1.05, f'{held:.2f} sim s per wall s at sim_speed 2'
    clock.set_speed(0.0)
    free = _run(clock, 0.3)
    assert free > 10.0, f'{free:.2f} sim s per wall s unbounded (ticks that cost nothing)'


def test_a_new_sim_speed_counts_from_when_it_is_set():
    clock = _clock(0.0)
    _run(clock, 0.2)                       # far ahead of any bound's wall time
    clock.set_speed(1.0)
    later = _run(clock, 0.5)
    # From now: neither a stop until the wall time catches up with the sim time run ahead,
    # nor a burst.
    assert 0.5 < later <= 1.05, f'{later:.2f} sim s per wall s after sim_speed 1'
