"""Test signals for measuring a servo axis: log chirp, PRBS and stepped sine, tick-exact.

The signals a drive's or a motion controller's frequency-response tool injects into the loop
(Kollmorgen WorkBench's "Bode plot" with its PRBS and sine-sweep excitation, Galil's and PMAC's
sine-sweep tuning tools): an amplitude in volts at the amplifier input (or added to the servo
output in closed loop), a band in Hz, a duration, and the servo rate.

Every signal is a plain array with one value per servo tick: sample n is the value at
t = n / sample_rate, n = 0 .. round(duration · sample_rate) − 1. Nothing depends on a clock, so
a servo tick reads `excitation.at(tick)` and two runs inject exactly the same volts.

* :func:`log_chirp` — a logarithmic sine sweep (as ``scipy.signal.chirp(method='logarithmic')``):
  equal time per decade; optional amplitude shaping ∝ f^amplitude_exponent (−1: the 1/f shaping
  that keeps a rigid axis' velocity-level response even; +1 or +2: less displacement at the low
  end of a position measurement).
* :func:`prbs` — a maximum-length pseudo-random binary sequence (as ``scipy.signal.max_len_seq``)
  of ±amplitude, each bit held `hold_ticks` servo ticks: flat spectrum up to ~0.44 · rate /
  hold_ticks, one period long enough for the band's low end. Periodic: averaging over whole
  periods (Welch with nperseg = period_ticks) has no leakage.
* :func:`stepped_sine` — one sine per frequency, log-spaced over the band, each with a settling
  part (faded in, then discarded by the analysis) and a measured window holding a whole number
  of cycles (the frequency is moved to that bin).

Library functions, no rclpy: an axis injects them in its servo tick (`Axis.excite`,
motion_ctrl.core.gather); :func:`from_registers` builds the one an axis's `excitation_*`
registers describe (the controller's `<axis>/excite` service).

The chirp and the sequence are scipy.signal's, computed here with numpy from the same formula
and the same taps (test_excitation compares them with scipy's, value for value): importing
scipy.signal takes ~1.6 s, which the controller paid at every start for two short functions.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

__all__ = ['Excitation', 'Segment', 'log_chirp', 'prbs', 'stepped_sine', 'from_registers',
           'PRBS_BAND_FRACTION', 'SIGNALS']

#: Taps of the maximum-length shift register per number of bits (scipy.signal.max_len_seq's:
#: the first listed for each length by newwaveinstruments.com's m-sequence table).
MLS_TAPS = {2: (1,), 3: (2,), 4: (3,), 5: (3,), 6: (5,), 7: (6,), 8: (7, 6, 1), 9: (5,),
            10: (7,), 11: (9,), 12: (11, 10, 4), 13: (12, 11, 8), 14: (13, 12, 2), 15: (14,),
            16: (15, 13, 4), 17: (14,), 18: (11,), 19: (18, 17, 14), 20: (17,), 21: (19,),
            22: (21,), 23: (18,), 24: (23, 22, 17), 25: (22,), 26: (25, 24, 20),
            27: (26, 25, 22), 28: (25,), 29: (27,), 30: (29, 28, 7), 31: (28,),
            32: (31, 30, 10)}

#: A PRBS held N ticks is flat to within 3 dB up to this fraction of rate / N
#: (|sin(π f N / fs) / (N sin(π f / fs))|² = ½ at f ≈ 0.443 fs / N).
PRBS_BAND_FRACTION = 0.443


@dataclass(frozen=True)
class Segment:
    """One frequency of a stepped sine: ticks [start, stop) are the segment, of which
    [measure_start, stop) is the measured window (a whole number of `cycles` at `frequency`)."""
    frequency: float
    start: int
    measure_start: int
    stop: int
    cycles: int


@dataclass
class Excitation:
    """A test signal, one value per servo tick [V]."""
    kind: str
    signal: np.ndarray
    sample_rate: float
    amplitude: float
    band: tuple
    period_ticks: int | None = None     # PRBS: ticks in one period of the sequence
    hold_ticks: int | None = None       # PRBS: ticks each bit is held
    segments: list = field(default_factory=list)   # stepped sine

    @property
    def ticks(self) -> int:
        return len(self.signal)

    @property
    def duration(self) -> float:
        return self.ticks / self.sample_rate

    @property
    def times(self) -> np.ndarray:
        """t = n / sample_rate of each sample [s]."""
        return np.arange(self.ticks) / self.sample_rate

    def at(self, tick: int) -> float:
        """The value for servo tick `tick` (0 before the start and after the end)."""
        if 0 <= tick < len(self.signal):
            return float(self.signal[tick])
        return 0.0


# -- validation -------------------------------------------------------------------------------

def _finite(name, value, *, positive=False, nonnegative=False) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float, np.integer, np.floating)):
        raise ValueError(f'{name} must be a number, got {value!r}')
    v = float(value)
    if not math.isfinite(v):
        raise ValueError(f'{name} must be finite, got {v!r}')
    if positive and not v > 0.0:
        raise ValueError(f'{name} must be > 0, got {v!r}')
    if nonnegative and not v >= 0.0:
        raise ValueError(f'{name} must be >= 0, got {v!r}')
    return v


def _int(name, value, minimum) -> int:
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)):
        raise ValueError(f'{name} must be an integer, got {value!r}')
    if value < minimum:
        raise ValueError(f'{name} must be >= {minimum}, got {value!r}')
    return int(value)


def _common(amplitude, band, duration, sample_rate, *, nyquist_ok):
    """Validated (amplitude, f_lo, f_hi, duration, sample_rate, ticks)."""
    fs = _finite('sample_rate', sample_rate, positive=True)
    amp = _finite('amplitude', amplitude, positive=True)
    try:
        lo, hi = band
    except (TypeError, ValueError):
        raise ValueError(f'band must be a pair (low Hz, high Hz), got {band!r}') from None
    lo = _finite('band low', lo, positive=True)
    hi = _finite('band high', hi, positive=True)
    if not hi > lo:
        raise ValueError(f'band high ({hi:g} Hz) must be above band low ({lo:g} Hz)')
    nyq = fs / 2.0
    if hi > nyq or (hi == nyq and not nyquist_ok):
        raise ValueError(f'band high {hi:g} Hz is {"above" if hi > nyq else "at"} the Nyquist '
                         f'frequency {nyq:g} Hz of the {fs:g} Hz sample_rate')
    dur = _finite('duration', duration, positive=True)
    ticks = int(round(dur * fs))
    if ticks < 2:
        raise ValueError(f'duration {dur:g} s is less than 2 ticks at {fs:g} Hz')
    return amp, lo, hi, dur, fs, ticks


def _shape(freq, amplitude, exponent, lo, hi):
    """amplitude · (f / f_peak)^exponent, the largest value being `amplitude`."""
    if exponent == 0.0:
        return np.full_like(np.asarray(freq, dtype=float), amplitude)
    ref = hi if exponent > 0.0 else lo
    return amplitude * (np.asarray(freq, dtype=float) / ref) ** exponent


# -- signals ----------------------------------------------------------------------------------

def log_chirp(amplitude, band, duration, sample_rate, *, amplitude_exponent=0.0) -> Excitation:
    """Logarithmic sine sweep from band[0] to band[1] Hz over `duration` s.

    The instantaneous frequency is f(t) = f0 · (f1/f0)^(t/duration) (scipy.signal.chirp,
    method='logarithmic', phase chosen so the sweep starts at 0 V). Its amplitude is
    amplitude · (f(t)/f_ref)^amplitude_exponent, f_ref being the band end where that is largest
    (so `amplitude` is the peak): 0 = constant, −1 = 1/f shaping. A log sweep spends equal
    time per decade, so its power spectral density falls as 1/f at constant amplitude.
    """
    amp, lo, hi, dur, fs, n = _common(amplitude, band, duration, sample_rate, nyquist_ok=False)
    p = _finite('amplitude_exponent', amplitude_exponent)
    if dur < 1.0 / lo:
        raise ValueError(f'duration {dur:g} s must hold at least one cycle of the band low end '
                         f'({1.0 / lo:g} s at {lo:g} Hz)')
    t = np.arange(n) / fs
    sweep = n / fs      # the sweep's own length: exactly the ticks generated
    freq = lo * (hi / lo) ** (t / sweep)
    # the phase is the integral of 2π f(t); cos(phase − 90°) starts at 0 V
    phase = 2.0 * np.pi * sweep / math.log(hi / lo) * lo * ((hi / lo) ** (t / sweep) - 1.0)
    wave = np.cos(phase + np.deg2rad(-90.0))
    return Excitation('log_chirp', _shape(freq, amp, p, lo, hi) * wave, fs, amp, (lo, hi))


def prbs(amplitude, band, duration, sample_rate, *, hold_ticks=None, nbits=None) -> Excitation:
    """Maximum-length binary sequence of ±amplitude (scipy.signal.max_len_seq).

    Each bit is held `hold_ticks` ticks (default: the largest hold that keeps band[1] inside
    the −3 dB band, 0.443 · rate / hold); the sequence has 2^nbits − 1 bits (default: the
    fewest whose period, (2^nbits − 1) · hold_ticks ticks, lasts at least 1 / band[0], so the
    frequency resolution of one period reaches the band's low end). The sequence repeats to
    fill round(duration · rate) ticks; a duration of whole periods (`period_ticks`) suits
    period-synchronous averaging.
    """
    amp, lo, hi, dur, fs, n = _common(amplitude, band, duration, sample_rate, nyquist_ok=True)
    if hold_ticks is None:
        hold = max(1, int(math.floor(PRBS_BAND_FRACTION * fs / hi)))
    else:
        hold = _int('hold_ticks', hold_ticks, 1)
        if hold > 1 and hi > PRBS_BAND_FRACTION * fs / hold:
            raise ValueError(f'hold_ticks {hold} gives a band up to '
                             f'{PRBS_BAND_FRACTION * fs / hold:g} Hz, below band high {hi:g} Hz')
    if nbits is None:
        need = math.ceil(fs / lo / hold)          # bits in one period of 1 / f_lo
        nbits = max(2, math.ceil(math.log2(need + 1)))
        if nbits > 32:
            raise ValueError(f'band low {lo:g} Hz needs a sequence of more than 2^32 bits')
    else:
        nbits = _int('nbits', nbits, 2)
        if nbits > 32:
            raise ValueError(f'nbits must be <= 32, got {nbits}')
    seq = max_len_seq(nbits).astype(float) * 2.0 - 1.0
    period = seq.size * hold
    if period > n:
        raise ValueError(f'duration {dur:g} s is shorter than one PRBS period '
                         f'({period / fs:g} s: {seq.size} bits of {hold} ticks)')
    one = np.repeat(seq, hold)
    wave = np.resize(one, n) * amp
    return Excitation('prbs', wave, fs, amp, (lo, hi), period_ticks=period, hold_ticks=hold)


def max_len_seq(nbits: int) -> np.ndarray:
    """The 2^nbits − 1 bits (0/1) of the maximum-length sequence from a shift register of ones
    with the taps MLS_TAPS (scipy.signal.max_len_seq(nbits)[0]): bit k + nbits is bit k
    exclusive-or the bits k + tap."""
    taps = MLS_TAPS[nbits]
    n = (1 << nbits) - 1
    bits = bytearray(n + nbits)
    bits[:nbits] = b'\x01' * nbits
    for k in range(n):
        b = bits[k]
        for tap in taps:
            b ^= bits[k + tap]
        bits[k + nbits] = b
    return np.frombuffer(bytes(bits[:n]), dtype=np.uint8)


def stepped_sine(amplitude, band, duration, sample_rate, *, points=20, settle_cycles=3,
                 amplitude_exponent=0.0) -> Excitation:
    """One sine per frequency, `points` frequencies log-spaced over the band, `duration` shared
    equally among them.

    Each segment starts with a settling part of at least `settle_cycles` cycles (its first half
    faded in with a raised cosine, so the axis is not kicked) and ends with the measured window:
    a whole number of cycles, the frequency moved to cycles · rate / window ticks (listed in
    `segments`). Amplitude shaping as in :func:`log_chirp`.
    """
    amp, lo, hi, dur, fs, n = _common(amplitude, band, duration, sample_rate, nyquist_ok=False)
    pts = _int('points', points, 1)
    settle = _finite('settle_cycles', settle_cycles, nonnegative=True)
    p = _finite('amplitude_exponent', amplitude_exponent)
    freqs = np.geomspace(lo, hi, pts) if pts > 1 else np.array([math.sqrt(lo * hi)])
    dwell = n // pts
    wave = np.zeros(n)
    segments = []
    for i, f in enumerate(freqs):
        fa = f
        for _ in range(3):     # settle at least settle_cycles of the frequency actually used
            s = int(math.ceil(settle * fs / min(f, fa)))
            m = dwell - s
            if m < fs / f:
                raise ValueError(
                    f'duration {dur:g} s is too short: {pts} points leave {dwell / fs:g} s per '
                    f'frequency, and {f:.4g} Hz needs {(s + math.ceil(fs / f)) / fs:g} s '
                    f'({settle:g} settling cycles and one measured cycle)')
            cycles = max(1, int(round(f * m / fs)))
            if cycles * fs / m >= fs / 2.0:
                cycles -= 1
            fa = cycles * fs / m
            if s >= settle * fs / fa:
                break
        start = i * dwell
        k = np.arange(-s, m)
        env = np.ones(s + m)
        ramp = s // 2
        if ramp > 0:
            env[:ramp] = 0.5 - 0.5 * np.cos(np.pi * np.arange(ramp) / ramp)
        a = float(_shape(fa, amp, p, lo, hi))
        wave[start:start + s + m] = a * env * np.sin(2.0 * np.pi * fa * k / fs)
        segments.append(Segment(fa, start, start + s, start + s + m, cycles))
    return Excitation('stepped_sine', wave, fs, amp, (lo, hi), segments=segments)


#: excitation_signal register value -> the signal's function
SIGNALS: dict = {'prbs': prbs, 'chirp': log_chirp, 'stepped_sine': stepped_sine}


def from_registers(values: dict, sample_rate: float) -> Excitation:
    """The test signal an axis's registers describe (excitation_signal, _amplitude,
    _band_low, _band_high, _duration, _points) at the servo rate; ValueError naming the register and
    what is wrong (a band above the Nyquist frequency, a duration too short for the band)."""
    kind = values['excitation_signal']
    if kind not in SIGNALS:
        raise ValueError(f'excitation_signal: unknown signal {kind!r}, expected one of '
                         f'{", ".join(SIGNALS)}')
    extra = {'points': values['excitation_points']} if kind == 'stepped_sine' else {}
    try:
        return SIGNALS[kind](values['excitation_amplitude'],
                             (values['excitation_band_low'], values['excitation_band_high']),
                             values['excitation_duration'], sample_rate, **extra)
    except ValueError as e:
        raise ValueError(f'excitation_* registers ({kind}): {e}') from None
