"""The ballbar judgement of a drawn path (ISO 230-4's circular test, read as a contouring
machine's user reads it): the commanded shapes of the coordinated-motion example (`draw`), and
the contour error of the true XY path from the commanded one, in linear counts, after the first
quarter of the path (the speed ramp)."""
from __future__ import annotations

import numpy as np

from motion_ctrl.core import trajectory as tj
from motion_ctrl.core.registers import LOAD_COUNTS_PER_M, axis_defaults

AXES = ('x', 'y')
PATH_DT = 5e-5        # s: the commanded path is sampled this finely for the contour error


def shape_points(shape: str, start: dict, radius: float, speed: float) -> tuple[tj.Points, tuple]:
    """The shape's points, starting (at rest) on the whole slide-encoder count nearest where
    the axes are; its centre. Both shapes end where they start: on a whole count, which a
    floored encoder reads as the target from the count up to the next (a point between counts
    is met, in the fine window, up to 1.6 counts away)."""
    x0, y0 = (round(start[a] * LOAD_COUNTS_PER_M) / LOAD_COUNTS_PER_M for a in ('x', 'y'))
    if shape == 'circle':
        center = (x0 - radius, y0)                 # start_angle 0: the start is centre + (r, 0)
        return tj.circle(center, radius, speed, start_time=0.1), center
    side = 2 * radius
    center = (x0, y0 + side / 2)                  # starts at the middle of the lower side
    return tj.rounded_square(center, side, radius / 4, speed, start_time=0.1), center


def judge(points: tj.Points, start: dict, truth_t, truth_xy) -> dict:
    """Contour error [counts] of the true XY samples (times from the trajectory's start) after
    the first quarter of the path (by length) and up to its end."""
    limits = {a: tj.AxisLimits.from_registers(axis_defaults()) for a in AXES}
    traj = tj.Trajectory.from_points(list(AXES), points, start={a: (start[a], 0.0, 0.0)
                                                                 for a in AXES}, limits=limits)
    t = np.arange(0.0, traj.duration + PATH_DT, PATH_DT)
    path = traj.sample(t)[0]
    length = np.concatenate([[0.0], np.cumsum(np.hypot(*np.diff(path, axis=0).T))])
    t_quarter = t[np.searchsorted(length, length[-1] / 4)]
    err = tj.contour_error(path, truth_xy) * LOAD_COUNTS_PER_M
    judged = (truth_t >= t_quarter) & (truth_t <= traj.duration)
    e = err[judged]
    return {'path': path, 'error': err, 't': truth_t, 'judged': judged,
            'rms': float(np.sqrt(np.mean(e ** 2))), 'peak': float(e.max()),
            'duration': traj.duration, 't_quarter': float(t_quarter)}
