"""A coordinate system of a controller: trajectories that several axes follow on one time base
(PMAC's PVT moves in a coordinate system, LinuxCNC's coordinated motion). A trajectory is
checked as a whole before any axis starts (motion_ctrl.core.trajectory), may be scheduled for a
stamp, and stops as one: an axis that leaves it by a stop, abort, disable or fault stops the
other axes of it too.

No ROS here: `ServoLoop` owns one and calls it at its tick (stage 4).
"""
from __future__ import annotations

from dataclasses import dataclass

from motion_ctrl.core.axis import Axis
from motion_ctrl.core.trajectory import AxisLimits, Trajectory

__all__ = ['Prepared', 'CoordinateSystem']


@dataclass(frozen=True)
class Prepared:
    """A trajectory checked and built from the axes' state `start` ({axis: (p, v, a)}), and
    each axis's share of it (`paths`, Trajectory.paths: a few ms for a few hundred points, so
    made here, off the servo thread where the node can)."""
    spec: dict
    trajectory: Trajectory
    start: dict
    paths: dict


class CoordinateSystem:
    """The trajectories of one controller's axes: those waiting for their stamp and those
    running. `values` are the axes' registers as applied ({axis: {register: value}})."""

    def __init__(self, axes: dict[str, Axis]):
        self.axes = axes
        # Waiting for their stamp (stamp, job, {axis: epoch}), and running ({axis: (its path,
        # the command epoch it started in)}).
        self.scheduled: list[tuple[float, Prepared, dict[str, int]]] = []
        self.running: list[dict] = []

    @property
    def busy(self) -> bool:
        return bool(self.scheduled or self.running)

    def prepare(self, spec: dict, values: dict):
        """Check and build the trajectory of `spec` (msg_defs.read_joint_trajectory's dict)
        from the axes' commanded state now: a Prepared, or the refusal. It only reads the
        axes, so the node can run it off the servo thread (a 400-point quintic takes ~8 ms);
        `start` builds it again if the axes have moved meanwhile."""
        limits = {a: AxisLimits.from_registers(values[a]) for a in self.axes}
        start = {a: self.axes[a].path_state for a in spec['names'] if a in self.axes}
        try:
            built = Trajectory.build(spec['names'], spec['times'], spec['positions'],
                                     spec['velocities'], spec['accelerations'],
                                     start=start, limits=limits)
        except ValueError as e:
            return str(e)
        return Prepared(spec, built, start, built.paths())

    def start(self, job, values: dict, stamp: float | None = None, now: float | None = None):
        """Start (or, with a `stamp` after `now`, schedule) `job`, a spec or a Prepared of it,
        checked as a whole from the axes' commanded state at the start; returns the refusal,
        or None. A refused trajectory changes nothing."""
        if isinstance(job, dict) or any(self.axes[a].path_state != s
                                        for a, s in job.start.items()):
            job = self.prepare(job if isinstance(job, dict) else job.spec, values)
            if isinstance(job, str):
                return job
        names = job.spec['names']
        for a in names:
            reason = self.axes[a].start_refusal('trajectory')
            if reason:
                return reason
        if stamp is not None and now is not None and stamp > now + 1e-9:
            self.scheduled.append((stamp, job, {a: self.axes[a].command_epoch for a in names}))
            return None
        paths = job.paths
        for a in names:
            ok, reason = self.axes[a].follow(paths[a])
            if not ok:                       # (checked above; a refusal here still counts)
                self._stop(set(names), f'{a} refused its path')
                return reason
        self.running = [g for g in self.running if not set(g) & set(names)]
        self.running.append({a: (paths[a], self.axes[a].command_epoch) for a in names})
        return None

    def tick(self, now: float, values: dict) -> list[tuple[str, str]]:
        """Start the trajectories that are due; stop the axes of a running one whose other
        axis left it by a stop, abort, disable or fault. Returns the log lines."""
        log: list[tuple[str, str]] = []
        due = [x for x in self.scheduled if x[0] <= now + 1e-9]
        if due:
            self.scheduled = [x for x in self.scheduled if x[0] > now + 1e-9]
            for stamp, job, epochs in due:
                void = [a for a, e in epochs.items() if self.axes[a].command_epoch != e]
                if void:
                    log.append(('warning', f'scheduled trajectory (stamped {stamp:.3f} s) '
                                           f'cancelled by {self.axes[void[0]].cancelled_by}'
                                           f' on {void[0]}'))
                    continue
                reason = self.start(job, values)
                if reason:
                    log.append(('warning', f'joint_trajectory refused: {reason}'))
        running = []
        for group in self.running:
            on = {a for a, (path, _) in group.items() if self.axes[a].profile.following(path)}
            left = [a for a, (_, epoch) in group.items() if self.axes[a].command_epoch != epoch]
            if left and on:
                log += self._stop(on, f'{left[0]} left it ({self.axes[left[0]].cancelled_by})')
            elif on:
                running.append(group)
        self.running = running
        return log

    def _stop(self, names: set, why: str) -> list[tuple[str, str]]:
        log = []
        for a in sorted(names):
            ok, _ = self.axes[a].stop('stop')
            if ok:
                log.append(('warning', f'{a}: trajectory stopped: {why}'))
        return log
