"""Measuring a servo axis: frequency response, a two-mass model fitted to it, loop margins.

What a drive's or controller's tuning software does with a frequency-response measurement
(Kollmorgen WorkBench's Bode plot and Performance Servo Tuner, Galil's and PMAC's tuning tools),
as library functions on sampled records (numpy arrays, one sample per servo tick):

1. :func:`frequency_response` — the frequency response from the amplifier command u [V] to a
   position y (scipy.signal.welch / csd / coherence, Hann-windowed averaged segments):

   * open loop, G = S_uy / S_uu, with the coherence of u and y;
   * in closed loop with the injected excitation r as instrument, G = S_ry / S_ru. Feedback
     makes u depend on the noise in y, which biases S_uy / S_uu towards −1/C where the noise
     dominates; r is uncorrelated with that noise, so S_ry / S_ru is not biased (the
     "indirect"/"joint input-output" estimate that drives measure with the loop closed).

2. :func:`fit_two_mass` — the two-mass model a motion engineer reads off a Bode plot, fitted by
   scipy.optimize.least_squares on log-magnitude and phase, weighted by coherence, over the
   points of the band whose coherence reaches a threshold. Volts to motor position:

       G_m(s) = K · (1 + 2ζa s/ωa + s²/ωa²) / ( s (s + σ) (1 + 2ζr s/ωr + s²/ωr²) )

   and (optionally, fitted jointly) volts to load position

       G_l(s) = K · (1 + τ s) / ( s (s + σ) (1 + 2ζr s/ωr + s²/ωr²) )

   K: acceleration per volt of the whole axis [m/s² per V]; its inverse is the total inertia
   in volts per m/s² — the acceleration feedforward kaff of a PMAC (Ixx35) or Galil (FA);
   σ: viscous pole (viscous friction / total inertia); ωa, ζa: the anti-resonance (the load
   alone on the screw's spring: ωa² = k / M_load); ωr, ζr: the resonance (ωr² = k (1/M_motor +
   1/M_load)), so the inertia ratio is M_load / M_motor = (ωr/ωa)² − 1 and the split of the
   inertia, the stiffness and the viscous friction follow. τ = screw damping / stiffness.
   With the amplifier's force (or torque) per volt given, the inertias come out in kg (kg·m²).
   The model is evaluated as the servo loop samples it: the zero-order-hold equivalent at the
   servo period (the DAC holds each command for a tick), plus whole ticks of delay.

3. :func:`margins` — gain margin, phase margin and crossovers of an open loop given as a
   sampled frequency response (interpolated on log frequency), optionally with a transport
   delay; :func:`pid_open_loop` builds that open loop for this package's servo law (PMAC PID,
   notch, dual loop) from a measured or fitted plant. The pass marks are Kollmorgen
   WorkBench's Performance Servo Tuner defaults, 45° phase margin and 8 dB gain margin (its
   "stiff" set; 55°/12 dB, 60°/20 dB are its milder ones).

4. The `identify` tool's pieces: :func:`merge` (the runs of a measurement as one response),
   :func:`friction` (Coulomb and viscous friction from constant-velocity runs both ways),
   :func:`physical_units` (the fit in kg, N/V, N/m from one known mass or force constant),
   :func:`doubts` (why a fit would not describe the axis: too little of the band coherent, no
   anti-resonance resolved) and :func:`format_report` (the table it prints). Its Bode plot is
   motion_ctrl.plotting.bode.

Units follow the controller's registers: positions in metres (load-equivalent on the motor
encoder, as `Axis` converts counts), volts, seconds. No rclpy: the excitation runs inside the
servo tick (core.gather), and the identify procedure (motion_ctrl.procedures.identify, run by
the `identify` and `autotune` tools) fetches its records over ROS and hands them to these
functions.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from numpy.lib.stride_tricks import sliding_window_view
from scipy import optimize
from scipy import signal as sps

from motion_ctrl.core.notch import Biquad

__all__ = [
    'FrequencyResponse', 'frequency_response', 'stepped_sine_response',
    'TwoMassModel', 'TwoMassFit', 'fit_two_mass',
    'AntiResonance', 'load_motor_ratio', 'fit_antiresonance', 'fit_two_mass_on_ratio',
    'Margins', 'margins', 'pid_response', 'pid_open_loop',
    'GAIN_MARGIN_DB', 'PHASE_MARGIN_DEG',
    'merge', 'Friction', 'friction', 'Breakaway', 'breakaway', 'STICK_S', 'physical_units',
    'doubts', 'format_report',
    'MIN_COHERENT_FRACTION', 'MIN_INERTIA_RATIO',
]

#: Kollmorgen WorkBench Performance Servo Tuner's default ("stiff") stability targets.
GAIN_MARGIN_DB = 8.0
PHASE_MARGIN_DEG = 45.0

TWO_PI = 2.0 * math.pi
#: fit_two_mass with the anti-resonance held: the motor's points this close to it are left out
HELD_DIP = 0.05
#: stepped_sine_response: DFT bins each side of a sine's own that give the noise around it
NOISE_BINS = 4


# ================================================================================================
# validation

def _record(name, x, n=None) -> np.ndarray:
    try:
        a = np.asarray(x, dtype=float)
    except (TypeError, ValueError):
        raise ValueError(f'{name} must be a sequence of numbers') from None
    if a.ndim != 1:
        raise ValueError(f'{name} must be one-dimensional, got shape {a.shape}')
    if n is not None and a.size != n:
        raise ValueError(f'{name} has {a.size} samples, u has {n}: records must be the same '
                         'length (one sample per servo tick)')
    if not np.all(np.isfinite(a)):
        bad = int(np.flatnonzero(~np.isfinite(a))[0])
        raise ValueError(f'{name} holds a non-finite value at sample {bad}')
    return a


def positive(name, v) -> float:
    """`v` as a float when it is a finite number > 0, else ValueError naming `name`."""
    if isinstance(v, bool) or not isinstance(v, (int, float, np.integer, np.floating)):
        raise ValueError(f'{name} must be a number, got {v!r}')
    v = float(v)
    if not (math.isfinite(v) and v > 0.0):
        raise ValueError(f'{name} must be a finite number > 0, got {v!r}')
    return v


# ================================================================================================
# 1. frequency response

@dataclass
class FrequencyResponse:
    """A measured frequency response: `response[i]` at `freq[i]` Hz, with its coherence (the
    one used to weight and select points; for the instrument estimate the lower of the
    coherences r→u and r→y, both kept in `coherence_ru`, `coherence_ry`)."""
    freq: np.ndarray
    response: np.ndarray
    coherence: np.ndarray
    sample_rate: float
    method: str                      # 'open_loop' | 'instrument' | 'stepped_sine'
    coherence_ru: np.ndarray | None = None
    coherence_ry: np.ndarray | None = None

    def select(self, band=None, min_coherence=0.0) -> np.ndarray:
        """Boolean mask of the points inside `band` (Hz, inclusive) with coherence >=
        min_coherence."""
        m = self.coherence >= min_coherence
        if band is not None:
            lo, hi = band
            m &= (self.freq >= lo) & (self.freq <= hi)
        return m

    def magnitude_db(self) -> np.ndarray:
        return 20.0 * np.log10(np.abs(self.response))

    def phase_deg(self) -> np.ndarray:
        return np.degrees(np.angle(self.response))


def frequency_response(u, y, sample_rate, *, r=None, nperseg=None, noverlap=None,
                       window='hann', detrend='linear', difference=False) -> FrequencyResponse:
    """Estimate the frequency response from u to y, sampled at `sample_rate` Hz.

    Without `r`: G = S_uy / S_uu (open loop: u is the excitation itself), coherence γ²_uy.
    With `r`, the excitation that was injected (closed loop, u = r − C y or u = r + …):
    G = S_ry / S_ru, coherence min(γ²_ru, γ²_ry).

    Spectra by Welch's method (scipy.signal.welch / csd / coherence): segments of `nperseg`
    samples (default: one second, at most a quarter of the record, so at least seven averages
    with the default 50 % overlap), `window`, `detrend` per segment ('linear' by default: a
    position record of a free axis drifts). `difference=True` runs the estimate on the first
    differences of every record — the same filter on input and output leaves G unchanged while
    an integrating plant's drift becomes a stationary velocity; use it when the position wanders
    far over the record. The 0 Hz bin is dropped.
    """
    fs = positive('sample_rate', sample_rate)
    u = _record('u', u)
    y = _record('y', y, u.size)
    if r is not None:
        r = _record('r', r, u.size)
    if difference:
        u, y = np.diff(u), np.diff(y)
        r = None if r is None else np.diff(r)
    n = u.size
    if nperseg is None:
        nperseg = min(int(round(fs)), n // 4)
    if isinstance(nperseg, bool) or not isinstance(nperseg, (int, np.integer)):
        raise ValueError(f'nperseg must be an integer, got {nperseg!r}')
    if not 8 <= nperseg <= n:
        raise ValueError(f'nperseg must be between 8 and the record length {n}, got {nperseg} '
                         f'(record of {n} samples at {fs:g} Hz)')
    kw = dict(fs=fs, window=window, nperseg=int(nperseg), noverlap=noverlap, detrend=detrend)
    with np.errstate(divide='ignore', invalid='ignore'):     # the 0 Hz bin, dropped below
        return _welch_estimate(u, y, r, fs, kw)


def _welch_estimate(u, y, r, fs, kw) -> FrequencyResponse:
    if r is None:
        f, s_uu = sps.welch(u, **kw)
        _, s_uy = sps.csd(u, y, **kw)          # scipy: conj(U)·Y
        _, coh = sps.coherence(u, y, **kw)
        g = s_uy / s_uu
        res = FrequencyResponse(f[1:], g[1:], coh[1:], fs, 'open_loop')
    else:
        f, s_ru = sps.csd(r, u, **kw)
        _, s_ry = sps.csd(r, y, **kw)
        _, c_ru = sps.coherence(r, u, **kw)
        _, c_ry = sps.coherence(r, y, **kw)
        g = s_ry / s_ru
        res = FrequencyResponse(f[1:], g[1:], np.minimum(c_ru, c_ry)[1:], fs, 'instrument',
                                c_ru[1:], c_ry[1:])
    # Bins the excitation does not reach (a PRBS's nulls): no estimate, coherence 0.
    bad = ~(np.isfinite(res.response) & np.isfinite(res.coherence))
    res.response[bad] = np.nan
    res.coherence[bad] = 0.0
    return res


def stepped_sine_response(excitation, u, y, *, difference=True) -> FrequencyResponse:
    """Frequency response of a stepped-sine run (motion_ctrl.core.excitation.stepped_sine).

    For each segment, over its measured window (whole cycles), u and y are each fitted by
    least squares with a sine and cosine at the segment's frequency plus a quadratic drift
    (1, t, t²) — the sine fit of IEEE 1057 — and G is the ratio of the two phasors. In closed
    loop this is already the instrument estimate: only what is coherent with the injected sine
    is kept. With `difference` (default) the fit runs on the first differences of u and y,
    which leaves G unchanged: a free axis' position drifts away (by far more than the sine's
    amplitude, and not as a polynomial) while its velocity only settles.

    `coherence` is, as Welch's coherence with segments of the window's length would give it,
    S / (S + N) at the segment's frequency: S the power of the fitted sine in its DFT bin of
    the window, N the noise in that bin, taken as the mean power of the neighbouring bins of
    what the fit leaves (``NOISE_BINS`` each side); the lower of u's and y's. A small sine is
    coherent when the noise around its frequency is smaller still, however much noise (encoder
    quantisation, friction harmonics) the record holds elsewhere: a stepped sine concentrates
    the excitation where it measures, a broadband signal spreads it.
    """
    segs = getattr(excitation, 'segments', None)
    if not segs:
        raise ValueError('excitation has no stepped-sine segments')
    u = _record('u', u)
    y = _record('y', y, u.size)
    if u.size < segs[-1].stop:
        raise ValueError(f'records of {u.size} samples are shorter than the excitation '
                         f'({segs[-1].stop} ticks)')
    if difference:
        u = np.diff(u, prepend=u[0])
        y = np.diff(y, prepend=y[0])
    fs = excitation.sample_rate
    freq, resp, share = [], [], []
    for s in segs:
        n = s.stop - s.measure_start
        k = np.arange(n)
        t = k / n - 0.5
        wt = 2.0 * np.pi * s.frequency * k / fs
        basis = np.column_stack([np.cos(wt), np.sin(wt), np.ones(n), t, t * t])
        coef, *_ = np.linalg.lstsq(basis, np.column_stack([u[s.measure_start:s.stop],
                                                           y[s.measure_start:s.stop]]),
                                   rcond=None)
        uc = complex(coef[0, 0], -coef[1, 0])      # a cos + b sin = Re[(a − j b) e^{jωt}]
        yc = complex(coef[0, 1], -coef[1, 1])
        freq.append(s.frequency)
        resp.append(yc / uc)
        rest = np.column_stack([u[s.measure_start:s.stop], y[s.measure_start:s.stop]]) \
            - basis @ coef
        spec = np.abs(np.fft.rfft(rest, axis=0)) ** 2
        k0 = s.cycles                               # the sine's bin (whole cycles)
        near = [k for k in range(k0 - NOISE_BINS, k0 + NOISE_BINS + 1)
                if k != k0 and 0 < k < spec.shape[0]]
        noise = spec[near].mean(axis=0)
        sig = (n / 2.0 * np.array([abs(uc), abs(yc)])) ** 2
        with np.errstate(divide='ignore', invalid='ignore'):
            c = np.where(sig > 0, sig / (sig + noise), 0.0)
        share.append(float(c.min()))
    return FrequencyResponse(np.array(freq), np.array(resp), np.array(share), fs,
                             'stepped_sine')


# ================================================================================================
# 2. the two-mass model

@dataclass(frozen=True)
class TwoMassModel:
    """Volts → motor (and load) position of a motor driving a load through a spring.

    accel_per_volt K [m/s² per V], viscous_pole σ [1/s], resonance / antiresonance [Hz] with
    their damping ratios, load_zero τ [s] (screw damping / stiffness, load output only)."""
    accel_per_volt: float
    viscous_pole: float
    resonance_hz: float
    resonance_damping: float
    antiresonance_hz: float
    antiresonance_damping: float
    load_zero: float = 0.0

    def _poles_and_numerator(self, output):
        K, sig = self.accel_per_volt, self.viscous_pole
        wr, zr = TWO_PI * self.resonance_hz, self.resonance_damping
        wa, za = TWO_PI * self.antiresonance_hz, self.antiresonance_damping
        wd = wr * math.sqrt(max(1.0 - zr * zr, 0.0))
        p = np.array([0.0, -sig, complex(-zr * wr, wd), complex(-zr * wr, -wd)])
        if output == 'motor':
            c = K * wr * wr / (wa * wa)
            num = np.array([c, c * 2.0 * za * wa, c * wa * wa])        # K ωr²/ωa² (s² + …)
        elif output == 'load':
            num = np.array([K * wr * wr * self.load_zero, K * wr * wr])
        else:
            raise ValueError(f"output must be 'motor' or 'load', got {output!r}")
        return p, num

    def response(self, freq, *, output='motor', sample_period=None, delay_ticks=0):
        """Complex response at `freq` Hz [m/V].

        With `sample_period` T: the zero-order-hold equivalent at that period,
        Σ r_i (e^{p_i T} − 1)/p_i / (z − e^{p_i T}) over the poles p_i with residues r_i — the
        sample y[n] taken before the command u[n] applies, as in a servo tick, so one tick of
        delay is in it — times z^−delay_ticks. Without: the continuous G(jω) (delay_ticks must
        then be 0)."""
        f = np.asarray(freq, dtype=float)
        p, num = self._poles_and_numerator(output)
        if sample_period is None:
            if delay_ticks:
                raise ValueError('delay_ticks needs sample_period')
            s = 1j * TWO_PI * f
            den = s * (s - p[1]) * (s - p[2]) * (s - p[3])
            return np.polyval(num, s) / den
        T = float(sample_period)
        z = np.exp(1j * TWO_PI * f * T)
        h = np.zeros(f.shape, dtype=complex)
        for i, pi in enumerate(p):
            others = np.delete(p, i)
            res = np.polyval(num, pi) / np.prod(pi - others)
            phi = T if pi == 0 else (np.exp(pi * T) - 1.0) / pi
            h = h + res * phi / (z - np.exp(pi * T))
        return h * z ** (-int(delay_ticks))


@dataclass
class TwoMassFit:
    """The fitted model and what an engineer reads from it.

    Inertias are in the controller's units, volts per m/s² (the acceleration feedforward kaff
    that cancels them); with `force_per_volt` [N/V] given also in kg (`*_mass`). A rotary motor
    measured in load-equivalent metres: J = M · (lead / 2π)²."""
    model: TwoMassModel
    accel_per_volt: float            # K [m/s² per V]
    inertia: float                   # 1/K, total [V·s²/m] (= kaff)
    motor_inertia: float             # [V·s²/m]
    load_inertia: float              # [V·s²/m]
    inertia_ratio: float             # load / motor
    stiffness: float                 # [V/m]
    viscous: float                   # [V per m/s]
    resonance_hz: float
    resonance_damping: float
    antiresonance_hz: float
    antiresonance_damping: float
    band: tuple                      # (low, high) Hz of the points used
    points: int                      # points used (coherence >= threshold, inside the band)
    rms_error_db: float              # magnitude residual, rms over the points used
    rms_error_deg: float             # phase residual, rms
    force_per_volt: float | None = None
    physical: dict = field(default_factory=dict)   # kg, N/m, N·s/m with force_per_volt
    sample_period: float | None = None   # the model is sampled at this period (None: continuous)
    delay_ticks: int = 0                 # whole ticks of delay fitted with

    def response(self, freq, output='motor', extra_delay_ticks=0):
        """The fitted model's response at `freq` Hz [m/V], sampled and delayed as it was
        fitted (plus `extra_delay_ticks`)."""
        return self.model.response(freq, output=output, sample_period=self.sample_period,
                                   delay_ticks=self.delay_ticks + extra_delay_ticks)


def _initial_guess(f, g):
    """Resonance at the peak and anti-resonance at the dip (below it) of |G|·ω², K from the
    plateau below the dip, σ from the low-frequency phase lead of G·(jω)²."""
    w = TWO_PI * f
    acc = g * (1j * w) ** 2
    a = np.abs(acc)
    ir = int(np.argmax(a))
    fr = f[ir]
    below = np.flatnonzero(f < fr)
    if below.size >= 2 and a[below].min() < a[ir] / 2:
        fa = f[below[int(np.argmin(a[below]))]]
    else:
        fa = fr / 1.05
    low = np.flatnonzero(f < fa / 3)
    if low.size < 3:
        low = np.arange(min(3, f.size))
    lowest = low[:3]
    # Below the viscous pole |G|·ω² falls off as ω/σ: the plateau is the largest level.
    K = float(np.median(np.sort(a[low])[-max(3, low.size // 2):]))
    lead = np.angle(acc[lowest])
    sig = float(np.median(w[lowest] * np.tan(np.clip(lead, 0.0, 1.4))))
    return K, max(sig, 1e-2), fr, fa


def fit_two_mass(motor: FrequencyResponse, load: FrequencyResponse | None = None, *,
                 band=None, min_coherence=0.9, delay_ticks=0, sampled=True,
                 force_per_volt=None, log_weight=True, antiresonance=None) -> TwoMassFit:
    """Fit the two-mass model to a measured volts → motor position response (and, if given,
    the volts → load position one, jointly: shared K, σ, resonance).

    Points used: inside `band` (Hz; default all) with coherence >= `min_coherence` (0.9, as
    drive tools grey out the rest). Residuals: natural log of model/measured — its real part
    is the log-magnitude error, its imaginary part the phase error in radians — weighted by
    √(γ²/(1 − γ²)) (the inverse of the estimate's relative scatter) and, with `log_weight`,
    by √(Δf/f) so each decade counts alike. `sampled`: the model is the zero-order-hold
    equivalent at the record's sample period plus `delay_ticks` (as a servo tick measures it;
    False: the continuous model, for a response that is not sampled-data).

    The viscous friction shows only as phase lead near its pole σ (a fraction of a hertz on the
    default slide): the band must reach down to a few times σ/2π for it to mean anything; the
    inertias and the resonances do not need that.

    `antiresonance` (frequency [Hz], damping), when given, is held instead of fitted: the
    anti-resonance located by :func:`fit_antiresonance` from the load/motor ratio, where the
    motor's own response has its dip and measures it worst; the motor's points within
    ``HELD_DIP`` (5 %) of it are then left out (the motor barely moves there, and what the
    encoder reports of it would pull the resonance).
    """
    fpv = None if force_per_volt is None else positive('force_per_volt', force_per_volt)
    held = None
    if antiresonance is not None:
        held = (positive('antiresonance frequency', antiresonance[0]),
                positive('antiresonance damping', antiresonance[1]))
    data = _fit_points(motor, load, band, min_coherence, held, log_weight)
    T = 1.0 / motor.sample_rate if sampled else None
    if not sampled and delay_ticks:
        raise ValueError('delay_ticks applies to a sampled model')
    problem = _TwoMassProblem(data, load is not None, held, T, motor.sample_rate / 2.0,
                              delay_ticks)
    return _read_fit(problem, problem.solve(), force_per_volt, fpv)


def _fit_points(motor, load, band, min_coherence, held, log_weight) -> list:
    """[(output, freq, response, weight)] of the points fit_two_mass uses, motor first: in
    `band` with coherence >= `min_coherence` (the motor's away from a held anti-resonance), at
    least 8 of each; weights √(γ²/(1 − γ²)), with `log_weight` times √(Δf/f), rms 1."""
    sets = [('motor', motor)] + ([('load', load)] if load is not None else [])
    data = []
    for name, fr in sets:
        if not isinstance(fr, FrequencyResponse):
            raise ValueError(f'{name} must be a FrequencyResponse')
        m = fr.select(band, min_coherence)
        if held is not None and name == 'motor':      # the dip the ratio located
            m &= np.abs(fr.freq / held[0] - 1.0) >= HELD_DIP
        if np.count_nonzero(m) < 8:
            raise ValueError(f'{name}: only {np.count_nonzero(m)} points in band {band} have '
                             f'coherence >= {min_coherence:g}; need at least 8 (more '
                             'excitation, a longer record, or a narrower band)')
        f = fr.freq[m]
        coh = np.clip(fr.coherence[m], 0.0, 0.999)
        w = np.sqrt(coh / (1.0 - coh))
        if log_weight:
            df = np.gradient(f) if f.size > 1 else np.ones(1)
            w = w * np.sqrt(np.abs(df) / f)
        w = w / np.sqrt(np.mean(w ** 2))
        data.append((name, f, fr.response[m], w))
    return data


class _TwoMassProblem:
    """fit_two_mass's least-squares problem (scipy.optimize.least_squares, trf): the parameters
    as logs, x = (K, σ, fa, ρ = (fr/fa)² − 1, ζr, ζa and, with the load, τ), fa and ζa left out
    of x when held; residuals the weighted log of model / measured (real: magnitude, imaginary:
    phase) of every point of `data` (_fit_points)."""

    def __init__(self, data, with_load: bool, held, T, nyq: float, delay_ticks):
        self.data, self.with_load, self.held = data, with_load, held
        self.T, self.nyq, self.delay_ticks = T, nyq, delay_ticks
        self.free = np.ones(6 + with_load, dtype=bool)
        self.full = np.zeros(self.free.size)
        if held is not None:                     # fa and ζa held: x has the others only
            self.free[[2, 5]] = False
            self.full[2], self.full[5] = math.log(held[0]), math.log(held[1])
        #: the frequencies [Hz] of the points used, lowest and highest
        self.band = (min(d[1][0] for d in data), max(d[1][-1] for d in data))

    def unpack(self, x) -> TwoMassModel:
        v = self.full.copy()
        v[self.free] = x
        K, sig, fa, rho, zr, za = np.exp(v[:6])
        fr = fa * math.sqrt(1.0 + rho)
        tau = math.exp(v[6]) if self.with_load else 0.0
        return TwoMassModel(K, sig, fr, zr, fa, za, tau)

    def errors(self, mdl: TwoMassModel) -> list:
        """log(model / measured) at each output's points."""
        return [np.log(mdl.response(f, output=name, sample_period=self.T,
                                    delay_ticks=self.delay_ticks) / g)
                for name, f, g, _ in self.data]

    def residuals(self, x):
        mdl = self.unpack(x)
        if self.T is not None and mdl.resonance_hz >= self.nyq:
            return np.full(sum(2 * d[1].size for d in self.data), 1e3)
        out = []
        for (_, _, _, w), e in zip(self.data, self.errors(mdl)):
            out.append(w * e.real)
            out.append(w * e.imag)
        return np.concatenate(out)

    def solve(self) -> TwoMassModel:
        """The model of least cost from three starts (resonance and anti-resonance damping 0.01,
        0.05, 0.2), the rest from the motor's response (_initial_guess), within bounds."""
        held, nyq = self.held, self.nyq
        _, fm, gm, _ = self.data[0]
        K0, sig0, fr0, fa0 = _initial_guess(fm, gm)
        if not fr0 > fa0:
            fa0 = fr0 / 1.05
        lo_f, hi_f = self.band
        lb = [math.log(K0 / 100), math.log(1e-3), math.log(lo_f / 2), math.log(1e-4),
              math.log(1e-4), math.log(1e-4)]
        ub = [math.log(K0 * 100), math.log(TWO_PI * hi_f), math.log(nyq), math.log(1e4),
              math.log(0.95), math.log(0.95)]
        if held is not None:
            fa0 = held[0]
            if not fr0 > fa0 * 1.001:
                fr0 = fa0 * 1.05
        best = None
        for z0 in (0.01, 0.05, 0.2):
            x0 = [math.log(K0), math.log(min(max(sig0, 2e-3), TWO_PI * hi_f / 2)),
                  math.log(fa0), math.log((fr0 / fa0) ** 2 - 1.0), math.log(z0), math.log(z0)]
            lbi, ubi = list(lb), list(ub)
            if self.with_load:
                x0.append(math.log(2 * z0 / (TWO_PI * fa0)))
                lbi.append(math.log(1e-9))
                ubi.append(math.log(1.0))
            if held is not None:
                lbi[2], ubi[2] = self.full[2] - 1.0, self.full[2] + 1.0      # unused: fa is held
                lbi[5], ubi[5] = self.full[5] - 1.0, self.full[5] + 1.0
            free = self.free
            start = np.clip(x0, np.array(lbi) + 1e-9, np.array(ubi) - 1e-9)[free]
            sol = optimize.least_squares(self.residuals, start,
                                         bounds=(np.array(lbi)[free], np.array(ubi)[free]),
                                         x_scale=1.0, method='trf')
            if best is None or sol.cost < best.cost:
                best = sol
        assert best is not None
        return self.unpack(best.x)


def _read_fit(problem: _TwoMassProblem, mdl: TwoMassModel, force_per_volt,
              fpv: float | None) -> TwoMassFit:
    """What an engineer reads from the fitted model: the inertia split by the inertia ratio
    (ωr/ωa)² − 1, the stiffness from the anti-resonance, the viscous friction from its pole, in
    kg and N with the force per volt; the unweighted residuals over the points used."""
    errors = problem.errors(mdl)
    mags = np.concatenate([e.real * 20.0 / math.log(10.0) for e in errors])
    phs = np.concatenate([np.degrees(e.imag) for e in errors])
    K = mdl.accel_per_volt
    rho = (mdl.resonance_hz / mdl.antiresonance_hz) ** 2 - 1.0
    inertia = 1.0 / K
    motor_i = inertia / (1.0 + rho)
    load_i = inertia - motor_i
    stiffness = load_i * (TWO_PI * mdl.antiresonance_hz) ** 2
    viscous = mdl.viscous_pole * inertia
    physical = {}
    if fpv is not None:
        physical = dict(total_mass=inertia * fpv, motor_mass=motor_i * fpv,
                        load_mass=load_i * fpv, stiffness=stiffness * fpv,
                        viscous=viscous * fpv)
    lo_f, hi_f = problem.band
    return TwoMassFit(mdl, K, inertia, motor_i, load_i, rho, stiffness, viscous,
                      mdl.resonance_hz, mdl.resonance_damping, mdl.antiresonance_hz,
                      mdl.antiresonance_damping, (float(lo_f), float(hi_f)), int(mags.size),
                      float(np.sqrt(np.mean(mags ** 2))), float(np.sqrt(np.mean(phs ** 2))),
                      force_per_volt, physical, problem.T, int(problem.delay_ticks))


@dataclass(frozen=True)
class AntiResonance:
    """The anti-resonance located on the load/motor position ratio (:func:`fit_antiresonance`):
    frequency [Hz], damping, the points it rests on, their band [Hz] and the rms residual of
    the ratio's magnitude [dB] and phase [°]."""
    frequency_hz: float
    damping: float
    points: int
    band: tuple
    rms_error_db: float
    rms_error_deg: float


def load_motor_ratio(motor: FrequencyResponse, load: FrequencyResponse) -> FrequencyResponse:
    """X_load / X_motor per frequency, from the volts → motor and volts → load responses of the
    same runs (the excitation and the amplifier cancel), with the lower of the two coherences."""
    if motor.freq.shape != load.freq.shape or not np.allclose(motor.freq, load.freq):
        raise ValueError('motor and load must be measured at the same frequencies')
    with np.errstate(divide='ignore', invalid='ignore'):
        r = load.response / motor.response
    coh = np.minimum(motor.coherence, load.coherence)
    bad = ~np.isfinite(r)
    r = np.where(bad, np.nan, r)
    coh = np.where(bad, 0.0, coh)
    return FrequencyResponse(motor.freq.copy(), r, coh, motor.sample_rate, 'ratio')


def fit_antiresonance(motor: FrequencyResponse, load: FrequencyResponse, model: TwoMassModel,
                      *, band=None, min_coherence=0.9, sampled=True) -> AntiResonance:
    """Locate the anti-resonance on the load/motor position ratio.

    The slide on the screw's spring is X_load / X_motor = (c s + k) / (m_s s² + (c + b) s + k):
    a clean second order whose natural frequency is the anti-resonance ωa² = k / m_s. It needs
    neither the amplifier's gain nor the feedback (both cancel), and it is measured best BELOW
    the anti-resonance, where both encoders move (at 0.75-0.95 ωa its magnitude is 2-10 and
    steep: 1 % on it is ~0.1 % on ωa), while the motor's own response locates ωa by its dip,
    where the motor hardly moves. The inertia split rests on (ωr / ωa)² − 1, which is 0.163 on
    the default slide: 1 % on ωa is 14 % on the split.

    The ratio is fitted as the sampled model gives it, `model`'s load response over its motor
    response (zero-order hold: the motor's aliases do not cancel; resonance and viscous pole
    held from `model`), for ωa, ζa and the screw's damping zero τ, on the points in `band`
    below the resonance where both motor and load reach `min_coherence`; residual: log of
    model / measured (magnitude and phase), unweighted.

    The encoders' quantisation is what limits it (the motion near ωa is a fraction of a count
    on both encoders): see the `identify` tool for how its runs keep that unbiased.
    """
    ratio = load_motor_ratio(motor, load)
    m = ratio.select(band, min_coherence) & (ratio.freq < model.resonance_hz)
    if np.count_nonzero(m) < 3:
        raise ValueError(f'only {np.count_nonzero(m)} points of the load/motor ratio in band '
                         f'{band} below the resonance have coherence >= {min_coherence:g} on '
                         'motor and load; need at least 3')
    f, g = ratio.freq[m], ratio.response[m]
    T = 1.0 / motor.sample_rate if sampled else None

    def model_at(x):
        fa, za, tau = np.exp(x)
        mdl = TwoMassModel(model.accel_per_volt, model.viscous_pole,
                           max(model.resonance_hz, fa * 1.0001), model.resonance_damping,
                           fa, za, tau)
        return mdl.response(f, output='load', sample_period=T) \
            / mdl.response(f, output='motor', sample_period=T)

    def residuals(x):
        e = np.log(model_at(x) / g)
        return np.concatenate([e.real, e.imag])

    lb, ub, fa0 = _antiresonance_start(f, g, model.resonance_hz)
    best = None
    for z0 in (0.005, 0.02, 0.08):
        x0 = np.clip([math.log(fa0), math.log(z0), math.log(2 * z0 / (TWO_PI * fa0))],
                     np.array(lb) + 1e-9, np.array(ub) - 1e-9)
        sol = optimize.least_squares(residuals, x0, bounds=(lb, ub), method='trf')
        if best is None or sol.cost < best.cost:
            best = sol
    assert best is not None
    fa, za, _ = (float(v) for v in np.exp(best.x))
    e = np.log(model_at(best.x) / g)
    return AntiResonance(fa, za, int(f.size), (float(f[0]), float(f[-1])),
                         float(np.sqrt(np.mean((e.real * 20.0 / math.log(10.0)) ** 2))),
                         float(np.sqrt(np.mean(np.degrees(e.imag) ** 2))))


def _antiresonance_start(f, g, resonance_hz: float) -> tuple[list, list, float]:
    """fit_antiresonance's bounds of log (fa, ζa, τ) and its start for fa: from the magnitude
    of each point, |R| ≈ 1 / |1 − (f / fa)²| below fa (points above it, phase near −180°, do
    not give a guess), between the lowest point and the resonance."""
    mag = np.abs(g)
    ok = (mag > 1.05) & (np.abs(np.angle(g)) < math.pi / 2)
    guess = f[ok] / np.sqrt(1.0 - 1.0 / mag[ok]) if np.any(ok) else f * 1.2
    lb = [math.log(f.min()), math.log(1e-4), math.log(1e-8)]
    ub = [math.log(resonance_hz), math.log(0.5), math.log(1e-2)]
    fa0 = float(np.clip(np.median(guess), f.min() * 1.001, resonance_hz * 0.999))
    return lb, ub, fa0


def fit_two_mass_on_ratio(motor: FrequencyResponse, load: FrequencyResponse, *, ratio=None,
                          band=None, ratio_band=None, min_coherence=0.9, delay_ticks=0,
                          force_per_volt=None, iterations=2) -> tuple[TwoMassFit, AntiResonance]:
    """The two-mass fit with its anti-resonance taken from the load/motor ratio: the joint fit
    of `motor` and `load` (:func:`fit_two_mass`), the anti-resonance located on the ratio of
    `ratio` = (motor, load) responses (default: the same ones) over `ratio_band` with that
    fit's poles (:func:`fit_antiresonance`), the joint fit again with it held (gain, resonance,
    damping and viscous pole fitted around it), `iterations` times. Returns (fit,
    anti-resonance)."""
    rm, rl = (motor, load) if ratio is None else ratio
    kw = dict(band=band, min_coherence=min_coherence, delay_ticks=delay_ticks,
              force_per_volt=force_per_volt)
    fit = fit_two_mass(motor, load, **kw)
    ar = None
    for _ in range(max(1, int(iterations))):
        ar = fit_antiresonance(rm, rl, fit.model, band=ratio_band, min_coherence=min_coherence)
        fit = fit_two_mass(motor, load, antiresonance=(ar.frequency_hz, ar.damping), **kw)
    assert ar is not None
    return fit, ar


# ================================================================================================
# 3. margins of an open loop

@dataclass
class Margins:
    """Stability margins of an open loop L (negative feedback: the closed loop is L/(1+L)).

    gain_margin_db: how far the gain may rise, the smallest −20·log10|L| at a phase crossover
    (phase −180° modulo 360°) where |L| < 1 (inf if none); lower_gain_margin_db: how far it may
    fall, the smallest 20·log10|L| at a phase crossover where |L| > 1 (the conditionally stable
    low end of a loop with an integrator and a double-integrating plant; inf if none).
    phase_margin_deg: the smallest 180° + ∠L at a gain crossover (|L| = 1), in (−180, 180];
    crossover_hz: that crossover; delay_margin_s: the smallest added delay that would use the
    phase margin up, PM / ω over the gain crossovers."""
    gain_margin_db: float
    phase_crossover_hz: float | None
    phase_margin_deg: float
    crossover_hz: float | None
    delay_margin_s: float
    lower_gain_margin_db: float = math.inf
    gain_crossovers_hz: list = field(default_factory=list)
    phase_crossovers_hz: list = field(default_factory=list)

    def problems(self, gain_margin_db=GAIN_MARGIN_DB, phase_margin_deg=PHASE_MARGIN_DEG):
        """What falls short of the targets (default: Kollmorgen's 8 dB and 45°), as text."""
        out = []
        if self.crossover_hz is None:
            out.append('no gain crossover in the frequencies given')
        elif self.phase_margin_deg < phase_margin_deg:
            out.append(f'phase margin {self.phase_margin_deg:.1f}° < {phase_margin_deg:g}° at '
                       f'{self.crossover_hz:.1f} Hz')
        if self.gain_margin_db < gain_margin_db:
            out.append(f'gain margin {self.gain_margin_db:.1f} dB < {gain_margin_db:g} dB at '
                       f'{self.phase_crossover_hz:.1f} Hz')
        return out

    def ok(self, gain_margin_db=GAIN_MARGIN_DB, phase_margin_deg=PHASE_MARGIN_DEG) -> bool:
        return not self.problems(gain_margin_db, phase_margin_deg)


def margins(freq, loop, *, delay=0.0) -> Margins:
    """Gain and phase margins of the open loop `loop` (complex, at ascending `freq` Hz),
    with an extra transport `delay` [s] (e.g. one servo tick, 1/rate) multiplied in.

    Crossovers are found between samples and interpolated linearly in log frequency (log
    magnitude, unwrapped phase), as read off a measured Bode plot; the grid should resolve the
    phase (a few points per resonance width). Margins say nothing about an open loop that is
    itself unstable (Nyquist): use them on stable plants, integrators allowed.
    """
    f = _record('freq', freq)
    if f.size < 2:
        raise ValueError('freq needs at least 2 points')
    if not (np.all(f > 0) and np.all(np.diff(f) > 0)):
        raise ValueError('freq must be positive and strictly ascending')
    L = np.asarray(loop, dtype=complex)
    if L.shape != f.shape or not np.all(np.isfinite(L)) or np.any(L == 0):
        raise ValueError('loop must be finite, non-zero and as long as freq')
    d = float(delay)
    if not (math.isfinite(d) and d >= 0.0):
        raise ValueError(f'delay must be a finite number >= 0 s, got {delay!r}')
    L = L * np.exp(-1j * TWO_PI * f * d)
    lf = np.log(f)
    lm = np.log(np.abs(L))
    ph = np.unwrap(np.angle(L))
    gcs = _gain_crossovers(f, lf, lm, ph)
    pcs = _phase_crossovers(lf, lm, ph)
    up = [(g, fp) for fp, g in pcs if g > 0.0]
    down = [(-g, fp) for fp, g in pcs if g <= 0.0]
    gm, fpc = min(up) if up else (math.inf, None)
    lgm = min(down)[0] if down else math.inf
    crossover: float | None
    if gcs:
        pm, crossover = min((p, c) for c, p in gcs)
        dm = min(max(p, 0.0) / 360.0 / c for c, p in gcs)
    else:
        pm, crossover, dm = math.inf, None, math.inf
    return Margins(float(gm), fpc, float(pm), crossover, float(dm), float(lgm),
                   [float(g[0]) for g in gcs], [float(p[0]) for p in pcs])


def _lerp(i, t, arr):
    return arr[i] + t * (arr[i + 1] - arr[i])


def _gain_crossovers(f, lf, lm, ph) -> list:
    """[(frequency, phase margin [°])] where |L| crosses 1 (log magnitude `lm` through 0),
    interpolated in log frequency `lf`, the unwrapped phase `ph` [rad] with it."""
    gcs = []
    for i in range(f.size - 1):
        a, b = lm[i], lm[i + 1]
        if a == 0.0 or (a < 0.0) != (b < 0.0) and b != 0.0:
            t = 0.0 if a == 0.0 else a / (a - b)
            fc = math.exp(_lerp(i, t, lf))
            pm = (math.degrees(_lerp(i, t, ph)) + 180.0) % 360.0
            if pm > 180.0:
                pm -= 360.0
            gcs.append((fc, pm))
    if lm[-1] == 0.0:
        pm = (math.degrees(ph[-1]) + 180.0) % 360.0
        gcs.append((float(f[-1]), pm - 360.0 if pm > 180.0 else pm))
    return gcs


def _phase_crossovers(lf, lm, ph) -> list:
    """[(frequency, gain margin [dB])] where the phase crosses −180° modulo 360°,
    interpolated in log frequency."""
    psi = (ph + math.pi) / TWO_PI                 # integer where the phase is −180° mod 360°
    k = np.floor(psi)
    pcs = []
    for i in range(lf.size - 1):
        if k[i] != k[i + 1]:
            target = max(k[i], k[i + 1])
            t = (target - psi[i]) / (psi[i + 1] - psi[i])
            fp = math.exp(_lerp(i, t, lf))
            pcs.append((fp, -_lerp(i, t, lm) * 20.0 / math.log(10.0)))
    return pcs


def pid_response(freq, *, kp, ki, kd, servo_period, notch=(0.0, 0.0, 0.0, 0.0)):
    """The feedback part of this package's PMAC PID (motion_ctrl.core.servo_law), per tick:

        u = F(z) · [ (kp + ki·T·z/(z − 1)) · (−x_pos) − kd · (1 − z⁻¹)/T · x_vel ]

    (the integrator adds ki·FE·T before the output; velocity is the backward difference of the
    encoder position; F the notch, Ixx36–39, normalised to unity DC gain). Returns
    (P(z), D(z)): the transfer from the position-loop encoder and from the velocity-loop encoder
    to −u [V/m]. Feedforward (kvff, kaff, friction) acts on the command, not on the loop."""
    T = positive('servo_period', servo_period)
    f = np.asarray(freq, dtype=float)
    z = np.exp(1j * TWO_PI * f * T)
    Biquad.validate(*notch)
    n1, n2, d1, d2 = notch
    zi = 1.0 / z
    F = (1.0 + n1 * zi + n2 * zi * zi) / (1.0 + d1 * zi + d2 * zi * zi)
    F = F * (1.0 + d1 + d2) / (1.0 + n1 + n2)
    P = F * (kp + ki * T * z / (z - 1.0))
    D = F * kd * (1.0 - zi) / T
    return P, D


def pid_open_loop(freq, registers, servo_period, position_plant, velocity_plant=None, *,
                  latency_ticks=0):
    """Open loop L(jω), broken at the amplifier input, of this package's PID on a plant given
    as responses [m/V] at `freq` (measured or TwoMassFit.response):

        L = z^−latency · [ P(z) · G_pos + D(z) · G_vel ]

    G_pos: volts → the position-loop encoder, G_vel: volts → the velocity-loop encoder (the
    same for `feedback` motor / load; motor and load for Galil's dual loop DV). `registers`:
    a dict with kp, ki, kd and optionally notch_n1, notch_n2, notch_d1, notch_d2 (the
    controller's register names and units). latency_ticks: whole ticks between the encoder
    sample and the command (1 over DDS, as motion_ctrl.tools.tuning assumes). Feed it to
    :func:`margins`.
    """
    gp = np.asarray(position_plant, dtype=complex)
    gv = gp if velocity_plant is None else np.asarray(velocity_plant, dtype=complex)
    notch = tuple(float(registers.get(k, 0.0)) for k in
                  ('notch_n1', 'notch_n2', 'notch_d1', 'notch_d2'))
    P, D = pid_response(freq, kp=float(registers['kp']), ki=float(registers.get('ki', 0.0)),
                        kd=float(registers.get('kd', 0.0)), servo_period=servo_period,
                        notch=notch)
    z = np.exp(1j * TWO_PI * np.asarray(freq, dtype=float) * servo_period)
    return z ** (-int(latency_ticks)) * (P * gp + D * gv)


# ================================================================================================
# 4. what the identify tool adds

def merge(responses) -> FrequencyResponse:
    """Several measured responses (stepped-sine runs over parts of a band) as one, sorted by
    frequency."""
    rs = list(responses)
    if not rs:
        raise ValueError('merge needs at least one response')
    f = np.concatenate([r.freq for r in rs])
    order = np.argsort(f, kind='stable')
    return FrequencyResponse(f[order], np.concatenate([r.response for r in rs])[order],
                             np.concatenate([r.coherence for r in rs])[order],
                             rs[0].sample_rate, rs[0].method)


@dataclass(frozen=True)
class Friction:
    """V = coulomb·sign(v) + viscous·v + offset, fitted to the mean output [V] of runs at
    constant velocities v [m/s] both ways: coulomb [V], viscous [V per m/s], offset [V] (a
    bias or a load that pulls one way, e.g. gravity), rms_residual [V]."""
    coulomb: float
    viscous: float
    offset: float
    rms_residual: float


def friction(velocities, volts) -> Friction:
    """Coulomb and viscous friction from constant-velocity runs (the mean output of each run at
    its velocity), by least squares; needs both directions, and two speeds for the viscous
    part (with one speed each way viscous is 0 and coulomb holds it)."""
    v = _record('velocities', velocities)
    u = _record('volts', volts, v.size)
    if not (np.any(v > 0) and np.any(v < 0)):
        raise ValueError('friction needs runs in both directions')
    speeds = np.unique(np.round(np.abs(v), 12))
    cols = [np.sign(v), np.ones_like(v)] + ([v] if speeds.size > 1 else [])
    a = np.column_stack(cols)
    coef, *_ = np.linalg.lstsq(a, u, rcond=None)
    res = u - a @ coef
    viscous = float(coef[2]) if speeds.size > 1 else 0.0
    return Friction(float(coef[0]), viscous, float(coef[1]), float(np.sqrt(np.mean(res ** 2))))


#: a creep's stick: the slide still for this long [s] before it breaks away again
STICK_S = 0.02


@dataclass(frozen=True)
class Breakaway:
    """The breakaway friction of one direction from a creep (a jog slow enough that the slide
    sticks and slips): `breakaway` [V], the median over the slips of the output's peak in the
    10 samples before the slide broke away after a stick of STICK_S or more (None: the slide
    crept without sticking, its breakaway not above its sliding friction); `slips` how many
    stuck and broke away; `creep` [V] the mean output over the creep."""
    breakaway: float | None
    slips: int
    creep: float


def breakaway(t, position, output, counts_per_m: float) -> Breakaway:
    """Breakaway friction from a creep's samples (stamps [s], slide position [m], output [V]);
    the direction is the creep's (the sign of the slide's travel). The output is taken as its
    5-sample median: one servo tick's kick of kd on a motor count is not a push."""
    t = np.asarray(t, dtype=float)
    reading = np.round(np.asarray(position, dtype=float) * positive('counts_per_m',
                                                                      counts_per_m))
    u = np.asarray(output, dtype=float)
    if t.size < 10 or t.size != reading.size or t.size != u.size:
        raise ValueError('breakaway needs at least 10 samples of equal length')
    sign = 1.0 if reading[-1] >= reading[0] else -1.0
    if u.size >= 5:
        u = np.concatenate([u[:2], np.median(sliding_window_view(u, 5), axis=1), u[-2:]])
    moved = np.flatnonzero(sign * np.diff(reading) > 0) + 1
    peaks = [sign * float(np.max(sign * u[max(a, b - 10):b]))
             for a, b in zip(moved[:-1], moved[1:]) if t[b] - t[a] >= STICK_S]
    creep = float(np.mean(u[u.size // 4:]))
    return Breakaway(float(np.median(peaks)) if peaks else None, len(peaks), creep)


#: the share of the band measured coherently below which a fit is not reported as a model
MIN_COHERENT_FRACTION = 0.6
#: a slide/motor inertia ratio below this means no anti-resonance was resolved
MIN_INERTIA_RATIO = 0.01


def doubts(fit: TwoMassFit, coherent_fraction: float) -> list[str]:
    """Why a fit does not describe the axis it was measured on ([] when nothing stands out): too
    little of the band measured coherently for the fit to rest on (a machine whose servo ticks
    are not evenly spaced smears a sine's phase: on this project's 2-core VM in real time, 21-33
    % of the default band), or no anti-resonance below the resonance (the fit merged the two:
    slide/motor inertia ratio ~0, and every mass from it meaningless)."""
    out = []
    if not coherent_fraction >= MIN_COHERENT_FRACTION:
        out.append(f'only {coherent_fraction * 100:.0f} % of the band measured with coherence '
                   f'>= 0.9 (at least {MIN_COHERENT_FRACTION * 100:.0f} % needed)')
    if not fit.inertia_ratio >= MIN_INERTIA_RATIO:
        out.append(f'no anti-resonance resolved below the resonance (slide/motor inertia '
                   f'ratio {fit.inertia_ratio:.3g})')
    return out


def physical_units(fit: TwoMassFit, *, slide_mass=None, force_per_volt=None) -> dict:
    """The fit in SI units from ONE absolute reference. The measurement sees only ratios (every
    mass, the stiffness, the friction and the force per volt scaled alike give the same
    response): `slide_mass` [kg] (weighed, or from CAD) gives the force per volt as
    slide_mass / load_inertia, `force_per_volt` [N/V] (amplifier A/V × motor Kt × 2π / lead,
    from the data sheets) gives the masses. Returns force_per_volt [N/V], motor_mass and
    slide_mass [kg] (the motor's inertia as a mass at the slide), stiffness [N/m],
    viscous [N·s/m] (two-mass fit; its pole must be in the band to mean anything)."""
    if (slide_mass is None) == (force_per_volt is None):
        raise ValueError('give exactly one of slide_mass and force_per_volt')
    if slide_mass is not None:
        fpv = positive('slide_mass', slide_mass) / fit.load_inertia
    else:
        fpv = positive('force_per_volt', force_per_volt)
    return dict(force_per_volt=fpv, motor_mass=fit.motor_inertia * fpv,
                slide_mass=fit.load_inertia * fpv, total_mass=fit.inertia * fpv,
                stiffness=fit.stiffness * fpv, viscous=fit.viscous * fpv)


def format_report(r: dict, ref: dict, min_coherence: float = 0.9) -> str:
    """identify's report (printed and report.md): its result `r` (identify.yaml's keys) as a
    Markdown table of quantity, value, unit, note, and the fit's points, coherence and
    residual; `ref` the absolute reference given ({'slide_mass': kg} or {'force_per_volt':
    N/V}, or {}), `min_coherence` the fit's."""
    rows = [('resonance', f'{r["resonance_hz"]:.1f}', 'Hz',
             f'damping {r["resonance_damping"]:.3f}'),
            ('anti-resonance', f'{r["antiresonance_hz"]:.1f}', 'Hz',
             f'damping {r["antiresonance_damping"]:.3f}'
             + (f'; load/motor ratio, {r["ratio_points"]} points'
                if r.get('ratio_points') else '')),
            ('total inertia (kaff)', f'{r["inertia"]:.4f}', 'V·s²/m',
             f'{r["accel_per_volt"]:.3f} m/s² per V'),
            ('motor-side inertia', f'{r["motor_inertia"]:.4f}', 'V·s²/m', ''),
            ('slide inertia', f'{r["load_inertia"]:.4f}', 'V·s²/m',
             f'ratio slide/motor {r["inertia_ratio"]:.3f}'),
            ('stiffness', f'{r["stiffness"]:.4g}', 'V/m', ''),
            ('Coulomb friction', f'{r["coulomb"]:.4f}', 'V',
             f'jogs both ways: +{r["coulomb_pos"]:.4f} / -{r["coulomb_neg"]:.4f}'),
            ('viscous friction', f'{r["viscous"]:.4f}', 'V·s/m', 'jogs at two speeds')]
    if 'breakaway_pos' in r:
        creep = f'creep at ±{r["creep_velocity"] * 1e3:g} mm/s'
        rows.append(('breakaway friction', f'+{r["breakaway_pos"]:.4f} / '
                     f'-{r["breakaway_neg"]:.4f}', 'V', (
                         f'{creep}: the output before the slide broke away, '
                         f'{r["stick_slips_pos"]} / {r["stick_slips_neg"]} slips')
                     if r['stick_slips_pos'] or r['stick_slips_neg'] else
                     f'{creep}: the slide crept without sticking (= Coulomb)'))
    rows.append(('delay', f'{r["delay_ticks"]}', 'ticks', 'best fit'))
    if 'force_per_volt' in r:
        how = ('from --slide-mass' if 'slide_mass' in ref else 'given (--force-per-volt)')
        rows += [('amplifier force per volt', f'{r["force_per_volt"]:.3f}', 'N/V', how),
                 ('motor-side inertia', f'{r["motor_mass"]:.3f}', 'kg', 'as a mass at the slide'),
                 ('slide mass', f'{r["slide_mass"]:.3f}', 'kg', ''),
                 ('stiffness', f'{r["stiffness_n_per_m"]:.4g}', 'N/m', ''),
                 ('Coulomb friction', f'{r["coulomb_n"]:.3f}', 'N', ''),
                 ('viscous friction', f'{r["viscous_n_s_per_m"]:.2f}', 'N·s/m', '')]
        if 'motor_inertia_kg_m2' in r:
            rows.append(('motor inertia', f'{r["motor_inertia_kg_m2"]:.4g}', 'kg·m²',
                         'with --lead'))
        if 'amplifier_gain' in r:
            rows.append(('amplifier gain', f'{r["amplifier_gain"]:.4f}', 'A/V',
                         'with --torque-constant'))
    lines = ['| quantity | value | unit | note |', '|---|---:|---|---|']
    lines += [f'| {a} | {b} | {c} | {d} |' for a, b, c, d in rows]
    lines.append(f'\nfit over {r["points"]} points (motor and load) with coherence >= '
                 f'{min_coherence:g} in {r["band"][0]:g}-{r["band"][1]:g} Hz; '
                 f'{r["coherent_fraction"] * 100:.0f} % of the {r["frequencies"]} frequencies '
                 f'measured coherently on motor or load (lowest of the better one '
                 f'{r["coherence_min"]:.3f}); residual {r["rms_error_db"]:.2f} dB, '
                 f'{r["rms_error_deg"]:.1f}° rms')
    return '\n'.join(lines)
