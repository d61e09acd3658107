"""The controller as the clock (`hardware: sim` with `use_sim_time`): it ticks back to back, as
fast as the machine allows up to `sim_speed` times real time (0: unbounded), publishes `/clock`,
and runs the callbacks that came (targets, services, parameters) between batches of ticks
(SIM_BATCH s of wall time): deterministic for targets stamped ahead. Its /clock is published
once a batch. `sim_speed` is 4 unless set: a client reading the streams (a tool placing a
move's status words among the joint_states samples, a recorder) keeps up; unbounded (~20x real
time here), a tool's readings of a move lag it by tens to hundreds of ms of sim time, and its
targets land at times set by its own lag.
"""
from __future__ import annotations

import time

from rosgraph_msgs.msg import Clock as ClockMsg

import msg_defs as md
from motion_ctrl.ros.hardware_topics import stamp_of

# s of wall time the sim clock ticks before it runs the callbacks
SIM_BATCH = 0.001


class SimClock:
    """`node`'s own clock: `tick(stamp)` is its servo cycle, `diagnostics()` its once-a-second
    report (in sim seconds). The node's clock is set to the ticks' time; it does not read
    /clock, which it would only hear from itself."""

    def __init__(self, node, period_ns: int, tick, diagnostics, speed: float) -> None:
        self.node = node
        self.speed = speed
        self.period_ns = period_ns
        self.tick = tick
        self.diagnostics = diagnostics
        self.pub_clock = node.create_publisher(ClockMsg, md.CLOCK, 10)
        self.sim_ns = 0
        self.wall_start = time.perf_counter()
        self.next_diagnostics_ns = 1_000_000_000
        node._time_source.detach_node()
        node._time_source.clock_callback(ClockMsg())

    def set_speed(self, speed: float) -> None:
        """`sim_speed` changed: counted from now."""
        self.speed = speed
        if speed > 0.0:
            self._count_from_now()

    def _due(self) -> float:
        """Wall seconds (since wall_start) at which the sim time now is due under the bound."""
        return self.sim_ns * 1e-9 / self.speed

    def _count_from_now(self) -> None:
        """The bound counted from the sim time now and the wall time now."""
        self.wall_start = time.perf_counter() - self._due()

    def spin_step(self, executor) -> None:
        """Servo ticks back to back for SIM_BATCH s of wall time (none while the sim time is
        ahead of `speed` x the wall time since the start), then /clock (the time of the
        last tick: ~1 kHz of wall time, as a simulator publishes it; one message per tick would
        cost every reader of /clock more than the tick itself) and the callbacks that came
        meanwhile."""
        speed = self.speed
        if speed > 0.0:
            ahead = self._due() - (time.perf_counter() - self.wall_start)
            if ahead > 0.0:             # (at full speed: callbacks only, until it is time)
                executor.spin_once(timeout_sec=min(ahead, SIM_BATCH))
                return
            if ahead < -SIM_BATCH:      # behind (a busy machine): on from now, not in a burst
                self._count_from_now()
        end = time.perf_counter() + SIM_BATCH
        # the batch ends at SIM_BATCH of wall time, or where the bound stands at its end
        last_ns = (round((end - self.wall_start) * speed * 1e9) if speed > 0.0
                   else None)
        while True:
            self.tick(stamp_of(self.sim_ns * 1e-9))
            if self.sim_ns >= self.next_diagnostics_ns:
                self.next_diagnostics_ns += 1_000_000_000
                self.diagnostics()
            self.sim_ns += self.period_ns
            if time.perf_counter() >= end or (last_ns is not None and self.sim_ns > last_ns):
                break
        clock = ClockMsg(clock=stamp_of((self.sim_ns - self.period_ns) * 1e-9))
        self.pub_clock.publish(clock)
        self.node._time_source.clock_callback(clock)
        executor.spin_once(timeout_sec=0.0)
