"""The coordinated-motion example's figure: each shape's commanded path with the true slide's
deviation from it magnified (as a ballbar plot shows it), and the contour error along the path
(motion_ctrl.analysis.contour computes it)."""
from __future__ import annotations

import pathlib

import matplotlib
import matplotlib.pyplot as plt
from scipy.spatial import cKDTree


def plot(results: dict, png: pathlib.Path, magnify: float = 200.0) -> None:
    """Each shape of `results` (analysis.contour.judge's figures and the true XY, 'truth')
    in a column: the path above, the contour error below; written to `png`."""
    matplotlib.use('Agg')
    fig, axs = plt.subplots(2, len(results), figsize=(6.5 * len(results), 10), squeeze=False)
    for col, (shape, r) in enumerate(results.items()):
        ax = axs[0][col]
        path, xy = r['path'], r['truth']
        # The deviation, magnified along the way from the nearest commanded point (ballbar).
        near = path[cKDTree(path).query(xy)[1]]
        shown = near + magnify * (xy - near)
        ax.plot(path[:, 0] * 1e3, path[:, 1] * 1e3, 'k-', lw=1, label='commanded path')
        ax.plot(shown[:, 0] * 1e3, shown[:, 1] * 1e3, 'r-', lw=0.8,
                label=f'true slide, deviation ×{magnify:g}')
        ax.set_aspect('equal')
        ax.set_xlabel('x [mm]')
        ax.set_ylabel('y [mm]')
        ax.set_title(f'{shape}: contour error RMS {r["rms"]:.2f}, peak {r["peak"]:.2f} counts '
                     '(after the first quarter)', fontsize=9)
        ax.legend(fontsize=8, loc='upper right')
        ax = axs[1][col]
        ax.plot(r['t'], r['error'], 'b-', lw=0.8)
        ax.axvspan(0, r['t_quarter'], color='0.9', label='first quarter (not judged)')
        ax.axvline(r['duration'], color='k', ls=':', label='end of the path')
        ax.set_xlabel('time from the trajectory start [s]')
        ax.set_ylabel('contour error [linear counts]')
        ax.legend(fontsize=8)
        ax.grid(alpha=0.3)
    fig.tight_layout()
    fig.savefig(png, dpi=110)
    plt.close(fig)
