"""`<axis>/excite` and `<axis>/gather`: the controller's excitation runs (PMAC gather, WorkBench
Bode). A run starts the test signal the axis's excitation_* registers describe
(`ServoLoop.excite`); the answer names it, numbered per axis. When it ends, the whole per-tick
record is published once, latched, on `<axis>/gather` (msg_defs.gather), built and sent on a
thread of its own so that the servo tick only hands it over.
"""
from __future__ import annotations

import queue
import threading

from std_msgs.msg import Float64MultiArray

import msg_defs as md
from motion_ctrl.core.gather import COLUMNS


class ExcitationRuns:
    """The runs of the axes of `loop` on `node` (the controller)."""

    def __init__(self, node, loop) -> None:
        self.node = node
        self.loop = loop
        self.pub_gather = {a: node.stream(Float64MultiArray, md.gather_topic(a), md.GATHER_QOS)
                           for a in loop.axes}
        self.runs = {a: 0 for a in loop.axes}
        self.run_meta: dict[str, dict] = {}
        self.gathers: queue.SimpleQueue = queue.SimpleQueue()     # (axis, Gather, meta)
        threading.Thread(target=self._gather_loop, name='gather', daemon=True).start()

    def close(self) -> None:
        """The publishing thread ends (it holds the node)."""
        self.gathers.put(None)

    def excite(self, a: str):
        """<axis>/excite: start a run; the answer names it (its number is in the record)."""
        ok, reason = self.loop.excite(a)
        if not ok:
            return False, reason
        self.runs[a] += 1
        g = self.loop.axes[a].gather
        assert g is not None                     # (accepted: the run is there)
        e, r = g.excitation, self.loop.values[a]
        meta = dict(run=self.runs[a], signal=r['excitation_signal'], amplitude=e.amplitude,
                    band=[float(e.band[0]), float(e.band[1])], duration=e.duration,
                    velocity=g.base_velocity, budget=g.budget, rate=e.sample_rate)
        self.run_meta[a] = meta
        text = (f'{a}: run {meta["run"]}: {meta["signal"]} {e.amplitude:g} V, {e.band[0]:g}-'
                f'{e.band[1]:g} Hz, {e.ticks} ticks, base velocity {g.base_velocity:g} m/s, '
                f'budget {g.budget:g} m; the record comes on {md.gather_topic(a)}')
        self.node.get_logger().info(text)
        return True, text

    def collect(self) -> None:
        """On the servo tick: a run that ended is handed to the publishing thread."""
        for a in list(self.run_meta):
            g = self.loop.axes[a].gather
            if g is not None and g.ended is not None:
                self.gathers.put((a, g, self.run_meta.pop(a)))

    def _gather_loop(self) -> None:
        while (item := self.gathers.get()) is not None:            # (None: the node goes)
            a, g, meta = item
            rec = g.records[:g.tick]
            msg = md.gather_message(rec, COLUMNS, meta | dict(ended=g.ended, ticks=int(g.tick)))
            self.pub_gather[a].send(msg)
            self.node.get_logger().info(f'{a}: run {meta["run"]} ended ({g.ended}): {g.tick} '
                                        f'ticks published on {md.gather_topic(a)}')
