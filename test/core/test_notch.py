"""Tests for motion_ctrl.core.notch (PMAC Ixx36..Ixx39 notch / low-pass).

Every test checks a number a servo engineer would check: coefficients against the manual's
formula, DC gain, attenuation (computed and measured on a simulated sine), refusals, CLI output.
"""

import cmath
import math

import numpy as np
import pytest
import yaml

from motion_ctrl.core import notch
from motion_ctrl.tools import notch as notch_cli
from motion_ctrl.core.notch import (Biquad, angle_matched_frequency, dc_gain, design, gain_db,
                               lowpass, prewarp_inputs, response)


def measured_gain(bq, f, servo_period, cycles_settle=400, n_fit=2000):
    """Feed a unit sine at f through bq; fit sin/cos at f to the settled output -> amplitude."""
    n_total = cycles_settle + n_fit
    k = np.arange(n_total)
    x = np.sin(2 * math.pi * f * servo_period * k)
    y = np.array([bq.step(float(v)) for v in x])
    kk = k[cycles_settle:]
    basis = np.column_stack([np.sin(2 * math.pi * f * servo_period * kk),
                             np.cos(2 * math.pi * f * servo_period * kk)])
    (a, b), *_ = np.linalg.lstsq(basis, y[cycles_settle:], rcond=None)
    return math.hypot(a, b)


# ---------------------------------------------------------------------------------------------
# the manual's formula

def test_manual_lowpass_example_60hz():
    # PMAC manual: 60 Hz, zeta 0.707, T = 250 us, "D only" low-pass.  The manual prints
    # alpha = 1.146, D1 = -1.861, D2 = 0.873, but its own sum is mis-added:
    # w T = 2 pi 60 * 250e-6 = 0.0942, 1 + 2 * 0.707 * 0.0942 + 0.0942^2 = 1.142, not 1.146.
    # With alpha = 1.142 the formula gives D1 = -1.8678, D2 = 0.8755: we test the FORMULA,
    # not the manual's misprint.
    n1, n2, d1, d2 = lowpass(60.0, 0.707, 250e-6)
    assert (n1, n2) == (0.0, 0.0)
    assert round(d1, 4) == -1.8678
    assert round(d2, 4) == 0.8755
    assert round(1.0 / d2, 3) == 1.142          # alpha
    assert round(d1, 3) != -1.861               # the manual's printed value is not the formula's
    # as a low-pass it passes DC at unity after normalisation and is -3.6 dB at 60 Hz
    # (backward Euler; the continuous prototype would be -3.0 dB)
    assert gain_db((n1, n2, d1, d2), 60.0, 250e-6) == pytest.approx(-3.57, abs=0.01)


def test_design_is_the_backward_euler_formula():
    # 100 Hz zeros zeta 0.1, T = 1 ms: w T = 0.6283185,
    # alpha = 1 + 0.1256637 + 0.3947842 = 1.5204479
    # N1 = -2 (1.0628319) / 1.5204479 = -1.3980510, N2 = 1 / 1.5204479 = 0.6577009
    n1, n2, d1, d2 = design(100.0, 0.1, 200.0, 0.5, 1e-3)
    assert n1 == pytest.approx(-1.3980510, abs=1e-7)
    assert n2 == pytest.approx(0.6577009, abs=1e-7)
    wt = 2 * math.pi * 200.0 * 1e-3
    alpha_p = 1 + 2 * 0.5 * wt + wt * wt
    assert d1 == pytest.approx(-2 * (1 + 0.5 * wt) / alpha_p, abs=1e-15)
    assert d2 == pytest.approx(1 / alpha_p, abs=1e-15)


def test_dc_gain_matches_manual_expression():
    # DC gain = (wz^2 / wp^2) (alpha_p / alpha_z); 225 Hz / 300 Hz at 1 kHz -> 1.28839
    T = 1e-3
    c = design(225.0, 0.05, 300.0, 0.7, T)
    wz, wp = 2 * math.pi * 225.0, 2 * math.pi * 300.0
    az = 1 + 2 * 0.05 * wz * T + (wz * T) ** 2
    ap = 1 + 2 * 0.7 * wp * T + (wp * T) ** 2
    assert dc_gain(*c) == pytest.approx((wz / wp) ** 2 * ap / az, rel=1e-12)
    assert dc_gain(*c) == pytest.approx(1.28839, abs=1e-5)
    assert response(c, 0.0, T) == pytest.approx(dc_gain(*c), abs=1e-12)


def test_design_refuses_nyquist_and_bad_inputs():
    with pytest.raises(ValueError, match='Nyquist'):
        design(500.0, 0.05, 400.0, 0.7, 1e-3)       # zeros at Nyquist of 1 kHz
    with pytest.raises(ValueError, match='Nyquist'):
        design(225.0, 0.05, 540.0, 0.7, 1e-3)       # poles above it
    with pytest.raises(ValueError):
        design(225.0, -0.1, 300.0, 0.7, 1e-3)
    with pytest.raises(ValueError):
        design(float('nan'), 0.05, 300.0, 0.7, 1e-3)
    with pytest.raises(ValueError):
        lowpass(60.0, 0.7, 0.0)


# ---------------------------------------------------------------------------------------------
# backward-Euler warping and the prewarp option

@pytest.mark.parametrize('f, zeta', [(225.0, 0.05), (300.0, 0.7), (135.0, 0.0), (60.0, 1.5)])
def test_prewarp_puts_roots_at_exp_sT(f, zeta):
    # prewarp = PMAC's formula fed with (f', zeta') whose backward-Euler root is exactly
    # z = exp(s T): radius exp(-zeta w T), angle w sqrt(1 - zeta^2) T.
    T = 1e-3
    n1, n2, _, _ = design(f, zeta, f, zeta, T, prewarp=True)
    w = 2 * math.pi * f
    s = complex(-zeta * w, w * cmath.sqrt(1 - zeta * zeta).real) if zeta < 1 else None
    if s is not None:
        z = cmath.exp(s * T)
        assert n1 == pytest.approx(-2 * z.real, abs=1e-12)
        assert n2 == pytest.approx(abs(z) ** 2, abs=1e-12)
    else:   # over-damped: two real roots exp(s1 T), exp(s2 T)
        r = math.sqrt(zeta * zeta - 1)
        z1, z2 = math.exp(w * (-zeta + r) * T), math.exp(w * (-zeta - r) * T)
        assert n1 == pytest.approx(-(z1 + z2), abs=1e-12)
        assert n2 == pytest.approx(z1 * z2, abs=1e-12)
    # the equivalent inputs, typed into the plain formula, give the same coefficients
    fe, ze = prewarp_inputs(f, zeta, T)
    wt = 2 * math.pi * fe * T
    alpha = 1 + 2 * ze * wt + wt * wt
    assert n1 == pytest.approx(-2 * (1 + ze * wt) / alpha, abs=1e-12)
    assert n2 == pytest.approx(1 / alpha, abs=1e-12)


def test_prewarp_inputs_for_the_default_250hz_notch():
    # zeros 225 Hz / 0.05 at 1 kHz need the formula fed with 214.26 Hz and damping -0.617;
    # poles 300 Hz / 0.7 need 581.1 Hz (above Nyquist!) and damping -0.046.
    fz, zz = prewarp_inputs(225.0, 0.05, 1e-3)
    fp, zp = prewarp_inputs(300.0, 0.7, 1e-3)
    assert (round(fz, 2), round(zz, 3)) == (214.26, -0.617)
    assert (round(fp, 1), round(zp, 3)) == (581.1, -0.046)


@pytest.mark.parametrize('fr, plain_db, plain_deepest_db, plain_deepest_hz, prewarp_db', [
    (150.0, 5.8, 6.2, 129.3, 21.7),
    (250.0, 4.0, 4.5, 191.4, 21.9),
    (350.0, 3.2, 3.6, 243.1, 23.4),
])
def test_backward_euler_warping_at_1khz(fr, plain_db, plain_deepest_db, plain_deepest_hz,
                                        prewarp_db):
    # Notch with zeros AT the resonance (ratio 1.0, zeta 0.05), poles 1.2x, zeta 0.7, 1 kHz.
    # Continuous prototype: 21.6 dB at the resonance.  The manual's plain formula gives a
    # shallow dip whose deepest point is far below the resonance; prewarp restores the notch.
    T = 1e-3
    plain = design(fr, 0.05, 1.2 * fr, 0.7, T)
    warped = design(fr, 0.05, 1.2 * fr, 0.7, T, prewarp=True)
    assert -gain_db(plain, fr, T) == pytest.approx(plain_db, abs=0.05)
    freqs = np.linspace(1.0, 499.9, 5000)
    g_plain = [gain_db(plain, f, T) for f in freqs]
    assert freqs[int(np.argmin(g_plain))] == pytest.approx(plain_deepest_hz, abs=0.5)
    assert -min(g_plain) == pytest.approx(plain_deepest_db, abs=0.05)   # nowhere deeper
    assert -gain_db(warped, fr, T) == pytest.approx(prewarp_db, abs=0.05)
    g_warped = [gain_db(warped, f, T) for f in freqs]
    assert freqs[int(np.argmin(g_warped))] == pytest.approx(fr, abs=0.5)   # centred where asked
    # plain backward Euler puts the zeros well inside the unit circle (|z| ~ 0.4 .. 0.7)
    z_plain = notch._roots(plain[0], plain[1])[0]
    z_warped = notch._roots(warped[0], warped[1])[0]
    assert abs(z_plain) < 0.75
    assert abs(z_warped) == pytest.approx(math.exp(-0.05 * 2 * math.pi * fr * T), abs=1e-12)


def test_backward_euler_numerical_damping_hurts_even_at_4khz():
    # At 4 kHz the frequency warp of 250 Hz is small (deepest point 239 Hz), but backward
    # Euler adds ~ w T / 2 = 0.2 of damping to the zeros: only 9.9 dB instead of 21.6 dB.
    T = 1 / 4000
    plain = design(250.0, 0.05, 300.0, 0.7, T)
    assert -gain_db(plain, 250.0, T) == pytest.approx(9.88, abs=0.01)
    warped = design(250.0, 0.05, 300.0, 0.7, T, prewarp=True)
    assert -gain_db(warped, 250.0, T) == pytest.approx(21.63, abs=0.01)


def test_frequency_only_angle_match_cannot_make_a_deep_notch():
    # The literal prewarp (move only the design frequency so the root ANGLE lands at f):
    # closed form x = sin(theta) / cos(theta + asin(zeta)).  At 1 kHz, zeros 135 Hz zeta 0.05:
    T = 1e-3
    fa = angle_matched_frequency(135.0, 0.05, T)
    assert fa == pytest.approx(191.63, abs=0.01)
    c = design(fa, 0.05, fa, 0.05, T)
    z = notch._roots(c[0], c[1])[0]
    assert abs(cmath.phase(z)) == pytest.approx(2 * math.pi * 135.0 * T, abs=1e-12)  # angle hit
    assert abs(z) == pytest.approx(0.624, abs=1e-3)           # but radius <= cos(48.6 deg) = 0.661
    assert abs(z) < math.cos(2 * math.pi * 135.0 * T)
    # Angles at or beyond acos(zeta) (< 90 deg, i.e. < fs/4) are not reachable at all:
    with pytest.raises(ValueError, match='not reachable'):
        angle_matched_frequency(250.0, 0.05, T)     # fs/4
    with pytest.raises(ValueError, match='not reachable'):
        angle_matched_frequency(180.0, 0.7, T)      # heavily damped poles: limit 126.6 Hz


# ---------------------------------------------------------------------------------------------
# designed notches: unity DC gain and >= 20 dB at the resonance (computed and measured)

@pytest.mark.parametrize('servo_rate, expected_db', [(1000.0, 21.95), (4000.0, 21.63)])
def test_designed_notch_unity_dc_and_20db_at_resonance(servo_rate, expected_db):
    T = 1.0 / servo_rate
    c = design(250.0, 0.05, 300.0, 0.7, T, prewarp=True)
    bq = Biquad(*c)
    # unity DC gain after normalisation, computed ...
    assert abs(response(c, 0.0, T) * bq.numerator_gain) == pytest.approx(1.0, abs=1e-9)
    # ... and measured: a constant input comes out unchanged
    for _ in range(2000):
        y = bq.step(0.37)
    assert y == pytest.approx(0.37, abs=1e-9)
    # >= 20 dB at the resonance, computed
    g = gain_db(c, 250.0, T)
    assert g == pytest.approx(-expected_db, abs=0.01)
    assert g <= -20.0
    # ... and measured on a sine at the resonance run through the filter
    bq.reset()
    amp = measured_gain(bq, 250.0, T)
    assert 20 * math.log10(amp) == pytest.approx(g, abs=0.01)
    assert amp < 0.1


def test_default_cli_notch_zero_ratio_090():
    # The manual's placement (zeros at 90 % of the resonance, for phase lead) notches 225 Hz:
    # >= 20 dB there, but only 13.6 dB at the 250 Hz resonance itself (continuous prototype:
    # 13.3 dB).  Pass --zero-ratio 1.0 for >= 20 dB at the resonance.
    T = 1e-3
    c = design(0.9 * 250.0, 0.05, 1.2 * 250.0, 0.7, T, prewarp=True)
    assert -gain_db(c, 250.0, T) == pytest.approx(13.61, abs=0.01)
    assert -gain_db(c, 225.0, T) >= 20.0
    s = 2j * math.pi * 250.0
    wz, wp = 2 * math.pi * 225.0, 2 * math.pi * 300.0
    cont = abs((s * s + 2 * 0.05 * wz * s + wz * wz) / (s * s + 2 * 0.7 * wp * s + wp * wp)) \
        * wp * wp / (wz * wz)
    assert -20 * math.log10(cont) == pytest.approx(13.3, abs=0.05)


# ---------------------------------------------------------------------------------------------
# Biquad

def test_biquad_default_is_pass_through():
    bq = Biquad()
    assert bq.numerator_gain == 1.0
    assert [bq.step(v) for v in (1.5, -2.0, 3.25)] == [1.5, -2.0, 3.25]
    bq.configure(0.0, 0.0, 0.0, 0.0)
    assert bq.step(7.0) == 7.0


def test_biquad_normalises_lowpass_dc_gain():
    # the manual's 60 Hz low-pass has a raw DC gain of 128.58; normalised it settles at 1.0
    c = lowpass(60.0, 0.707, 250e-6)
    assert dc_gain(*c) == pytest.approx(128.58, abs=0.01)
    bq = Biquad(*c)
    assert bq.numerator_gain == pytest.approx(1 / 128.58, rel=1e-4)
    for _ in range(1000):
        y = bq.step(2.0)
    assert y == pytest.approx(2.0, abs=1e-9)


@pytest.mark.parametrize('coeffs, reason', [
    ((2.5, 0.0, 0.0, 0.0), 'register range'),
    ((0.0, 0.0, -2.0001, 0.9), 'register range'),
    ((float('nan'), 0.0, 0.0, 0.0), 'finite'),
    ((0.0, 0.0, float('inf'), 0.0), 'finite'),
    ((0.0, 0.0, -1.8, 0.7), 'unstable'),      # real pole at z = 1.09
    ((0.0, 0.0, -1.0, 1.0), 'unstable'),      # poles on the unit circle (|z| = 1)
    ((0.0, 0.0, 0.0, -1.2), 'unstable'),      # poles at +/-1.095
    ((-1.0, 0.0, 0.0, 0.0), 'DC gain 0'),     # zero at z = 1
    (('0.5', 0.0, 0.0, 0.0), 'number'),
])
def test_biquad_refuses(coeffs, reason):
    bq = Biquad(0.0, 0.0, -0.5, 0.0)
    with pytest.raises(ValueError, match=reason):
        bq.configure(*coeffs)
    assert bq.coefficients == (0.0, 0.0, -0.5, 0.0)    # unchanged after a refusal


def test_biquad_accepts_stable_edge():
    # |d1| < 1 + d2 and |d2| < 1: poles at 0.95 +/- 0.2j (|z| = 0.971) accepted
    bq = Biquad(0.0, 0.0, -1.9, 0.9425)
    assert bq.coefficients == (0.0, 0.0, -1.9, 0.9425)


def test_biquad_reset_no_bump():
    bq = Biquad(*design(250.0, 0.05, 300.0, 0.7, 1e-3, prewarp=True))
    bq.reset(2.5)
    assert [round(bq.step(2.5), 12) for _ in range(5)] == [2.5] * 5


def test_biquad_reconfigure_keeps_history():
    T = 1e-3
    a = design(250.0, 0.05, 300.0, 0.7, T, prewarp=True)
    b = design(150.0, 0.05, 180.0, 0.7, T, prewarp=True)
    bq = Biquad(*a)
    for _ in range(500):
        bq.step(1.0)
    bq.configure(*b)                                    # steady state: no jump at all
    assert max(abs(bq.step(1.0) - 1.0) for _ in range(50)) < 1e-12
    # with a moving input the history is kept: the output equals that of filter b run on the
    # same past inputs with a's past outputs, not of a freshly reset b
    bq.configure(*a)
    xs = [math.sin(0.3 * k) for k in range(100)]
    ys = [bq.step(x) for x in xs]
    x1, x2, y1, y2 = xs[-1], xs[-2], ys[-1], ys[-2]
    bq.configure(*b)
    g = 1.0 / dc_gain(*b)
    expected = g * (0.5 + b[0] * x1 + b[1] * x2) - b[2] * y1 - b[3] * y2
    assert bq.step(0.5) == pytest.approx(expected, abs=1e-15)
    fresh = Biquad(*b)
    assert abs(fresh.step(0.5) - expected) > 0.1


# ---------------------------------------------------------------------------------------------
# CLI

def run_cli(capsys, *args):
    assert notch_cli.main(list(args)) == 0
    out = capsys.readouterr().out
    return out, yaml.safe_load(out)


def test_cli_default_notch_yaml(capsys):
    out, doc = run_cli(capsys, '--resonance', '250')
    params = doc['controller']['ros__parameters']
    assert sorted(params) == ['x.notch_d1', 'x.notch_d2', 'x.notch_n1', 'x.notch_n2']
    expected = design(0.9 * 250.0, 0.05, 1.2 * 250.0, 0.7, 1e-3, prewarp=True)
    got = tuple(params[f'x.notch_{k}'] for k in ('n1', 'n2', 'd1', 'd2'))
    assert all(isinstance(v, float) for v in got)      # ROS double parameters, not strings/ints
    assert got == pytest.approx(expected, abs=1e-15)
    assert '# prewarp: ON' in out
    assert '# DC gain before normalisation: 1.65212' in out
    assert '# attenuation at the resonance 250 Hz: 13.61 dB' in out
    assert 'without prewarp: 3.15 dB at 250 Hz' in out


def test_cli_no_prewarp_axis_and_ratios(capsys):
    out, doc = run_cli(capsys, '--resonance', '250', '--servo-rate', '4000', '--axis', 'y',
                       '--zero-ratio', '1.0', '--zero-damping', '0.02', '--pole-ratio', '1.3',
                       '--pole-damping', '0.8', '--no-prewarp')
    params = doc['controller']['ros__parameters']
    expected = design(250.0, 0.02, 1.3 * 250.0, 0.8, 1 / 4000, prewarp=False)
    got = tuple(params[f'y.notch_{k}'] for k in ('n1', 'n2', 'd1', 'd2'))
    assert got == pytest.approx(expected, abs=1e-15)
    assert '# prewarp: OFF' in out


def test_cli_lowpass_manual_example(capsys):
    out, doc = run_cli(capsys, '--lowpass', '60', '--damping', '0.707', '--servo-rate', '4000',
                       '--no-prewarp')
    p = doc['controller']['ros__parameters']
    assert p['x.notch_n1'] == 0.0 and isinstance(p['x.notch_n1'], float)
    assert p['x.notch_n2'] == 0.0
    assert round(p['x.notch_d1'], 4) == -1.8678
    assert round(p['x.notch_d2'], 4) == 0.8755


@pytest.mark.parametrize('args', [
    ['--resonance', '500'],                   # at Nyquist of 1 kHz
    ['--resonance', '450'],                   # poles (1.2 x 450 = 540 Hz) above Nyquist
    ['--lowpass', '2500', '--servo-rate', '4000'],
    ['--resonance', '-5'],
    ['--resonance', 'abc'],
    [],                                       # neither --resonance nor --lowpass
    ['--resonance', '100', '--damping', '0.3'],
    ['--resonance', '100', '--axis', 'x.y'],
])
def test_cli_bad_arguments_exit_2(capsys, args):
    with pytest.raises(SystemExit) as e:
        notch_cli.main(args)
    assert e.value.code == 2
    err = capsys.readouterr().err
    errors = [line for line in err.splitlines() if line.startswith('notch: error:')]
    assert len(errors) == 1
