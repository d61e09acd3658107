"""`ros2 run motion_ctrl notch --resonance HZ`: design the PMAC Ixx36..Ixx39 notch (or a
second-order low-pass) for one axis with motion_ctrl.core.notch and print it as `ros2 param load`
YAML for the controller node."""
import argparse
import math
import re
import sys
from typing import NamedTuple

from motion_ctrl.core.notch import Biquad, dc_gain, design, gain_db, lowpass, prewarp_inputs
from motion_ctrl.core.registers import yaml_float

#: Defaults of the CLI, with the reasons (also shown by --help).
DEFAULT_ZERO_RATIO = 0.9     # manual / Delta Tau: zeros at ~90 % of the resonance for phase lead
DEFAULT_ZERO_DAMPING = 0.05  # typical structural damping of a mechanical resonance (2-5 %)
DEFAULT_POLE_RATIO = 1.2     # "somewhat above": +5 dB high-frequency gain after normalisation
DEFAULT_POLE_DAMPING = 0.7   # heavily damped: no peaking of its own
DEFAULT_LOWPASS_DAMPING = 0.707

_AXIS_RE = re.compile(r'^[A-Za-z][A-Za-z0-9_]*$')


def _build_parser():
    p = argparse.ArgumentParser(
        prog='notch',
        description='Design the PMAC Ixx36..Ixx39 notch (or low-pass) for one axis and print it '
                    'as a "ros2 param load" YAML for the controller node.  The controller '
                    'normalises the filter to unity DC gain: do not rescale kp.')
    mode = p.add_mutually_exclusive_group(required=True)
    mode.add_argument('--resonance', type=float, metavar='HZ',
                      help='mechanical resonance to notch, Hz')
    mode.add_argument('--lowpass', type=float, metavar='HZ',
                      help='design a second-order low-pass at HZ instead (D only)')
    p.add_argument('--servo-rate', type=float, default=1000.0, metavar='HZ',
                   help='servo loop rate, Hz (default 1000)')
    p.add_argument('--axis', default='x', help='axis name (default x)')
    p.add_argument('--zero-ratio', type=float, metavar='R',
                   help=f'zero pair frequency / resonance (default {DEFAULT_ZERO_RATIO}: the '
                        'manual\'s 90 %%, phase lead below the notch)')
    p.add_argument('--zero-damping', type=float, metavar='Z',
                   help=f'zero pair damping (default {DEFAULT_ZERO_DAMPING}: lightly damped, '
                        'like a typical mechanical resonance; smaller = deeper but narrower)')
    p.add_argument('--pole-ratio', type=float, metavar='R',
                   help=f'pole pair frequency / resonance (default {DEFAULT_POLE_RATIO}: '
                        '"somewhat above"; the high-frequency gain grows as (pole/zero)^2)')
    p.add_argument('--pole-damping', type=float, metavar='Z',
                   help=f'pole pair damping (default {DEFAULT_POLE_DAMPING}: heavily damped)')
    p.add_argument('--damping', type=float, metavar='Z',
                   help=f'low-pass damping (default {DEFAULT_LOWPASS_DAMPING}), with --lowpass')
    p.add_argument('--no-prewarp', dest='prewarp', action='store_false',
                   help="use the manual's plain backward-Euler formula (default: prewarp, the "
                        'discrete zeros/poles land at the requested frequencies)')
    return p


def _sweep_extremes(coeffs, T, n=4000):
    """(f_min, gain_min_db, f_max, gain_max_db) of the normalised response over (0, Nyquist)."""
    nyq = 0.5 / T
    best_lo = (0.0, math.inf)
    best_hi = (0.0, -math.inf)
    for i in range(1, n + 1):
        f = nyq * i / n
        g = gain_db(coeffs, f, T)
        if g < best_lo[1]:
            best_lo = (f, g)
        if g > best_hi[1]:
            best_hi = (f, g)
    return best_lo + best_hi


class Design(NamedTuple):
    """A filter designed for the CLI: its coefficients, the comment lines that say what was
    asked, the frequency its attenuation is printed at (and what that frequency is), and the
    comment lines that close the report."""
    coeffs: tuple
    asked: list[str]
    probe: float
    probe_name: str
    figures: list[str]


def main(argv=None):
    """``ros2 run motion_ctrl notch --resonance HZ [...]``: print the registers as YAML."""
    parser = _build_parser()
    a = parser.parse_args(argv)
    if not (math.isfinite(a.servo_rate) and a.servo_rate > 0):
        parser.error(f'--servo-rate must be > 0 Hz, got {a.servo_rate:g}')
    if not _AXIS_RE.match(a.axis):
        parser.error(f'--axis must be a parameter-name prefix like x or axis_1, got {a.axis!r}')
    T = 1.0 / a.servo_rate
    d = _lowpass(parser, a, T) if a.lowpass is not None else _notch(parser, a, T)
    sys.stdout.write('\n'.join(_report(a, T, d)) + '\n')
    return 0


def _lowpass(parser, a, T: float) -> Design:
    """The second-order low-pass of --lowpass (D only); a parser error on a --resonance option
    or a design the biquad refuses."""
    nyq = 0.5 * a.servo_rate
    for opt in ('zero_ratio', 'zero_damping', 'pole_ratio', 'pole_damping'):
        if getattr(a, opt) is not None:
            parser.error(f'--{opt.replace("_", "-")} applies to --resonance, not --lowpass')
    zeta = DEFAULT_LOWPASS_DAMPING if a.damping is None else a.damping
    try:
        coeffs = lowpass(a.lowpass, zeta, T, prewarp=a.prewarp)
        Biquad.validate(*coeffs)
    except ValueError as e:
        parser.error(str(e))
    asked = ['# motion_ctrl second-order low-pass (PMAC Ixx36..Ixx39, D only), '
             f'axis {a.axis}',
             f'# low-pass {a.lowpass:g} Hz, damping {zeta:g}, servo rate {a.servo_rate:g} Hz '
             f'(T = {T:g} s, Nyquist {nyq:g} Hz)']
    _, _, f_hi, g_hi = _sweep_extremes(coeffs, T)
    figures = [f'# gain at Nyquist: {gain_db(coeffs, nyq, T):+.2f} dB; highest gain: '
               f'{g_hi:+.2f} dB at {f_hi:.1f} Hz']
    return Design(coeffs, asked, a.lowpass, 'cut-off', figures)


def _notch(parser, a, T: float) -> Design:
    """The notch of --resonance: zeros and poles at their ratios of it, each option's default
    where not given; a parser error on a bad value or a design the biquad refuses."""
    nyq = 0.5 * a.servo_rate
    if a.damping is not None:
        parser.error('--damping applies to --lowpass; use --zero-damping/--pole-damping')
    zr = DEFAULT_ZERO_RATIO if a.zero_ratio is None else a.zero_ratio
    zd = DEFAULT_ZERO_DAMPING if a.zero_damping is None else a.zero_damping
    pr = DEFAULT_POLE_RATIO if a.pole_ratio is None else a.pole_ratio
    pd = DEFAULT_POLE_DAMPING if a.pole_damping is None else a.pole_damping
    f = a.resonance
    if not (math.isfinite(f) and 0 < f < nyq):
        parser.error(f'--resonance {f:g} Hz must be > 0 and below the Nyquist frequency '
                     f'{nyq:g} Hz of the {a.servo_rate:g} Hz servo rate')
    for name, v in (('--zero-ratio', zr), ('--pole-ratio', pr)):
        if not (math.isfinite(v) and v > 0):
            parser.error(f'{name} must be > 0, got {v:g}')
    try:
        coeffs = design(zr * f, zd, pr * f, pd, T, prewarp=a.prewarp)
        Biquad.validate(*coeffs)
    except ValueError as e:
        parser.error(str(e))
    asked = [f'# motion_ctrl notch (PMAC Ixx36..Ixx39), axis {a.axis}',
             f'# resonance {f:g} Hz, servo rate {a.servo_rate:g} Hz (T = {T:g} s, '
             f'Nyquist {nyq:g} Hz)',
             f'# zeros {zr * f:g} Hz (ratio {zr:g}), damping {zd:g}; '
             f'poles {pr * f:g} Hz (ratio {pr:g}), damping {pd:g}']
    if a.prewarp:
        fz, zz = prewarp_inputs(zr * f, zd, T)
        fp, zp = prewarp_inputs(pr * f, pd, T)
        asked.append("# = the manual's formula fed with equivalent inputs (outside its usual "
                     f'range, which is the point): zeros {fz:.6g} Hz damping {zz:.6g}; '
                     f'poles {fp:.6g} Hz damping {zp:.6g}')
    f_lo, g_lo, f_hi, g_hi = _sweep_extremes(coeffs, T)
    other = design(zr * f, zd, pr * f, pd, T, prewarp=not a.prewarp)
    figures = [f'# deepest point: {-g_lo:.2f} dB at {f_lo:.1f} Hz; highest gain: '
               f'{g_hi:+.2f} dB at {f_hi:.1f} Hz',
               f'# for comparison, {"without" if a.prewarp else "with"} prewarp: '
               f'{-gain_db(other, f, T):.2f} dB at {f:g} Hz']
    return Design(coeffs, asked, f, 'resonance', figures)


def _report(a, T: float, d: Design) -> list[str]:
    """The lines printed: what was asked, the prewarp, the DC gain and the attenuation, the
    design's figures, then the registers as `ros2 param load` YAML."""
    out = list(d.asked)
    if a.prewarp:
        out.append('# prewarp: ON (discrete zeros/poles at z = exp(s T), centred where asked); '
                   "--no-prewarp gives the manual's plain backward-Euler formula")
    else:
        out.append("# prewarp: OFF (the manual's plain backward-Euler formula; frequencies warp "
                   'when 2 pi f T is not small)')
    out.append(f'# DC gain before normalisation: {dc_gain(*d.coeffs):.6g} (the controller '
               'normalises the filter to unity DC gain; do not rescale kp)')
    out.append(f'# attenuation at the {d.probe_name} {d.probe:g} Hz: '
               f'{-gain_db(d.coeffs, d.probe, T):.2f} dB')
    out.extend(d.figures)
    out.append('controller:')
    out.append('  ros__parameters:')
    for name, v in zip(('notch_n1', 'notch_n2', 'notch_d1', 'notch_d2'), d.coeffs):
        out.append(f'    {a.axis}.{name}: {yaml_float(v)}')
    return out


if __name__ == '__main__':
    sys.exit(main())
