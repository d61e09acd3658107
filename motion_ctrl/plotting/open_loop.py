"""autotune's open-loop plot (open_loop.png): the Bode plot of the open loop L of each set of
registers on the measured axis, the model as a line and the measured points as markers, the
gain and phase margins marked at their crossovers, as Kollmorgen WorkBench's Performance Servo
Tuner shows a proposal. The loops and margins are analysis.autotune's (open_loops,
Evaluation)."""
from __future__ import annotations

import numpy as np
from matplotlib.figure import Figure

from motion_ctrl.analysis.autotune import AxisResponse, Evaluation, open_loops


def _wrapped(deg):
    """Phase in [-360°, 0): −180° (the stability point) in the middle of the plot."""
    return np.mod(deg, 360.0) - 360.0


def plot_open_loop(path, axis: AxisResponse, evaluations: list, *, title: str = '') -> None:
    """Bode plot of the open loop L of each (label, Evaluation): the model as a line, the
    measured points as markers, gain and phase margins marked (model) at their crossovers."""
    fig = Figure(figsize=(9, 7.5))
    ax_m, ax_p = fig.subplots(2, 1, sharex=True)
    for i, (label, ev) in enumerate(evaluations):
        _loop(ax_m, ax_p, axis, label, ev, f'C{i}')
    for a in (ax_m, ax_p):
        a.axvline(axis.model.resonance_hz, color='k', ls=':', lw=0.8)
        a.axvline(axis.model.antiresonance_hz, color='grey', ls=':', lw=0.8)
        a.grid(True, which='both', alpha=0.3)
    ax_m.axhline(0.0, color='k', lw=0.8)
    ax_p.axhline(-180.0, color='k', lw=0.8)
    ax_m.set_ylim(-40, 60)
    ax_m.set_ylabel('|L| [dB]')
    ax_p.set_ylabel('phase of L [°]')
    ax_p.set_ylim(-360, 0)
    ax_p.set_yticks(list(range(-360, 1, 45)))
    ax_p.set_xlabel('frequency [Hz]')
    ax_m.set_xlim(1.0, axis.nyquist)
    ax_m.legend(fontsize=8, loc='lower left')
    ax_m.set_title(title or 'open loop (line: model, markers: measured; one tick of latency, '
                   'notch included)', fontsize=9)
    fig.tight_layout()
    fig.savefig(path, dpi=110)


def _loop(ax_m, ax_p, axis: AxisResponse, label: str, ev: Evaluation, c: str) -> None:
    """One set of registers in colour `c`: L of the model (line) and of the measured points
    (markers), its margins marked."""
    (f, L), measured = open_loops(axis, ev)
    ph = _wrapped(np.degrees(np.angle(L)))
    ax_m.semilogx(f, 20 * np.log10(np.abs(L)), '-', color=c, lw=1.2,
                  label=f'{label}: GM {ev.gain_margin_db:.1f} dB, PM '
                        f'{ev.phase_margin_deg:.1f}°, crossover '
                        f'{ev.crossover_hz or float("nan"):.1f} Hz')
    gap = np.abs(np.diff(ph)) > 180.0             # a wrap, not a line across the plot
    ax_p.semilogx(f, np.where(np.append(gap, False), np.nan, ph), '-', color=c, lw=1.2)
    if measured is not None:
        fm, Lm = measured
        phm = _wrapped(np.degrees(np.angle(Lm)))
        ax_m.semilogx(fm, 20 * np.log10(np.abs(Lm)), 'o', ms=3.5, mfc='none', mec=c)
        ax_p.semilogx(fm, phm, 'o', ms=3.5, mfc='none', mec=c)
    m = ev.model
    if m.crossover_hz is not None:
        fc = m.crossover_hz
        pc = m.phase_margin_deg - 180.0
        ax_p.annotate('', xy=(fc, pc), xytext=(fc, pc - m.phase_margin_deg),
                      arrowprops=dict(arrowstyle='<->', color=c, lw=1.5))
        ax_p.text(fc * 1.04, pc - m.phase_margin_deg / 2, f'PM {m.phase_margin_deg:.1f}°',
                  color=c, fontsize=8)
        ax_m.plot([fc], [0.0], 'x', color=c, ms=8)
    if m.phase_crossover_hz is not None:
        fp = m.phase_crossover_hz
        lm = -m.gain_margin_db
        ax_m.annotate('', xy=(fp, 0.0), xytext=(fp, lm),
                      arrowprops=dict(arrowstyle='<->', color=c, lw=1.5))
        ax_m.text(fp * 1.04, lm / 2, f'GM {m.gain_margin_db:.1f} dB', color=c, fontsize=8)
