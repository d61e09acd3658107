"""autotune's verification plot (steps.png): the demo's moves with each set of gains (before /
after), the slide error after the end of the profile, the rest after MOTION_DONE and the output,
from analysis.autotune's MoveResults."""
from __future__ import annotations

import math

from matplotlib.figure import Figure


def plot_steps(path, runs: dict, *, title: str = '') -> None:
    """Per move (a column each), every set of gains (before / after) in it: the slide error
    [counts] in the first 0.8 s after the end of the profile (top), and over the whole record
    with the rest watched after MOTION_DONE (middle), the output [V] over it (bottom);
    MOTION_DONE marked, a limit cycle named in the legend."""
    names = list(runs)
    labels = list(dict.fromkeys(m.label for v in runs.values() for m in v))  # one panel each
    n = len(labels)
    fig = Figure(figsize=(4.2 * n, 9.5))
    axes = fig.subplots(3, n, sharey='row', squeeze=False)
    for j, label in enumerate(labels):
        span = max(float(m.t[-1]) for v in runs.values() for m in v if m.label == label)
        top, mid, bot = axes[0][j], axes[1][j], axes[2][j]
        for i, name in enumerate(names):
            m = next((x for x in runs[name] if x.label == label), None)
            if m is None:
                continue
            c = f'C{i}'
            keep = (m.t >= -0.1) & (m.t <= 0.8)
            settle = f'{m.settle_ms:.0f} ms' if math.isfinite(m.settle_ms) else 'none'
            top.plot(m.t[keep] * 1e3, m.error[keep], '-', color=c, lw=1.1,
                     label=f'{name}: settle {settle}, final {m.final_error:+.2f}')
            mid.plot(m.t, m.error, '-', color=c, lw=1.0, label=f'{name}: {m.rest.short()}')
            if m.output.size:
                bot.plot(m.t, m.output, '-', color=c, lw=0.8)
            if math.isfinite(m.settle_ms):
                top.axvline(m.settle_ms, color=c, ls=':', lw=1)
                for a in (mid, bot):
                    a.axvline(m.settle_ms / 1e3, color=c, ls=':', lw=1)
        for a in (top, mid):
            a.axhspan(-1, 1, color='g', alpha=0.1)
            a.grid(True, alpha=0.3)
        bot.grid(True, alpha=0.3)
        top.set_title(label, fontsize=9)
        top.set_xlabel('time from the end of the profile [ms]')
        top.set_ylim(-25, 25)
        top.legend(fontsize=7, loc='lower right')
        mid.set_ylim(-5, 5)
        mid.set_xlim(-0.1, span)
        mid.legend(fontsize=7, loc='upper right')
        bot.set_xlim(-0.1, span)
        bot.set_xlabel('time from the end of the profile [s]')
    axes[0][0].set_ylabel('slide error (joint_states) [linear counts]')
    axes[1][0].set_ylabel('slide error, whole record [counts]')
    axes[2][0].set_ylabel('output [V]')
    if title:
        fig.suptitle(title, fontsize=10)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
