"""identify's Bode plot (bode.png): the measured responses volts -> motor and load position, the
fitted two-mass model over them and the coherence, as Kollmorgen WorkBench's Bode plot shows a
measurement; with the load/motor ratio runs, a fourth panel of |X_load / X_motor|. The numbers
are analysis.identify's (FrequencyResponse, TwoMassFit)."""
from __future__ import annotations

import numpy as np
from matplotlib.figure import Figure

from motion_ctrl.analysis.identify import FrequencyResponse, TwoMassFit


def _lagging(deg):
    """Phase in (−360°, 0]: a position response lags (−180° for a double integrator)."""
    return np.where(deg > 0.0, deg - 360.0, deg)


def plot_bode(path, motor: FrequencyResponse, load: FrequencyResponse | None,
              fit: TwoMassFit | None, *, title: str = '', min_coherence: float = 0.9,
              ratio: FrequencyResponse | None = None) -> None:
    """Bode plot (magnitude, phase, coherence) of the measured responses [m/V], the fitted
    model over them, points below `min_coherence` drawn hollow (the fit leaves them out); with
    `ratio` (analysis.identify.load_motor_ratio of the runs that located the anti-resonance) a
    fourth panel: |X_load / X_motor| measured and the model's."""
    fig = Figure(figsize=(9, 9) if ratio is None else (9, 11))
    if ratio is None:
        ax_m, ax_p, ax_c = fig.subplots(3, 1, sharex=True,
                                        gridspec_kw=dict(height_ratios=[3, 2, 1]))
    else:
        ax_m, ax_p, ax_c, ax_r = fig.subplots(4, 1, sharex=True,
                                              gridspec_kw=dict(height_ratios=[3, 2, 1, 2]))
        _ratio_panel(ax_r, ratio, fit, min_coherence)
    sets = [('motor', motor, 'C0')] + ([('load', load, 'C1')] if load is not None else [])
    for name, fr, colour in sets:
        _response(ax_m, ax_p, ax_c, name, fr, colour, fit, min_coherence)
    if fit is not None:
        for ax in (ax_m, ax_p):
            ax.axvline(fit.resonance_hz, color='k', ls=':', lw=0.8)
            ax.axvline(fit.antiresonance_hz, color='grey', ls=':', lw=0.8)
        ax_m.set_title(f'{title}\nresonance {fit.resonance_hz:.1f} Hz, anti-resonance '
                       f'{fit.antiresonance_hz:.1f} Hz' if title else
                       f'resonance {fit.resonance_hz:.1f} Hz')
    ax_m.set_ylabel('|G| [dB re 1 m/V]')
    ax_m.legend(fontsize=8)
    ax_p.set_ylabel('phase [°]')
    ax_p.set_ylim(-370, 10)
    ax_p.set_yticks([-360, -270, -180, -90, 0])
    ax_c.axhline(min_coherence, color='r', lw=0.8, ls='--')
    ax_c.set_ylabel('coherence')
    ax_c.set_ylim(0, 1.05)
    (ax_c if ratio is None else ax_r).set_xlabel('frequency [Hz]')
    ax_c.legend(fontsize=8)
    for ax in (ax_m, ax_p, ax_c):
        ax.grid(True, which='both', alpha=0.3)
    fig.tight_layout()
    fig.savefig(path, dpi=110)


def _response(ax_m, ax_p, ax_c, name: str, fr: FrequencyResponse, colour: str,
              fit: TwoMassFit | None, min_coherence: float) -> None:
    """One measured response (motor or load): magnitude and phase, coherent points filled, its
    coherence, and the fitted model's line over its frequencies."""
    good = fr.coherence >= min_coherence
    for mask, face in ((good, colour), (~good, 'none')):
        ax_m.semilogx(fr.freq[mask], fr.magnitude_db()[mask], 'o', ms=4, mfc=face,
                      mec=colour, label=f'{name}, measured' if face != 'none' else None)
        ax_p.semilogx(fr.freq[mask], _lagging(fr.phase_deg()[mask]), 'o', ms=4,
                      mfc=face, mec=colour)
    ax_c.semilogx(fr.freq, fr.coherence, 'o-', ms=3, color=colour, label=name)
    if fit is not None:
        f = np.geomspace(fr.freq.min(), fr.freq.max(), 800)
        h = fit.response(f, output=name)
        ax_m.semilogx(f, 20 * np.log10(np.abs(h)), '-', color=colour, lw=1,
                      label=f'{name}, two-mass fit')
        ax_p.semilogx(f, _lagging(np.degrees(np.angle(h))), '-', color=colour, lw=1)


def _ratio_panel(ax_r, ratio: FrequencyResponse, fit: TwoMassFit | None,
                 min_coherence: float) -> None:
    """|X_load / X_motor| of the ratio runs, coherent points filled, and the model's ratio up
    to the resonance, the anti-resonance marked."""
    good = ratio.coherence >= min_coherence
    for mask, face in ((good, 'C2'), (~good, 'none')):
        ax_r.semilogx(ratio.freq[mask], np.abs(ratio.response[mask]), 'o', ms=4, mfc=face,
                      mec='C2', label='measured' if face != 'none' else None)
    if fit is not None:
        f = np.geomspace(ratio.freq.min() * 0.8, fit.resonance_hz, 400)
        ax_r.semilogx(f, np.abs(fit.response(f, output='load') / fit.response(f)), '-',
                      color='C2', lw=1, label='two-mass model')
        ax_r.axvline(fit.antiresonance_hz, color='grey', ls=':', lw=0.8)
    ax_r.set_yscale('log')
    ax_r.set_ylabel('|X_load / X_motor|')
    ax_r.legend(fontsize=8)
    ax_r.grid(True, which='both', alpha=0.3)
