"""The controller's /diagnostics (diagnostic_msgs/DiagnosticArray, REP 107's aggregator input):
one status for the servo loop, from its timing statistics (core.diagnostics.LoopStats), and
one per axis, from what the axis's tick reports.

Once a second. Up to AXES_PER_MESSAGE axes it is one message; more axes go in further messages
of AXES_PER_MESSAGE statuses each, one a servo tick after the first (as diagnostic_updater's
tasks publish apart: the aggregator takes statuses from any message), so that no tick builds
and sends them all: 256 axes' statuses cost the servo thread 8-14 ms in one message here."""
from __future__ import annotations

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue

from msg_defs.status import Status
from motion_ctrl.core.diagnostics import LoopStats


AXES_PER_MESSAGE = 16


class Diagnostics:
    """The /diagnostics messages of a controller: `start` once a second, `tick` every servo
    tick (it sends the next part, if any, of the axes' statuses)."""

    def __init__(self, stream, node_name: str, axes: dict):
        self.stream, self.node_name, self.axes = stream, node_name, axes
        self.pending: list[str] = []

    def start(self, stamp, stats: LoopStats, extra: dict | None = None) -> None:
        """The servo loop's status and the first AXES_PER_MESSAGE axes' now; the others
        follow, AXES_PER_MESSAGE a tick. A part still pending is sent first."""
        while self.pending:
            self.tick(stamp)
        names = list(self.axes)
        arr = DiagnosticArray()
        arr.header.stamp = stamp
        arr.status = [loop_status(self.node_name, stats, extra)] + [
            axis_status(self.node_name, a, self.axes[a]) for a in names[:AXES_PER_MESSAGE]]
        self.stream.send(arr)
        self.pending = names[AXES_PER_MESSAGE:]

    def tick(self, stamp) -> None:
        if not self.pending:
            return
        part, self.pending = self.pending[:AXES_PER_MESSAGE], self.pending[AXES_PER_MESSAGE:]
        arr = DiagnosticArray()
        arr.header.stamp = stamp
        arr.status = [axis_status(self.node_name, a, self.axes[a]) for a in part]
        self.stream.send(arr)


def loop_status(node_name: str, stats: LoopStats, extra: dict | None = None):
    """The servo loop's status: its rate against the nominal, `stats`' figures and `extra`,
    more values of the loop's status, name -> number."""
    loop = DiagnosticStatus(name=f'{node_name}: servo loop', hardware_id=node_name)
    s = stats.summary()
    nominal = 1.0 / stats.nominal
    if s and s['rate_hz'] >= 0.99 * nominal:
        loop.level, loop.message = DiagnosticStatus.OK, f'{s["rate_hz"]:.1f} Hz'
    elif s:
        loop.level, loop.message = DiagnosticStatus.WARN, (
            f'{s["rate_hz"]:.1f} Hz, below 99 % of {nominal:g} Hz')
    else:
        loop.level, loop.message = DiagnosticStatus.WARN, 'no ticks yet'
    loop.values = [KeyValue(key='nominal_rate_hz', value=f'{nominal:g}')] + [
        KeyValue(key=k, value=f'{v:.6g}') for k, v in (s | (extra or {})).items()]
    return loop


def axis_status(node_name: str, name: str, axis):
    """An axis's status: faults, amplifier fault, hunting; mode, feedback, the gains it runs
    with, status word, following error, output."""
    st = DiagnosticStatus(name=f'{node_name}: axis {name}', hardware_id=name)
    faults = axis.status & (Status.FOLLOWING_ERROR_FATAL | Status.FEEDBACK_FAULT
                            | Status.OVERSPEED)
    drive = axis.drive_fault_reason
    hunting = axis.hunting
    st.level = DiagnosticStatus.ERROR if faults or drive else \
        DiagnosticStatus.WARN if hunting.hunting else DiagnosticStatus.OK
    st.message = (f'faulted: {Status(faults)!r}' if faults else
                  f'amplifier fault: {drive}' if drive else
                  f'hunting: {hunting.describe(axis.loop_counts_per_m)}' if hunting.hunting
                  else 'enabled' if axis.enabled else 'disabled')
    st.values = [KeyValue(key='mode', value=axis.r['mode']),
                 KeyValue(key='feedback', value=axis.r['feedback']),
                 # the gains the loop runs with (applied, not just accepted)
                 KeyValue(key='kp', value=repr(axis.r['kp'])),
                 KeyValue(key='ki', value=repr(axis.r['ki'])),
                 KeyValue(key='kd', value=repr(axis.r['kd'])),
                 KeyValue(key='enabled', value=str(axis.enabled)),
                 KeyValue(key='status', value=f'0x{int(axis.status):05x}'),
                 KeyValue(key='following_error_m', value=f'{axis.following_error:.3e}'),
                 KeyValue(key='output_v', value=f'{axis.output:.3f}'),
                 # core.hunting: output reversals at rest without settling
                 KeyValue(key='hunting', value=str(hunting.hunting)),
                 KeyValue(key='output_reversals_at_rest', value=str(hunting.reversals)),
                 KeyValue(key='hunting_period_s', value=f'{hunting.period:.3f}'),
                 KeyValue(key='hunting_amplitude_counts',
                          value=f'{hunting.amplitude * axis.loop_counts_per_m:.2f}')]
    return st
