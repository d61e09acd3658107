"""PMAC Ixx36..Ixx39 second-order notch / low-pass filter on the servo output.

Registers (Turbo PMAC; here ``<axis>.notch_n1``, ``notch_n2``, ``notch_d1``, ``notch_d2``)::

    Ixx36 = N1, Ixx37 = N2, Ixx38 = D1, Ixx39 = D2          (range -2.0 .. 2.0 each)

              1 + N1 z^-1 + N2 z^-2
    F(z) = --------------------------          all four 0 = pass-through (PMAC default)
              1 + D1 z^-1 + D2 z^-2

PMAC design (User Manual, "Manual Notch Specification"): start from the continuous notch

    G(s) = (s^2 + 2 zeta_z w_z s + w_z^2) / (s^2 + 2 zeta_p w_p s + w_p^2),   w = 2 pi f

and discretise it by backward Euler, s = (1 - z^-1) / T, T = servo period:

    alpha_z = 1 + 2 zeta_z w_z T + w_z^2 T^2
    N1 = -2 (1 + zeta_z w_z T) / alpha_z        N2 = 1 / alpha_z
    alpha_p = 1 + 2 zeta_p w_p T + w_p^2 T^2
    D1 = -2 (1 + zeta_p w_p T) / alpha_p        D2 = 1 / alpha_p

The DC gain of F is (1 + N1 + N2) / (1 + D1 + D2) = (w_z^2 / w_p^2) (alpha_p / alpha_z).
The manual compensates it by multiplying the proportional gain Ixx30 by the inverse.  This
product does NOT: :class:`Biquad` normalises the filter to unity DC gain itself (it multiplies the
numerator by 1 / DC gain), so ``kp`` keeps its meaning whatever the notch registers hold.  Do not
rescale ``kp`` when you load PMAC-designed coefficients.  With D only (N1 = N2 = 0) the same
block is the manual's second-order low-pass (:func:`lowpass`).

Backward-Euler warping (measured, see the tests).  Backward Euler maps the whole left half
s-plane into the disc |z - 1/2| < 1/2.  Every zero or pole it produces from a damped pair
(zeta >= 0) therefore lies at an angle below 90 degrees (below fs/4) and at a radius of at most
cos(angle).  It also adds about w T / 2 of numerical damping to every pair.  When w T is not
small the zero pair lands well inside the unit circle and at a lower frequency than asked: at a
1 kHz servo rate a 250 Hz resonance (zeros at 225 Hz) gets its zeros at 147 Hz, radius 0.56, and
the "notch" is a 4.3 dB dip centred near 171 Hz (3.2 dB at 250 Hz).  Nothing at or above fs/4
(250 Hz at 1 kHz) can be notched by the plain formula at all.  Even at 4 kHz, where the
frequency warp is small, the extra damping limits a notch with its zeros at 250 Hz to 9.9 dB
there (21.6 dB with prewarp, as in continuous time).

Moving only the design frequency so that the zero *angle* lands where asked (the literal
"prewarp", :func:`angle_matched_frequency`, closed form below) cannot fix that: the reachable
angle is bounded by arccos(zeta) < 90 degrees and the radius stays at most cos(angle), so the
notch stays shallow.  The remedy offered here, ``prewarp=True``, still feeds PMAC's formula, but
with the equivalent design inputs (f', zeta') whose backward-Euler image is exactly the
matched root z = exp(s T) of the continuous pair (:func:`prewarp_inputs`)::

    s' = (1 - exp(-s T)) / T    for each continuous root s = w (-zeta +/- j sqrt(1 - zeta^2))
    w'^2 = s1' s2',  2 zeta' w' = -(s1' + s2')

Since 1 - s' T = exp(-s T), backward Euler puts the discrete root at exp(s T): angle
w sqrt(1 - zeta^2) T (the pair's damped frequency: 0.1 % below f for zeta 0.05), radius
exp(-zeta w T).  Hence N1 = -2 r cos(theta), N2 = r^2 for a complex pair.  zeta' is usually
negative (the matched zeros lie outside the backward-Euler disc); that is fine, the formula is
pure algebra and the poles stay inside the unit circle.  :func:`design` defaults to the
manual's plain formula (prewarp=False); the CLI (motion_ctrl.tools.notch) defaults to prewarp
and says so in its output.

No rclpy here: plain, deterministic Python.
"""

import cmath
import math
from typing import Final

__all__ = [
    'REGISTER_LIMIT', 'design', 'lowpass', 'prewarp_inputs', 'angle_matched_frequency', 'dc_gain',
    'response', 'gain_db', 'Biquad',
]

#: Ixx36..Ixx39 are 24-bit registers, 1 sign bit + 1 integer bit + 22 fractional bits.
REGISTER_LIMIT: Final = 2.0


# ----------------------------------------------------------------------------------------------
# design

def _check_design_input(name, f, zeta, servo_period):
    if not (isinstance(servo_period, (int, float)) and math.isfinite(servo_period)
            and servo_period > 0):
        raise ValueError(f'servo_period must be a finite number > 0 s, got {servo_period!r}')
    if not (math.isfinite(f) and f > 0):
        raise ValueError(f'{name} frequency must be a finite number > 0 Hz, got {f!r}')
    nyquist = 0.5 / servo_period
    if f >= nyquist:
        raise ValueError(f'{name} frequency {f:g} Hz is at or above the Nyquist frequency '
                         f'{nyquist:g} Hz of the {1.0 / servo_period:g} Hz servo rate')
    if not (math.isfinite(zeta) and zeta >= 0):
        raise ValueError(f'{name} damping must be a finite number >= 0, got {zeta!r}')


def _pmac_pair(f, zeta, servo_period):
    """PMAC's backward-Euler formula for one second-order pair -> (c1, c2)."""
    wt = 2.0 * math.pi * f * servo_period
    alpha = 1.0 + 2.0 * zeta * wt + wt * wt
    return -2.0 * (1.0 + zeta * wt) / alpha, 1.0 / alpha


def prewarp_inputs(f, zeta, servo_period):
    """Equivalent backward-Euler design inputs ``(f', zeta')`` for the pair ``(f, zeta)``.

    Feeding ``(f', zeta')`` into PMAC's formula places the discrete roots exactly at
    ``z = exp(s T)`` of the continuous roots ``s`` of ``s^2 + 2 zeta w s + w^2`` (matched
    pole-zero mapping): angle ``w sqrt(1 - zeta^2) T``, radius ``exp(-zeta w T)``.  ``zeta'``
    is usually negative and ``f'`` may exceed Nyquist (300 Hz, zeta 0.7 at 1 kHz -> 581 Hz,
    -0.046), so a tool that range-checks its inputs (``design`` included) refuses them;
    ``design(..., prewarp=True)`` applies them internally.  The algebra is the manual's.
    """
    _check_design_input('design', f, zeta, servo_period)
    T = servo_period
    w = 2.0 * math.pi * f
    if zeta < 1.0:
        s = complex(-zeta * w, w * math.sqrt(1.0 - zeta * zeta))
        sp = (1.0 - cmath.exp(-s * T)) / T          # s' ; the other root is its conjugate
        wp = abs(sp)
        return wp / (2.0 * math.pi), -sp.real / wp
    r = math.sqrt(zeta * zeta - 1.0)               # real roots (over-damped pair)
    s1, s2 = w * (-zeta + r), w * (-zeta - r)
    p1, p2 = (1.0 - math.exp(-s1 * T)) / T, (1.0 - math.exp(-s2 * T)) / T
    wp = math.sqrt(p1 * p2)
    return wp / (2.0 * math.pi), -(p1 + p2) / (2.0 * wp)


def angle_matched_frequency(f, zeta, servo_period):
    """Frequency-only prewarp: the f' for which PMAC's formula with damping ``zeta`` puts the
    discrete root at angle ``theta = 2 pi f T``.

    The backward-Euler root of ``(f', zeta)`` is ``z = 1 / (1 - s T)``, whose angle is
    ``atan2(x sqrt(1 - zeta^2), 1 + zeta x)`` with ``x = 2 pi f' T``.  Solving for x gives the
    closed form ``x = sin(theta) / cos(theta + asin(zeta))``, defined only for
    ``theta < acos(zeta)`` (< 90 degrees, i.e. below fs/4): beyond that no frequency reaches the
    angle and ValueError is raised.  Even when it exists the root radius is at most
    ``cos(theta)``, so this does NOT give a deep notch, and the f' it returns often lies above
    Nyquist (225 Hz, zeta 0.05 at 1 kHz -> 1471 Hz, radius 0.11), which :func:`design` refuses.
    It is provided to document the limit.
    :func:`prewarp_inputs` is the usable remedy.
    """
    _check_design_input('design', f, zeta, servo_period)
    if zeta >= 1.0:
        raise ValueError(f'damping {zeta:g} >= 1 gives real roots: they have no angle to match')
    theta = 2.0 * math.pi * f * servo_period
    limit = math.acos(zeta)
    if theta >= limit:
        raise ValueError(
            f'{f:g} Hz is not reachable by backward Euler with damping {zeta:g} at '
            f'{1.0 / servo_period:g} Hz: the root angle is limited to acos(zeta) = '
            f'{math.degrees(limit):.1f} deg, i.e. {limit / (2 * math.pi * servo_period):.1f} Hz')
    x = math.sin(theta) / math.cos(theta + math.asin(zeta))
    return x / (2.0 * math.pi * servo_period)


def design(f_zero, zeta_zero, f_pole, zeta_pole, servo_period, prewarp=False):
    """Notch coefficients ``(n1, n2, d1, d2)`` = (Ixx36, Ixx37, Ixx38, Ixx39).

    Frequencies in Hz (0 < f < Nyquist), dampings >= 0, ``servo_period`` in s.  With
    ``prewarp=False`` this is exactly the PMAC manual's backward-Euler formula.  With
    ``prewarp=True`` each pair is first replaced by its :func:`prewarp_inputs` equivalent, so the
    discrete zeros/poles sit at exp(s T) (notch centred at the requested frequency).
    Raises ValueError on a bad input.  Stability is checked by :meth:`Biquad.configure`.
    """
    _check_design_input('zero', f_zero, zeta_zero, servo_period)
    _check_design_input('pole', f_pole, zeta_pole, servo_period)
    if prewarp:
        f_zero, zeta_zero = prewarp_inputs(f_zero, zeta_zero, servo_period)
        f_pole, zeta_pole = prewarp_inputs(f_pole, zeta_pole, servo_period)
    n1, n2 = _pmac_pair(f_zero, zeta_zero, servo_period)
    d1, d2 = _pmac_pair(f_pole, zeta_pole, servo_period)
    return n1, n2, d1, d2


def lowpass(f, zeta, servo_period, prewarp=False):
    """Second-order low-pass ``(0.0, 0.0, d1, d2)``: the manual's "D only" use of the filter.

    Manual example: 60 Hz, zeta 0.707, T = 250 us -> D1 = -1.8678, D2 = 0.8755 (the manual
    prints -1.861 / 0.873 because it mis-adds alpha as 1.146 instead of 1.142).
    """
    _check_design_input('low-pass', f, zeta, servo_period)
    if prewarp:
        f, zeta = prewarp_inputs(f, zeta, servo_period)
    d1, d2 = _pmac_pair(f, zeta, servo_period)
    return 0.0, 0.0, d1, d2


# ----------------------------------------------------------------------------------------------
# analysis

def dc_gain(n1, n2, d1, d2):
    """DC gain F(z=1) = (1 + n1 + n2) / (1 + d1 + d2) of the raw (un-normalised) filter."""
    den = 1.0 + d1 + d2
    if den == 0.0:
        raise ValueError('denominator has a pole at z = 1 (1 + d1 + d2 = 0): infinite DC gain')
    return (1.0 + n1 + n2) / den


def response(coeffs, f, servo_period):
    """Complex frequency response F(e^{j w T}) of the raw filter ``coeffs = (n1, n2, d1, d2)``
    at ``f`` Hz (not normalised: divide by :func:`dc_gain` for what :class:`Biquad` does)."""
    n1, n2, d1, d2 = coeffs
    zi = cmath.exp(complex(0.0, -2.0 * math.pi * f * servo_period))      # z^-1
    return (1.0 + (n1 + n2 * zi) * zi) / (1.0 + (d1 + d2 * zi) * zi)


def gain_db(coeffs, f, servo_period, normalise=True):
    """|F| at ``f`` in dB; with ``normalise`` relative to the DC gain (what the Biquad applies).
    Negative = attenuation."""
    g = abs(response(coeffs, f, servo_period))
    if normalise:
        dc = dc_gain(*coeffs)
        if dc == 0.0:
            raise ValueError('DC gain is 0: the response cannot be normalised')
        g /= abs(dc)
    return 20.0 * math.log10(g) if g > 0.0 else -math.inf


# ----------------------------------------------------------------------------------------------
# run-time filter

class Biquad:
    """The Ixx36..Ixx39 filter as run in the servo loop, normalised to unity DC gain.

    ``y = g (x + n1 x[-1] + n2 x[-2]) - d1 y[-1] - d2 y[-2]`` (direct form I) with
    ``g = 1 / dc_gain``: this replaces the manual's "multiply Ixx30 by the inverse of the DC
    gain".  All-zero coefficients (the default) = pass-through.
    """

    __slots__ = ('_g', '_b1', '_b2', '_a1', '_a2', '_x1', '_x2', '_y1', '_y2', '_coeffs', 'passes')
    # (typed here: configure takes any input and refuses it with a reason)
    _g: float
    _b1: float
    _b2: float
    _a1: float
    _a2: float
    _x1: float
    _x2: float
    _y1: float
    _y2: float

    def __init__(self, n1=0.0, n2=0.0, d1=0.0, d2=0.0):
        self._x1 = self._x2 = self._y1 = self._y2 = 0.0
        self.configure(n1, n2, d1, d2)

    @staticmethod
    def validate(n1, n2, d1, d2):
        """Raise ValueError (with the reason) unless the four registers make a usable filter;
        return the normalising numerator gain 1 / dc_gain."""
        names = ('n1', 'n2', 'd1', 'd2')
        for name, c in zip(names, (n1, n2, d1, d2)):
            if isinstance(c, bool) or not isinstance(c, (int, float)):
                raise ValueError(f'notch_{name} must be a number, got {c!r}')
            if not math.isfinite(c):
                raise ValueError(f'notch_{name} must be finite, got {c!r}')
            if abs(c) > REGISTER_LIMIT:
                raise ValueError(f'notch_{name} = {c:g} is outside the register range '
                                 f'-{REGISTER_LIMIT:g} .. {REGISTER_LIMIT:g}')
        # 1 + d1 z^-1 + d2 z^-2 has both roots strictly inside |z| < 1 iff (Jury)
        # |d2| < 1 and |d1| < 1 + d2.
        if not (abs(d2) < 1.0 and abs(d1) < 1.0 + d2):
            radius = max(abs(p) for p in _roots(d1, d2))
            raise ValueError(f'notch denominator (d1 = {d1:g}, d2 = {d2:g}) is unstable: '
                             f'pole at |z| = {radius:.6g}, need < 1')
        num = 1.0 + n1 + n2
        if abs(num) <= 1e-12:
            raise ValueError(f'notch numerator (n1 = {n1:g}, n2 = {n2:g}) has a zero at z = 1: '
                             'DC gain 0 cannot be normalised')
        return (1.0 + d1 + d2) / num

    def configure(self, n1, n2, d1, d2):
        """Load new registers.  Validates first (ValueError, state untouched); the input/output
        history is kept, so a filter in steady state stays there (both old and new filters have
        unity DC gain) and any transient is only what the new coefficients imply."""
        g = self.validate(n1, n2, d1, d2)
        self._coeffs = (float(n1), float(n2), float(d1), float(d2))
        self._g = g
        self._b1 = g * n1
        self._b2 = g * n2
        self._a1 = float(d1)
        self._a2 = float(d2)
        # All-zero registers: y = x (the history still runs, so a notch set later starts
        # from it), and peek need not compute it.
        self.passes = not (n1 or n2 or d1 or d2)

    @property
    def coefficients(self) -> tuple[float, float, float, float]:
        """The registers as configured: (n1, n2, d1, d2)."""
        return self._coeffs

    @property
    def numerator_gain(self) -> float:
        """The normalising gain g = 1 / dc_gain applied to the numerator (1.0 = pass-through)."""
        return self._g

    def reset(self, value=0.0):
        """Set the history to the steady state in which the output equals ``value``
        (input = output = value, as the DC gain is 1): closing the loop causes no bump."""
        v = float(value)
        self._x1 = self._x2 = self._y1 = self._y2 = v

    def peek(self, x: float) -> float:
        """What `step(x)` would return, without advancing the filter (the servo law tests this
        tick's output for saturation before it commits the integration)."""
        if self.passes:
            return x
        return self._g * x + self._b1 * self._x1 + self._b2 * self._x2 \
            - self._a1 * self._y1 - self._a2 * self._y2

    def step(self, x: float) -> float:
        """Filter one sample; returns the output."""
        y = self._g * x + self._b1 * self._x1 + self._b2 * self._x2 \
            - self._a1 * self._y1 - self._a2 * self._y2
        self._x2 = self._x1
        self._x1 = x
        self._y2 = self._y1
        self._y1 = y
        return y


def _roots(c1, c2):
    """Roots of z^2 + c1 z + c2."""
    disc = cmath.sqrt(c1 * c1 - 4.0 * c2)
    return (-c1 + disc) / 2.0, (-c1 - disc) / 2.0
