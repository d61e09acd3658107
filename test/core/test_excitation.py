"""motion_ctrl.core.excitation: test signals, tick-exact, with their band and validation."""
import math

import numpy as np
import pytest
from scipy import signal as sps

from motion_ctrl.core import excitation as ex

FS = 1000.0


def _band_share(x, fs, lo, hi, nperseg=None):
    """Share of the signal's power between lo and hi Hz."""
    f, p = sps.welch(x, fs, nperseg=nperseg or min(x.size, 2048))
    inside = (f >= lo) & (f <= hi)
    return p[inside].sum() / p.sum()


def test_the_chirp_and_the_sequence_are_scipys():
    """Computed with numpy (scipy.signal's import would cost the controller's start 1.6 s), they
    are scipy.signal's chirp and max_len_seq, value for value."""
    for band, duration in (((5.0, 300.0), 4.0), ((2.0, 200.0), 5.0), ((0.5, 499.0), 2.0)):
        n = round(duration * FS)
        t = np.arange(n) / FS
        ref = sps.chirp(t, f0=band[0], t1=n / FS, f1=band[1], method='logarithmic', phi=-90.0)
        np.testing.assert_allclose(ex.log_chirp(1.0, band, duration, FS).signal, ref,
                                   rtol=0, atol=1e-9)
    for nbits in range(2, 17):
        np.testing.assert_array_equal(ex.max_len_seq(nbits), sps.max_len_seq(nbits)[0])
    assert set(ex.MLS_TAPS) == set(range(2, 33))


def test_log_chirp_is_tick_exact_starts_at_zero_and_stays_in_band():
    c = ex.log_chirp(2.0, (5.0, 300.0), 4.0, FS)
    assert c.kind == 'log_chirp' and c.ticks == 4000 and c.duration == 4.0
    assert c.signal[0] == pytest.approx(0.0, abs=1e-12)        # no step at the start
    assert np.max(np.abs(c.signal)) <= 2.0 + 1e-12
    assert np.max(np.abs(c.signal)) > 1.99
    # Sample n is the value at n / rate: the same as scipy's chirp on that time base.
    t = np.arange(4000) / FS
    ref = 2.0 * sps.chirp(t, 5.0, 4.0, 300.0, method='logarithmic', phi=-90)
    np.testing.assert_allclose(c.signal, ref, atol=1e-12)
    assert c.at(1234) == c.signal[1234] and c.at(-1) == 0.0 and c.at(4000) == 0.0
    assert _band_share(c.signal, FS, 4.0, 320.0) > 0.99
    # Logarithmic: the instantaneous frequency (from zero crossings) doubles in equal times.
    half = c.signal[:2000], c.signal[2000:]
    f_mid = 5.0 * (300.0 / 5.0) ** 0.5
    crossings = [np.count_nonzero(np.diff(np.signbit(h))) for h in half]
    # cycles in each half: ∫ f dt = (f_end − f_start) · T_half / ln(f_end / f_start)
    expect = [(f_mid - 5.0) * 2.0 / math.log(f_mid / 5.0),
              (300.0 - f_mid) * 2.0 / math.log(300.0 / f_mid)]
    for n, e in zip(crossings, expect):
        assert n / 2 == pytest.approx(e, rel=0.02)


def test_log_chirp_one_over_f_shaping():
    c = ex.log_chirp(1.0, (2.0, 200.0), 5.0, FS, amplitude_exponent=-1.0)
    flat = ex.log_chirp(1.0, (2.0, 200.0), 5.0, FS)
    f = 2.0 * 100.0 ** (flat.times / 5.0)                       # instantaneous frequency
    np.testing.assert_allclose(c.signal, flat.signal * 2.0 / f, atol=1e-12)   # ∝ 1/f
    assert np.abs(c.signal).max() <= 1.0
    assert np.abs(c.signal[-10:]).max() == pytest.approx(2.0 / 200.0, rel=0.05)
    rising = ex.log_chirp(1.0, (2.0, 200.0), 5.0, FS, amplitude_exponent=1.0)
    np.testing.assert_allclose(rising.signal, flat.signal * f / 200.0, atol=1e-12)
    assert np.abs(rising.signal[-200:]).max() > 0.95 and np.abs(rising.signal[:500]).max() < 0.03


def test_prbs_levels_period_and_flat_band():
    p = ex.prbs(1.5, (2.0, 100.0), 6.0, FS)
    assert set(np.unique(p.signal)) == {-1.5, 1.5}
    # hold: 0.443 · 1000 / 100 → 4 ticks; bits: 2^7 − 1 = 127 · 4 = 508 ticks ≥ 1/2 Hz
    assert p.hold_ticks == 4 and p.period_ticks == 127 * 4
    assert p.ticks == 6000
    np.testing.assert_array_equal(p.signal[p.period_ticks:2 * p.period_ticks],
                                  p.signal[:p.period_ticks])
    # Each bit held 4 ticks.
    bits = p.signal[:p.period_ticks].reshape(-1, 4)
    assert np.all(bits == bits[:, :1])
    # One period's spectrum: flat to within 3 dB up to band high (a maximum-length sequence
    # has equal power in every bin but DC).
    one = p.signal[:p.period_ticks]
    spec = np.abs(np.fft.rfft(one)) ** 2
    f = np.fft.rfftfreq(one.size, 1 / FS)
    inband = (f > 0) & (f <= 100.0)
    db = 10 * np.log10(spec[inband] / spec[inband].max())
    assert db.min() > -3.2
    # Tick-exact and repeatable.
    np.testing.assert_array_equal(p.signal, ex.prbs(1.5, (2.0, 100.0), 6.0, FS).signal)


def test_prbs_full_band_is_white():
    p = ex.prbs(1.0, (1.0, 500.0), 3.0, FS)
    assert p.hold_ticks == 1 and p.period_ticks == 1023
    one = p.signal[:1023]
    spec = np.abs(np.fft.rfft(one))[1:] ** 2
    np.testing.assert_allclose(spec, spec[0], rtol=1e-9)      # every bin alike


def test_stepped_sine_segments_hold_whole_cycles_in_the_band():
    s = ex.stepped_sine(0.8, (5.0, 300.0), 6.0, FS, points=6, settle_cycles=3)
    assert s.ticks == 6000 and len(s.segments) == 6
    freqs = [seg.frequency for seg in s.segments]
    assert freqs == sorted(freqs)
    for want, seg in zip(np.geomspace(5.0, 300.0, 6), s.segments):
        assert seg.frequency == pytest.approx(want, rel=0.1)
        n = seg.stop - seg.measure_start
        assert seg.cycles == pytest.approx(seg.frequency * n / FS, abs=1e-9)
        assert seg.measure_start - seg.start >= 3 * FS / seg.frequency - 1
        w = s.signal[seg.measure_start:seg.stop]
        # A whole number of cycles at full amplitude: all the power in one DFT bin.
        spec = np.abs(np.fft.rfft(w))
        assert np.argmax(spec) == seg.cycles
        assert spec[seg.cycles] ** 2 / np.sum(spec ** 2) > 0.999
        assert 2 * spec[seg.cycles] / n == pytest.approx(0.8, rel=1e-9)   # full amplitude
        assert abs(s.signal[seg.start]) < 1e-12                # faded in from 0


@pytest.mark.parametrize('kw, word', [
    (dict(amplitude=float('nan')), 'amplitude'),
    (dict(amplitude=-1.0), 'amplitude'),
    (dict(amplitude=0.0), 'amplitude'),
    (dict(amplitude='1'), 'amplitude'),
    (dict(duration=float('inf')), 'duration'),
    (dict(duration=-2.0), 'duration'),
    (dict(sample_rate=float('nan')), 'sample_rate'),
    (dict(sample_rate=0.0), 'sample_rate'),
    (dict(band=(10.0, 600.0)), 'Nyquist'),
    (dict(band=(100.0, 10.0)), 'band high'),
    (dict(band=(float('nan'), 10.0)), 'band low'),
    (dict(band=(-1.0, 10.0)), 'band low'),
    (dict(band=10.0), 'band'),
])
@pytest.mark.parametrize('make', [ex.log_chirp, ex.prbs, ex.stepped_sine])
def test_bad_arguments_are_named(make, kw, word):
    args = dict(amplitude=1.0, band=(5.0, 200.0), duration=4.0, sample_rate=FS) | kw
    with pytest.raises(ValueError, match=word):
        make(**args)


def test_signal_specific_validation():
    with pytest.raises(ValueError, match='Nyquist'):
        ex.log_chirp(1.0, (5.0, 500.0), 2.0, FS)            # a sine at Nyquist is degenerate
    ex.prbs(1.0, (5.0, 500.0), 2.0, FS)                     # a PRBS's band may reach it
    with pytest.raises(ValueError, match='amplitude_exponent'):
        ex.log_chirp(1.0, (5.0, 200.0), 2.0, FS, amplitude_exponent=float('nan'))
    with pytest.raises(ValueError, match='one cycle'):
        ex.log_chirp(1.0, (0.1, 200.0), 2.0, FS)
    with pytest.raises(ValueError, match='hold_ticks'):
        ex.prbs(1.0, (5.0, 200.0), 2.0, FS, hold_ticks=4)   # 4 ticks reach only 111 Hz
    with pytest.raises(ValueError, match='hold_ticks'):
        ex.prbs(1.0, (5.0, 200.0), 2.0, FS, hold_ticks=0)
    with pytest.raises(ValueError, match='nbits'):
        ex.prbs(1.0, (5.0, 200.0), 2.0, FS, nbits=40)
    with pytest.raises(ValueError, match='PRBS period'):
        ex.prbs(1.0, (0.5, 200.0), 1.0, FS)                 # a period of 2 s in 1 s
    with pytest.raises(ValueError, match='too short'):
        ex.stepped_sine(1.0, (1.0, 200.0), 2.0, FS, points=20)
    with pytest.raises(ValueError, match='points'):
        ex.stepped_sine(1.0, (5.0, 200.0), 2.0, FS, points=0)
