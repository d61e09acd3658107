"""calibrate's figure of an ISO 230-2 test (motion_ctrl.analysis.iso230 evaluates it): the
deviation along the travel per approach direction, means and ±2s bands, one panel per run."""
from __future__ import annotations

import matplotlib
import matplotlib.pyplot as plt


def plot_report(runs: dict, path, counts_per_m: float, title: str = '') -> None:
    """PNG: deviation along the travel per direction (means, ±2 s bands), one panel per run."""
    matplotlib.use('Agg')
    fig, axes = plt.subplots(len(runs), 1, figsize=(9, 3.6 * len(runs)), sharex=True,
                             squeeze=False)
    for ax, (label, r) in zip(axes[:, 0], runs.items()):
        x = r.targets * 1e3
        for mean, s, raw, colour, name in ((r.mean_up, r.s_up, r.up, 'tab:blue', '↑ positive'),
                                           (r.mean_down, r.s_down, r.down, 'tab:red',
                                            '↓ negative')):
            ax.fill_between(x, (mean - 2 * s) * counts_per_m, (mean + 2 * s) * counts_per_m,
                            color=colour, alpha=0.2, label=f'{name}: x̄ ± 2s')
            ax.plot(x, mean * counts_per_m, 'o-', color=colour, label=f'{name}: x̄')
            for j in range(raw.shape[1]):
                ax.plot(x, raw[:, j] * counts_per_m, '.', color=colour, alpha=0.35, ms=3)
        ax.axhline(0.0, color='k', lw=0.6)
        h = {k: v * counts_per_m for k, v in r.headline().items()}
        ax.set_title(f'{label}: A {h["A"]:.1f}, B {h["B"]:.1f}, E {h["E"]:.1f}, '
                     f'M {h["M"]:.1f}, R {h["R"]:.1f} counts', fontsize=10)
        ax.set_ylabel('deviation [linear counts]')
        ax.grid(alpha=0.3)
        ax.legend(fontsize=8, ncol=2, loc='best')
    axes[-1, 0].set_xlabel('target position [mm]')
    if title:
        fig.suptitle(title, fontsize=10)
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)
