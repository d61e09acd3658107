"""Proposing servo gains from a measured response: the maths of the `autotune` tool.

What a drive's tuner does after its Bode measurement (Kollmorgen WorkBench's Performance Servo
Tuner, Galil's and PMAC's auto-tuning): from the axis's response volts → motor and load position
(the two-mass model `identify` fits, and the measured points themselves), registers of this
package's PMAC PID are proposed for a preset, with the stability margins they give on the
*measured* open loop:

    L = z^−1 · F(z) · [ (kp + ki·T·z/(z − 1)) · G_pos + kd·(1 − z⁻¹)/T · G_vel ]

(identify.pid_open_loop: one tick of latency from the encoder sample to the command; F the
Ixx36–39 notch; `feedback` dual: G_pos the load, G_vel the motor, Galil DV; motor: both the
motor). The margins are computed twice, by identify.margins — on the fitted model over a dense
grid (it resolves the resonance and reaches to Nyquist) and on the measured points whose
coherence reaches 0.9 on motor and load — and the lower of the two is what the proposal promises.

The gains come from one shape and one scale. With J the axis's total inertia [V·s²/m] and ωc
the design crossover, as for a rigid body J s²:

    kd = J·ωc,   kp = kd·ωc / a,   ki = kp·ωc / (a·b)

(the PID's zeros at about ωc/a and ωc/(a·b): a = 3, b = 4 puts 45–60° of phase at the
crossover). For each shape (a, b) of a small grid, ωc is raised by bisection to the largest
value for which the margins meet the preset's targets and the crossover stays below the
preset's share of the first anti-resonance (a two-mass loop should not cross over above about
half of it). Of those, the largest ki wins (the stiffest at low frequency: what drives a
backlash gap or a friction offset out and ends a move; on the simulated slide it settled the
demo's moves about twice as fast as choosing the highest crossover or bandwidth did), then the
higher bandwidth.

The notch (Ixx36–39), by a rule a motion engineer would apply: a notch where the resonance
limits the loop, and only where it pays for its phase lag.

1. Without a notch, each shape stops at its largest crossover because something is missed just
   above it. The resonance holds that shape back when what is missed is a margin at a
   frequency at the resonance (RESONANCE_BAND: 0.75 × the anti-resonance to 1.3 × the
   resonance): the gain margin of the resonance's peak, or the phase margin where the peak
   crosses 0 dB. The phase margin at the crossover itself (latency, ZOH and the PID), or the
   preset's crossover limit, are not the resonance's doing, and no notch moves them.
2. Only the shapes the resonance holds back are tried with a notch, each with every notch of
   a family (_notch_candidates: zeros and poles at 1, 1.05 or 1.1 × the resonance, zeros ζ
   0.02–0.2 (depth), poles ζ 0.15–0.5 (width), core.notch.design with prewarp, at least 6 dB
   down at the resonance).
3. The best of them is proposed if it gives at least NOTCH_KEEP_GAIN (1.1) × the ki of the best
   gains without a notch (the preset's objective). Where no gains meet the preset without a
   notch, the best notch is taken; `notch=True` forces the best, `False` forbids one.

What that gives on the simulated slide (test_autotune.py, in the plant's own numbers): with
the screw ten times softer (resonance 77 Hz, anti-resonance 71 Hz), no notch, dual nor motor:
the crossover (32 Hz dual; motor at the preset's limit, half the anti-resonance) is bounded by
the phase margin there, not by the resonance, and a forced notch costs a third of the ki (its
lag below its centre). With a slide four times as heavy on that screw (slide / motor 0.65,
resonance 46 Hz, anti-resonance 36 Hz) the resonance's peak crosses 0 dB: without a notch the
gains keep a tenth of the ki, and a notch at the resonance (ζ 0.02–0.05 / 0.15) gives 9–10 ×
the ki. On the default slide (243 Hz) some shapes are held back by the resonance, but the best
notch buys only 4–5 % more ki: no notch.

Feedforward (on the command, outside the loop): kaff = J (the acceleration it cancels),
kvff = kd + viscous (PMAC form: kd acts on the actual velocity, kvff = kd cancels it on a move,
plus the viscous friction), friction_ff = the Coulomb friction (Ixx68), from identify's jogs,
and friction_ff_at_rest = AT_REST_SHARE (0.75) of it: at rest, pushed by the sign of a position
error outside the anti-hunting window, so the last counts of a move are not crept out by the
integrator against stiction (the demo's moves on the default slide in the harness: ~30 ms
instead of ~310 with the same gains). With `feedback` motor it is 0: pushed by the motor's
error, the motor breaks away alone inside the backlash gap (0.75 of the whole axis's friction
is more than its own) and the axis hunts at rest (the harness, the stiff proposal: output p-p
0.6-0.7 V at rest on the default slide and with the screw ten times softer, none of the moves
done; 0.01-0.09 V and done without the aid).

No rclpy: file input (identify's output folder) is here; the runs on a live axis are in
procedures/autotune.py, the figures in plotting/open_loop.py and plotting/steps.py, the command
in tools/autotune.py.
"""
from __future__ import annotations

import math
import pathlib
from dataclasses import dataclass, field

import numpy as np
import yaml

from motion_ctrl.analysis import identify as idf
from motion_ctrl.analysis import rest
from motion_ctrl.core import notch as nt
from motion_ctrl.core.registers import yaml_float

__all__ = ['Preset', 'PRESETS', 'AxisResponse', 'Evaluation', 'NotchChoice', 'Proposal',
           'FEEDBACKS', 'LATENCY_TICKS', 'evaluate', 'open_loops', 'propose', 'read_identify',
           'write_response', 'params_yaml', 'format_proposal',
           'MoveResult', 'move_result', 'format_verification']

LATENCY_TICKS = 1          # encoder sample -> command over DDS (as tools/tuning, doc/identify.md)
FEEDBACKS = ('dual', 'motor')
NOTCH_KEEP_GAIN = 1.10     # a notch must raise ki by 10 % to be worth its phase lag
#: the notch family (_notch_candidates): centre as a multiple of the resonance, zero damping
#: (depth), pole damping (width)
NOTCH_CENTRES = (1.0, 1.05, 1.1)
NOTCH_ZERO_DAMPING = (0.02, 0.05, 0.1, 0.2)
NOTCH_POLE_DAMPING = (0.15, 0.2, 0.3, 0.5)
NOTCH_MIN_CUT_DB = 6.0     # a candidate is a notch of the resonance: this much down there
#: "at the resonance": from this share of the anti-resonance to this multiple of the resonance
RESONANCE_BAND = (0.75, 1.3)
SHAPES = tuple((a, b) for a in (1.5, 2.0, 3.0, 4.0, 6.0) for b in (4.0, 8.0, 16.0))
#: the search asks this much more than the preset (grids differ; the gains are rounded)
SEARCH_PAD_DB, SEARCH_PAD_DEG = 0.2, 0.5
NOTCH_REGISTERS = ('notch_n1', 'notch_n2', 'notch_d1', 'notch_d2')
GAIN_REGISTERS = ('kp', 'ki', 'kd', 'kvff', 'kaff', 'friction_ff', 'friction_ff_at_rest') \
    + NOTCH_REGISTERS
#: friction_ff_at_rest as a share of the Coulomb friction: below 1, friction still stops the
#: slide once it breaks free; in the harness the demo's moves settled in ~30 ms from 0.7 to 0.9
#: (0.6: 140-180 ms, 1.0: 2.5 counts of overshoot; the integrator alone: 310 ms)
AT_REST_SHARE = 0.75
MIN_COHERENCE = 0.9
#: design crossovers [Hz] tried, lowest first, as the low end of each shape's bisection
LOW_CROSSOVERS_HZ = (0.5, 1.0, 2.0, 5.0, 10.0)


@dataclass(frozen=True)
class Preset:
    """Targets of a tuning: gain and phase margin, and the highest crossover as a share of the
    first anti-resonance."""
    name: str
    gain_margin_db: float
    phase_margin_deg: float
    bandwidth_fraction: float
    note: str


PRESETS = {
    'stiff': Preset('stiff', 8.0, 45.0, 0.5, 'Kollmorgen default 8 dB / 45°, crossover up to '
                    'half the first anti-resonance'),
    'medium': Preset('medium', 8.0, 45.0, 0.3, '8 dB / 45°, crossover up to 0.3 of the first '
                     'anti-resonance'),
    'soft': Preset('soft', 10.0, 55.0, 0.2, 'conservative 10 dB / 55°, crossover up to 0.2 of '
                   'the first anti-resonance'),
}


@dataclass
class AxisResponse:
    """An axis as identify measured it: the fitted model (sampled at `sample_period`, with
    `delay_ticks` as fitted), the measured responses volts → motor and load position (optional:
    without them the margins are the model's alone), and the friction of the jogs (Coulomb [V],
    viscous [V per m/s])."""
    model: idf.TwoMassModel
    sample_period: float
    delay_ticks: int = 0
    coulomb: float = 0.0
    viscous: float = 0.0
    motor: idf.FrequencyResponse | None = None
    load: idf.FrequencyResponse | None = None
    #: identify's friction each way [V], (positive, negative): the breakaway of its creeps and
    #: the Coulomb friction of its jogs (None: not measured)
    breakaway: tuple[float, float] | None = None
    coulomb_sides: tuple[float, float] | None = None

    def __post_init__(self):
        idf.positive('sample_period', self.sample_period)
        m = self.model
        for name in ('accel_per_volt', 'resonance_hz', 'antiresonance_hz'):
            idf.positive(name, getattr(m, name))
        nyq = 0.5 / self.sample_period
        if not m.antiresonance_hz < m.resonance_hz < nyq:
            raise ValueError(f'the model needs anti-resonance < resonance < Nyquist ({nyq:g} Hz), '
                             f'got {m.antiresonance_hz:g} and {m.resonance_hz:g} Hz')
        if (self.motor is None) != (self.load is None):
            raise ValueError('give both measured responses (motor and load) or neither')
        if self.motor is not None and self.load is not None and \
                not np.array_equal(self.motor.freq, self.load.freq):
            raise ValueError('the measured motor and load responses must share their frequencies')
        if not (math.isfinite(self.coulomb) and self.coulomb >= 0.0):
            raise ValueError(f'coulomb must be a finite number >= 0 V, got {self.coulomb!r}')
        if not math.isfinite(self.viscous):
            raise ValueError(f'viscous must be finite, got {self.viscous!r}')
        for name in ('breakaway', 'coulomb_sides'):
            v = getattr(self, name)
            if v is not None and not (len(v) == 2 and all(math.isfinite(x) and x >= 0.0
                                                          for x in v)):
                raise ValueError(f'{name} must be two finite numbers >= 0 V (positive, '
                                 f'negative), got {v!r}')

    def slip(self) -> float | None:
        """The slip [m] of the slide when it breaks away (analysis.rest.slip), the larger of
        the two directions; None without identify's breakaway."""
        if self.breakaway is None:
            return None
        sides = self.coulomb_sides or (self.coulomb, self.coulomb)
        return max(rest.slip(self.model, b, c) for b, c in zip(self.breakaway, sides))

    @property
    def inertia(self) -> float:
        """Total inertia [V·s²/m] (= kaff)."""
        return 1.0 / self.model.accel_per_volt

    @property
    def nyquist(self) -> float:
        return 0.5 / self.sample_period

    def grid(self, n=1200, band_points=201) -> np.ndarray:
        """Frequencies [Hz] for the model's margins: log-spaced to just below Nyquist, with the
        resonance and anti-resonance resolved (points spaced by a tenth of their width)."""
        m = self.model
        f = [np.geomspace(0.2, 0.999 * self.nyquist, n)]
        for fc, z in ((m.resonance_hz, m.resonance_damping),
                      (m.antiresonance_hz, m.antiresonance_damping)):
            w = max(z, 0.002) * fc
            f.append(np.linspace(max(fc - 10 * w, 0.2), min(fc + 10 * w, 0.999 * self.nyquist),
                                 band_points))
        return np.unique(np.concatenate(f))

    def plant(self, freq) -> tuple[np.ndarray, np.ndarray]:
        """Model (motor, load) responses [m/V] at `freq`, sampled and delayed as fitted."""
        kw = dict(sample_period=self.sample_period, delay_ticks=self.delay_ticks)
        return (self.model.response(freq, output='motor', **kw),
                self.model.response(freq, output='load', **kw))

    def measured(self, min_coherence=MIN_COHERENCE):
        """(freq, motor, load) of the measured points coherent on both, or None."""
        if self.motor is None or self.load is None:
            return None
        coh = np.minimum(self.motor.coherence, self.load.coherence)
        keep = (coh >= min_coherence) & np.isfinite(self.motor.response) \
            & np.isfinite(self.load.response)
        idx = np.flatnonzero(keep)
        # by frequency; where two runs measured the same frequency (identify's coarse and fine
        # stepped sines can meet), the more coherent point
        idx = idx[np.lexsort((-coh[idx], self.motor.freq[idx]))]
        f = self.motor.freq[idx]
        idx = idx[np.concatenate([[True], np.diff(f) > 0])]
        if idx.size < 2:
            return None
        return self.motor.freq[idx], self.motor.response[idx], self.load.response[idx]


def _loop(freq, gains, motor, load, feedback, period):
    pos, vel = (load, motor) if feedback == 'dual' else (motor, motor)
    return idf.pid_open_loop(freq, gains, period, pos, vel, latency_ticks=LATENCY_TICKS)


def _closed_bandwidth(freq, gains, motor, load, feedback, period) -> float:
    """-3 dB bandwidth [Hz] of the position loop, command -> position-loop encoder, without
    feedforward: z^-1·P·G_pos / (1 + L)."""
    pos = load if feedback == 'dual' else motor
    L = _loop(freq, gains, motor, load, feedback, period)
    notch = tuple(float(gains.get(k, 0.0)) for k in NOTCH_REGISTERS)
    P, _ = idf.pid_response(freq, kp=gains['kp'], ki=gains.get('ki', 0.0),
                            kd=gains.get('kd', 0.0), servo_period=period, notch=notch)
    z = np.exp(2j * math.pi * np.asarray(freq) * period)
    T = np.abs(z ** -LATENCY_TICKS * P * pos / (1.0 + L))
    below = np.flatnonzero(T < 1.0 / math.sqrt(2.0))
    if below.size == 0:
        return float(freq[-1])
    i = int(below[0])
    if i == 0:
        return float(freq[0])
    # interpolate on log frequency, linear in dB
    a, b = 20 * np.log10(T[i - 1]), 20 * np.log10(T[i])
    t = (-3.0103 - a) / (b - a) if b != a else 0.0
    return float(math.exp(math.log(freq[i - 1]) + t * (math.log(freq[i]) - math.log(freq[i - 1]))))


@dataclass
class Evaluation:
    """Registers on an axis: margins on the model (dense grid) and on the measured points (None
    without them); `gain_margin_db`, `phase_margin_deg`: the lower of the two; `crossover_hz`:
    the first gain crossover (model); `bandwidth_hz`: -3 dB of the position loop (model)."""
    registers: dict
    feedback: str
    model: idf.Margins
    measured: idf.Margins | None
    gain_margin_db: float
    phase_margin_deg: float
    crossover_hz: float | None
    bandwidth_hz: float

    def problems(self, preset: Preset) -> list:
        out = []
        if self.crossover_hz is None:
            out.append('no gain crossover')
        if self.phase_margin_deg < preset.phase_margin_deg:
            out.append(f'phase margin {self.phase_margin_deg:.1f}° < {preset.phase_margin_deg:g}°')
        if self.gain_margin_db < preset.gain_margin_db:
            out.append(f'gain margin {self.gain_margin_db:.1f} dB < {preset.gain_margin_db:g} dB')
        return out

    def ok(self, preset: Preset) -> bool:
        return not self.problems(preset)


def _check_feedback(feedback) -> str:
    if feedback == 'sampled':
        return 'motor'          # Galil's sampled dual loop: a motor loop between corrections
    if feedback not in FEEDBACKS:
        raise ValueError(f"feedback must be one of {', '.join(FEEDBACKS)} (or sampled, tuned as "
                         f"motor), got {feedback!r}: a loop closed on the load alone is not "
                         'collocated and not tuned here')
    return feedback


def _check_gains(gains) -> dict:
    out = {}
    for k in ('kp', 'ki', 'kd'):
        v = gains.get(k, 0.0) if k != 'kp' else gains.get('kp')
        if v is None:
            raise ValueError('registers need kp')
        if isinstance(v, bool) or not isinstance(v, (int, float, np.integer, np.floating)) \
                or not math.isfinite(v) or v < 0:
            raise ValueError(f'{k} must be a finite number >= 0, got {v!r}')
        out[k] = float(v)
    n = tuple(float(gains.get(k, 0.0)) for k in NOTCH_REGISTERS)
    nt.Biquad.validate(*n)
    out.update(zip(NOTCH_REGISTERS, n))
    return out


def evaluate(axis: AxisResponse, registers: dict, feedback: str = 'dual', *,
             freq=None) -> Evaluation:
    """Margins and bandwidth of `registers` (kp, ki, kd, notch_*) on the axis."""
    feedback = _check_feedback(feedback)
    g = _check_gains(registers)
    T = axis.sample_period
    f = axis.grid() if freq is None else np.asarray(freq, dtype=float)
    gm_, gl_ = axis.plant(f)
    m_model = idf.margins(f, _loop(f, g, gm_, gl_, feedback, T))
    m_meas = None
    meas = axis.measured()
    if meas is not None:
        fm, mm, ml = meas
        m_meas = idf.margins(fm, _loop(fm, g, mm, ml, feedback, T))
    gms = [m_model.gain_margin_db] + ([m_meas.gain_margin_db] if m_meas else [])
    pms = [m_model.phase_margin_deg] + ([m_meas.phase_margin_deg] if m_meas else [])
    cross = min(m_model.gain_crossovers_hz) if m_model.gain_crossovers_hz else None
    return Evaluation(dict(registers), feedback, m_model, m_meas, float(min(gms)),
                      float(min(pms)), cross, _closed_bandwidth(f, g, gm_, gl_, feedback, T))


def open_loops(axis: AxisResponse, ev: Evaluation) -> tuple:
    """The open loop L of an evaluation's registers on the axis, as autotune's open-loop plot
    draws it: ((freq, L) of the model over axis.grid(), (freq, L) of the measured points or
    None without them)."""
    g = _check_gains(ev.registers)
    T = axis.sample_period
    f = axis.grid()
    gm_, gl_ = axis.plant(f)
    model = (f, _loop(f, g, gm_, gl_, ev.feedback, T))
    meas = axis.measured()
    if meas is None:
        return model, None
    fm, mm, ml = meas
    return model, (fm, _loop(fm, g, mm, ml, ev.feedback, T))


@dataclass(frozen=True)
class NotchChoice:
    """A notch as designed (core.notch.design, prewarp): zeros and poles [Hz] with damping."""
    f_zero: float
    zeta_zero: float
    f_pole: float
    zeta_pole: float

    def registers(self, period) -> dict:
        c = nt.design(self.f_zero, self.zeta_zero, self.f_pole, self.zeta_pole, period,
                      prewarp=True)
        nt.Biquad.validate(*c)
        return dict(zip(NOTCH_REGISTERS, (float(x) for x in c)))


def _notch_candidates(axis: AxisResponse) -> list:
    """The notches tried: zeros and poles together at the resonance or a little above it (a
    notch's phase lag below its centre is what it costs at the crossover; above the resonance
    it costs less), zeros damped NOTCH_ZERO_DAMPING (depth ζz/ζp at the centre), poles
    NOTCH_POLE_DAMPING (width). Each designed by core.notch.design with prewarp (the discrete
    zeros at exp(sT) of the continuous ones); kept only if it is a notch of the resonance: at
    least NOTCH_MIN_CUT_DB down at the fitted resonance frequency."""
    fr = axis.model.resonance_hz
    T = axis.sample_period
    out = []
    for centre in NOTCH_CENTRES:
        for zz in NOTCH_ZERO_DAMPING:
            for zp in NOTCH_POLE_DAMPING:
                out.append(NotchChoice(centre * fr, zz, centre * fr, zp))
    ok = []
    for c in out:
        try:
            coeffs = tuple(c.registers(T).values())
        except ValueError:
            continue
        if nt.gain_db(coeffs, fr, T) <= -NOTCH_MIN_CUT_DB:
            ok.append(c)
    return ok


def _shape_gains(J, wc, a, b) -> dict:
    kd = J * wc
    kp = kd * wc / a
    return dict(kp=kp, ki=kp * wc / (a * b), kd=kd)


@dataclass
class Proposal:
    """The registers proposed for a preset, and what they give on the measured axis."""
    preset: Preset
    feedback: str
    registers: dict                      # GAIN_REGISTERS
    notch: NotchChoice | None
    evaluation: Evaluation
    cap_hz: float                        # the crossover limit of the preset
    limit: str                           # what bounded the crossover
    shape: tuple
    notes: list = field(default_factory=list)
    #: step 1 of the rule: without a notch, some PID shape stops at a margin missed at the
    #: resonance (or no gains meet the preset at all); whether a notch then pays is step 3
    resonance_limits: bool = False

    @property
    def ok(self) -> bool:
        return self.evaluation.ok(self.preset)


def _round(v, digits=4) -> float:
    if v == 0.0:
        return 0.0
    return float(f'{v:.{digits}g}')


def propose(axis: AxisResponse, preset: str | Preset = 'stiff', feedback: str = 'dual', *,
            notch: bool | None = None) -> Proposal:
    """Registers for `preset` (stiff, medium, soft) on `axis` with `feedback` dual or motor.

    notch: None = only where the resonance limits the loop (the default), False = never, True =
    always. Raises ValueError on bad input, and when no gains meet the preset's margins (the
    measured loop is too poor: more coherent points, a lower latency, or a softer preset).

    The steps (module docstring): the search without a notch, the shapes the resonance holds
    back (step 1), the search with the notches of the family (step 2), the notch decision
    (step 3), the result (rounded gains, feedforward, evaluated on the full grid)."""
    if isinstance(preset, str):
        if preset not in PRESETS:
            raise ValueError(f"preset must be one of {', '.join(PRESETS)}, got {preset!r}")
        preset = PRESETS[preset]
    feedback = _check_feedback(feedback)
    if notch not in (None, True, False):
        raise ValueError(f'notch must be None, True or False, got {notch!r}')
    search = _Search(axis, preset, feedback)
    plain_shapes = search.per_shape({}, SHAPES)
    plain = _best(plain_shapes)
    held = search.held_back(plain_shapes)
    candidates = _notch_candidates(axis)
    decision = _NotchDecision(notch, plain, held,
                              _notch_search(search, candidates, notch, plain, held),
                              len(candidates))
    notes = []
    if plain is not None:
        bound = search.binding(plain_shapes[plain[2]][2])
        fr, fa = axis.model.resonance_hz, axis.model.antiresonance_hz
        notes.append(f'without a notch: bounded by {_said(bound)} (PID zeros at crossover/'
                     f'{plain[2][0]:g}, /{plain[2][0] * plain[2][1]:g}; resonance {fr:.1f} Hz, '
                     f'anti-resonance {fa:.1f} Hz)')
    notes += decision.notes(axis)
    chosen, choice = (decision.with_notch if decision.keep else (plain, None))  # type: ignore[misc]
    if chosen is None:
        raise ValueError(f'no gains meet {preset.name} ({preset.gain_margin_db:g} dB, '
                         f'{preset.phase_margin_deg:g}°) on this axis with feedback {feedback}'
                         + ('' if notch is not False else ' without a notch'))
    return _proposal(axis, search, chosen, choice, notes,
                     bool(held) or plain is None)


class _Search:
    """The search of propose for one preset on one axis: the margins a set of registers gives
    on the search's grid (300 points, 81 across each resonance) and on the measured points, and
    each PID shape's largest crossover that meets the preset's targets (with SEARCH_PAD_DB and
    SEARCH_PAD_DEG) and its crossover limit, by bisection."""

    def __init__(self, axis: AxisResponse, preset: Preset, feedback: str):
        self.preset, self.feedback = preset, feedback
        self.T = axis.sample_period
        self.J = axis.inertia
        self.cap = preset.bandwidth_fraction * axis.model.antiresonance_hz
        self.f = axis.grid(300, 81)     # the search's grid; the result is evaluated on the full one
        self.gm_, self.gl_ = axis.plant(self.f)
        self.meas = axis.measured()
        self.gm_target = preset.gain_margin_db + SEARCH_PAD_DB
        self.pm_target = preset.phase_margin_deg + SEARCH_PAD_DEG
        self.top = 2 * math.pi * 0.6 * axis.model.antiresonance_hz   # the same for every preset
        #: "at the resonance" (step 1 of the rule)
        self.band = (RESONANCE_BAND[0] * axis.model.antiresonance_hz,
                     RESONANCE_BAND[1] * axis.model.resonance_hz)

    def model_margins(self, regs) -> idf.Margins:
        return idf.margins(self.f, _loop(self.f, regs, self.gm_, self.gl_, self.feedback, self.T))

    def measured_margins(self, regs) -> idf.Margins | None:
        if self.meas is None:
            return None
        fm, m_, l_ = self.meas
        return idf.margins(fm, _loop(fm, regs, m_, l_, self.feedback, self.T))

    def feasible(self, regs) -> tuple[bool, float | None]:
        """Whether `regs` meet the targets on the model and the measured points, and the first
        gain crossover on the model (None: none)."""
        mm = self.model_margins(regs)
        if not mm.gain_crossovers_hz:
            return False, None
        cross = min(mm.gain_crossovers_hz)
        if mm.gain_margin_db < self.gm_target or mm.phase_margin_deg < self.pm_target \
                or cross > self.cap:
            return False, cross
        me = self.measured_margins(regs)
        if me is not None:
            if me.gain_margin_db < self.gm_target or me.phase_margin_deg < self.pm_target:
                return False, cross
        return True, cross

    def binding(self, regs) -> list:
        """What the loop misses just above the largest feasible crossover (the bisection's
        infeasible end): [(what, frequency [Hz])]."""
        out = []
        loops = [('', self.model_margins(regs))]
        measured = self.measured_margins(regs)
        if measured is not None:
            loops.append((' (measured points)', measured))
        for where, mm in loops:
            if not mm.gain_crossovers_hz:
                continue
            if mm.phase_margin_deg < self.pm_target:
                out.append(('phase margin' + where, mm.crossover_hz))
            if mm.gain_margin_db < self.gm_target:
                out.append(('gain margin' + where, mm.phase_crossover_hz))
        cross = min(loops[0][1].gain_crossovers_hz or [0.0])
        if cross > self.cap:
            out.append(("the preset's crossover limit", self.cap))
        return out

    def held_back(self, shapes: dict) -> dict:
        """Step 1 of the rule: {shape: [(what, frequency)]} of the shapes of per_shape({}, ...)
        whose largest crossover stops at a margin missed at the resonance."""
        held = {s: _at_resonance(self.binding(v[2]), self.band) for s, v in shapes.items()}
        return {s: w for s, w in held.items() if w}

    def per_shape(self, nregs, shapes, beat=0.0) -> dict:
        """{shape: ((ki, bandwidth), registers, registers just above)}: each shape's largest
        feasible crossover (bisection), with the registers of its infeasible end. With `beat`
        > 0 only shapes that can give more ki: the bisection starts at the crossover that gives
        ki = beat (ki = J·ωc³/(a²·b)), and a shape infeasible there is left out (one look
        instead of a bisection: most notch candidates end there)."""
        out = {}
        for a, b in shapes:
            regs = lambda wc: _shape_gains(self.J, wc, a, b) | nregs   # noqa: E731
            lo = self._low_end(regs, a, b, beat)
            if lo is None:
                continue
            hi = math.log(self.top)
            for _ in range(11):
                mid = 0.5 * (lo + hi)
                if self.feasible(regs(math.exp(mid)))[0]:
                    lo = mid
                else:
                    hi = mid
            r = regs(math.exp(lo))
            bw = _closed_bandwidth(self.f, r, self.gm_, self.gl_, self.feedback, self.T)
            out[(a, b)] = ((r['ki'], round(bw, 1)), r, regs(math.exp(hi)))
        return out

    def _low_end(self, regs, a, b, beat) -> float | None:
        """The bisection's feasible low end, log ωc, for shape (a, b); None: the shape is left
        out."""
        if beat > 0.0:
            need = (beat * a * a * b / self.J) ** (1.0 / 3.0)
            if need >= self.top or not self.feasible(regs(need))[0]:
                return None
            return math.log(need)
        # The bisection needs a feasible low end. The lowest crossover is not always one: a
        # viscous pole fitted above it (the band starts at 20 Hz, so the fit barely sees it) can
        # keep the loop off 0 dB on the grid there.
        return next((math.log(2 * math.pi * f0) for f0 in LOW_CROSSOVERS_HZ
                     if self.feasible(regs(2 * math.pi * f0))[0]), None)


def _best(shapes: dict) -> tuple | None:
    """(key, registers, shape) of the largest ki, then bandwidth."""
    if not shapes:
        return None
    s = max(shapes, key=lambda k: shapes[k][0])
    return shapes[s][0], shapes[s][1], s


def _at_resonance(bound, band) -> list:
    return [(w, fq) for w, fq in bound if fq is not None and band[0] <= fq <= band[1]
            and 'crossover limit' not in w]


def _said(bound) -> str:
    return ', '.join(f'{w} at {fq:.1f} Hz' for w, fq in bound if fq is not None) \
        or 'nothing on the grid'


@dataclass
class _NotchDecision:
    """Step 3 of the rule: `plain` the best gains without a notch ((ki, bandwidth), registers,
    shape; None: no gains meet the preset without one), `held` the shapes the resonance holds
    back (step 1), `with_notch` the best gains with a notch of the family ((...), NotchChoice;
    None: none better), of `candidates` notches; `notch` as propose was asked."""
    notch: bool | None
    plain: tuple | None
    held: dict
    with_notch: tuple | None
    candidates: int

    @property
    def gain(self) -> float | None:
        """ki with the notch over ki without."""
        if self.with_notch is None or self.plain is None:
            return None
        return self.with_notch[0][0][0] / self.plain[0][0]

    @property
    def deserved(self) -> bool:
        """The rule proposes the notch: no gains without one, or a shape the resonance holds
        back gets NOTCH_KEEP_GAIN × the ki with it."""
        gain = self.gain
        return self.plain is None or (self.with_notch is not None
                                      and self.with_notch[0][2] in self.held
                                      and gain is not None and gain >= NOTCH_KEEP_GAIN)

    @property
    def keep(self) -> bool:
        return self.with_notch is not None and (self.notch is True or self.deserved)

    def notes(self, axis: AxisResponse) -> list:
        """Why there is a notch or none, as the proposal's notes say it."""
        fr, T = axis.model.resonance_hz, axis.sample_period
        plain, with_notch, held, gain = self.plain, self.with_notch, self.held, self.gain
        desc, nki, pki = '', 0.0, (plain[0][0] if plain is not None else 0.0)
        if with_notch is not None:
            c, ws, nki = with_notch[1], with_notch[0][2], with_notch[0][0][0]
            desc = (f'{c.f_zero:.1f} Hz, ζ {c.zeta_zero:g} / {c.zeta_pole:g}, '
                    f'{-nt.gain_db(tuple(c.registers(T).values()), fr, T):.1f} dB down at the '
                    f'resonance; PID zeros at crossover/{ws[0]:g}, /{ws[0] * ws[1]:g}')
        if self.keep and plain is None:
            return [f'notch ({desc}): no gains meet the margins without one']
        if self.keep and not self.deserved:
            return [f'notch ({desc}): asked for (--notch on); ki {nki:.4g} with '
                    f'it, {pki:.4g} without (the rule would not propose it)']
        if self.keep:
            return [f'notch ({desc}): ki {nki:.4g} with it, '
                    f'{pki:.4g} without ({gain:.2f} ×); without it these gains stop '
                    f'at {_said(held[ws])}: the resonance limits the loop']
        if self.notch is not None or plain is None:
            return []
        if not held:
            return [f'no notch: the resonance does not limit the loop (none of the '
                    f'{len(SHAPES)} PID shapes stops at a margin missed at the resonance '
                    'without one)']
        if with_notch is None:
            return [f'no notch: {len(held)} of {len(SHAPES)} PID shapes stop at the '
                    f'resonance without one, but none of the {self.candidates} notches of '
                    f'the family gives them {NOTCH_KEEP_GAIN:g} × the ki without one '
                    f'({pki:.4g}): their phase lag at the crossover costs more than their '
                    'cut at the resonance buys']
        return [f'no notch: {len(held)} of {len(SHAPES)} PID shapes stop at the '
                f'resonance without one, but the best notch of the family ({desc}) '
                f'gives ki {nki:.4g}, without {pki:.4g} '
                f'({gain:.2f} ×, under {NOTCH_KEEP_GAIN:g} ×): its phase lag at the '
                'crossover costs more than its cut at the resonance buys']


def _notch_search(search: _Search, candidates: list, notch: bool | None, plain: tuple | None,
                  held: dict) -> tuple | None:
    """Step 2 of the rule: each notch of the family with the shapes the resonance holds back
    (every shape where a notch is asked for or no gains meet the preset without one). By
    default only a notch that pays is of interest: the search looks for ki above
    NOTCH_KEEP_GAIN × the best without one, and then above the best notch so far. Returns
    (best gains, NotchChoice) or None."""
    shapes = SHAPES if notch is True or plain is None else tuple(s for s in SHAPES if s in held)
    with_notch = None
    floor = NOTCH_KEEP_GAIN * plain[0][0] if notch is None and plain is not None else 0.0
    if notch is not False and shapes:
        for c in candidates:
            beat = max(floor, with_notch[0][0][0] if with_notch is not None else 0.0)
            got = _best(search.per_shape(c.registers(search.T), shapes, beat))
            if got is not None and (with_notch is None or got[0] > with_notch[0][0]):
                with_notch = (got, c)
    return with_notch


def _proposal(axis: AxisResponse, search: _Search, chosen: tuple, choice: NotchChoice | None,
              notes: list, resonance_limits: bool) -> Proposal:
    """The result: the chosen gains rounded to 4 digits, the notch's coefficients as designed,
    evaluated on the full grid; then the feedforward (module docstring: kvff = kd + viscous,
    kaff = J, friction_ff = Coulomb, friction_ff_at_rest = AT_REST_SHARE of it with the dual
    loop)."""
    feedback = search.feedback
    _, regs, shape = chosen
    regs = {k: _round(v) for k, v in regs.items() if k in ('kp', 'ki', 'kd')} | \
        {k: float(v) for k, v in regs.items() if k.startswith('notch_')}
    regs |= {k: 0.0 for k in NOTCH_REGISTERS if k not in regs}
    ev = evaluate(axis, regs, feedback)
    cross = ev.crossover_hz or 0.0
    limit = ("the preset's crossover limit" if cross >= 0.97 * search.cap else 'the margins')
    kd = regs['kd']
    friction = max(axis.coulomb, 0.0)
    regs = dict(kp=regs['kp'], ki=regs['ki'], kd=kd,
                kvff=_round(kd + max(axis.viscous, 0.0)), kaff=_round(search.J),
                friction_ff=_round(friction),
                friction_ff_at_rest=_round(AT_REST_SHARE * friction if feedback == 'dual'
                                           else 0.0)) \
        | {k: regs[k] for k in NOTCH_REGISTERS}
    ev.registers = dict(regs)
    return Proposal(search.preset, feedback, regs, choice, ev, search.cap, limit, shape, notes,
                    resonance_limits)


# ================================================================================================
# files: identify's output in, ros2 param load YAML out

RESPONSE_FILE = 'response.csv'
RESPONSE_HEADER = 'freq_hz,motor_re,motor_im,motor_coherence,load_re,load_im,load_coherence'


def write_response(path, motor: idf.FrequencyResponse, load: idf.FrequencyResponse) -> None:
    """The measured responses as CSV (identify writes it beside identify.yaml)."""
    if not np.array_equal(motor.freq, load.freq):
        raise ValueError('motor and load responses must share their frequencies')
    a = np.column_stack([motor.freq, motor.response.real, motor.response.imag, motor.coherence,
                         load.response.real, load.response.imag, load.coherence])
    np.savetxt(path, a, delimiter=',', header=RESPONSE_HEADER, comments='', fmt='%.10g')


def read_identify(folder) -> AxisResponse:
    """An identify output folder (identify.yaml, and response.csv when it is there) as an
    AxisResponse. Raises ValueError naming what is missing or wrong."""
    d = pathlib.Path(folder)
    if d.is_file():
        d = d.parent
    path = d / 'identify.yaml'
    if not path.is_file():
        raise ValueError(f'{path}: not found (run identify first: it writes identify.yaml)')
    try:
        r = yaml.safe_load(path.read_text())
    except yaml.YAMLError as e:
        raise ValueError(f'{path}: not YAML: {e}') from None
    if not isinstance(r, dict):
        raise ValueError(f'{path}: not an identify result')
    need = ('accel_per_volt', 'resonance_hz', 'resonance_damping', 'antiresonance_hz',
            'antiresonance_damping', 'delay_ticks')
    missing = [k for k in need if k not in r]
    if missing:
        raise ValueError(f'{path}: missing {", ".join(missing)}')
    period = float(r.get('sample_period', 1e-3))
    model = idf.TwoMassModel(float(r['accel_per_volt']), float(r.get('viscous_pole', 0.05)),
                             float(r['resonance_hz']), float(r['resonance_damping']),
                             float(r['antiresonance_hz']), float(r['antiresonance_damping']),
                             float(r.get('load_zero', 0.0)))
    motor = load = None
    csv = d / RESPONSE_FILE
    if csv.is_file():
        try:
            a = np.loadtxt(csv, delimiter=',', skiprows=1, ndmin=2)
        except ValueError as e:
            raise ValueError(f'{csv}: {e}') from None
        if a.shape[1] != 7:
            raise ValueError(f'{csv}: expected 7 columns ({RESPONSE_HEADER})')
        rate = 1.0 / period
        motor = idf.FrequencyResponse(a[:, 0], a[:, 1] + 1j * a[:, 2], a[:, 3], rate,
                                      'stepped_sine')
        load = idf.FrequencyResponse(a[:, 0], a[:, 4] + 1j * a[:, 5], a[:, 6], rate,
                                     'stepped_sine')
    sides = {k: (float(r[f'{k}_pos']), float(r[f'{k}_neg'])) if f'{k}_pos' in r else None
             for k in ('breakaway', 'coulomb')}
    return AxisResponse(model, period, int(r['delay_ticks']), float(r.get('coulomb', 0.0)),
                        float(r.get('viscous', 0.0)), motor, load, sides['breakaway'],
                        sides['coulomb'])


def params_yaml(registers: dict, axis: str = 'x', node: str = 'controller',
                comment: str = '') -> str:
    """`ros2 param load` YAML of the registers (every value a double, core.registers.yaml_float)."""
    lines = [f'# {line}' for line in comment.splitlines()]
    lines += [f'{node}:', '  ros__parameters:']
    lines += [f'    {axis}.{k}: {v if isinstance(v, str) else yaml_float(v)}'
              for k, v in registers.items()]
    return '\n'.join(lines) + '\n'


def _fmt_margins(ev: Evaluation) -> str:
    meas = ''
    if ev.measured is not None:
        pm = (f'{ev.measured.phase_margin_deg:.1f}°' if ev.measured.crossover_hz is not None
              else 'no gain crossover among them')
        gm = (f'{ev.measured.gain_margin_db:.1f} dB' if math.isfinite(ev.measured.gain_margin_db)
              else 'no phase crossover among them')
        meas = (f' (measured points: {gm}, {pm}; model: {ev.model.gain_margin_db:.1f} dB, '
                f'{ev.model.phase_margin_deg:.1f}°)')
    cross = f'{ev.crossover_hz:.1f} Hz' if ev.crossover_hz is not None else 'none'
    return (f'gain margin {ev.gain_margin_db:.1f} dB, phase margin {ev.phase_margin_deg:.1f}°'
            f'{meas}; crossover {cross}, bandwidth {ev.bandwidth_hz:.1f} Hz')


def format_proposal(p: Proposal, before: Evaluation | None = None) -> str:
    """The proposal as text: registers (before and proposed), margins, bandwidth, notes."""
    lines = [f'autotune: preset {p.preset.name} ({p.preset.note}), feedback {p.feedback}']
    lines.append('| register | before | proposed |')
    lines.append('|---|---:|---:|')
    for k, v in p.registers.items():
        b = '' if before is None or k not in before.registers else \
            f'{float(before.registers[k]):.6g}'
        lines.append(f'| {k} | {b} | {v:.6g} |')
    if p.notch is not None:
        n = p.notch
        lines.append(f'notch: zeros {n.f_zero:.1f} Hz ζ {n.zeta_zero:.3f}, poles {n.f_pole:.1f} '
                     f'Hz ζ {n.zeta_pole:.2f} (core.notch.design, prewarp)')
    if before is not None:
        lines.append(f'before:   {_fmt_margins(before)}')
    lines.append(f'proposed: {_fmt_margins(p.evaluation)}')
    lines.append(f'crossover limit of the preset {p.cap_hz:.1f} Hz '
                 f'({p.preset.bandwidth_fraction:g} of the anti-resonance); bounded by '
                 f'{p.limit}; PID zeros at crossover/{p.shape[0]:g} and '
                 f'/{p.shape[0] * p.shape[1]:g}')
    lines += p.notes
    verdict = 'meets' if p.ok else 'MISSES'
    lines.append(f'{verdict} the preset\'s {p.preset.gain_margin_db:g} dB / '
                 f'{p.preset.phase_margin_deg:g}°' +
                 ('' if p.ok else ': ' + '; '.join(p.evaluation.problems(p.preset))))
    return '\n'.join(lines)


# ================================================================================================
# verification: the moves, measured on the controller's own joint_states

@dataclass
class MoveResult:
    """One verified move: `settle_ms` from the end of the profile (AT_TARGET) to MOTION_DONE
    (inf: none), `overshoot` past the target in the direction of the move and `final_error`
    at rest [load counts], `output_pp` the output's peak-to-peak at rest [V]; `rest` whether it
    came to rest and stayed (analysis.rest.judge: after MOTION_DONE neither the reading nor
    the output turned back; without it the limit cycle's period and amplitude); the trace
    (time from the end of the profile [s], error [counts], output [V]) for the plot."""
    label: str
    target: float
    settle_ms: float
    overshoot: float
    final_error: float
    output_pp: float
    t: np.ndarray
    error: np.ndarray
    rest: rest.Judgement
    output: np.ndarray = field(default_factory=lambda: np.zeros(0))
    #: the true slide error at the end [counts], where a simulated plant gives it (--spawn)
    true_error: float | None = None

    @property
    def settled(self) -> bool:
        return self.rest.settled


def move_result(label, target, start, t, position, effort, t_end, t_done, counts_per_m,
                coulomb: float) -> MoveResult:
    """Metrics of a move from the controller's samples (stamp t [s], load position [m],
    output [V]): t_end the end of the profile, t_done MOTION_DONE (None: not raised); the
    samples after MOTION_DONE are the rest (final error: their mean over the last half;
    output_pp: their spread), judged by analysis.rest.judge with the axis's Coulomb friction
    [V]."""
    t = np.asarray(t, dtype=float)
    pos = np.asarray(position, dtype=float)
    eff = np.asarray(effort, dtype=float)
    if t.size == 0 or t.size != pos.size or t.size != eff.size:
        raise ValueError('move_result needs samples of equal length')
    sign = 1.0 if target >= start else -1.0
    err = (pos - target) * counts_per_m
    rest_from = t_done if t_done is not None else (t_end if t_end is not None else t[0])
    at_rest = t >= rest_from
    if not np.any(at_rest):
        raise ValueError('no samples at rest')
    last = at_rest & (t >= 0.5 * (rest_from + t[-1]))
    settle = math.inf if t_done is None or t_end is None else max(t_done - t_end, 0.0) * 1e3
    over = max(0.0, float(np.max(sign * err)))
    ref = t_end if t_end is not None else float(t[0])
    judged = rest.judge(t, pos, eff, t_end, t_done, counts_per_m, coulomb)
    # (rounded: the readings of a count off give 1 ± 1e-10 counts)
    return MoveResult(label, float(target), settle, over, round(float(np.mean(err[last])), 6),
                      float(np.ptp(eff[at_rest])), t - ref, err, judged, eff)


def format_verification(runs: dict, evaluations: dict) -> str:
    """Before/after table: per move settle time, overshoot, final error, output p-p and rest
    (at rest, or why not: the limit cycle's period and amplitude); then the median settle
    time and the margins and bandwidth of each set."""
    truth = any(m.true_error is not None for v in runs.values() for m in v)
    lines = ['| gains | move | settle [ms] | overshoot [counts] | final error [counts] | '
             + ('slide (plant) [counts] | ' if truth else '')
             + 'output p-p at rest [V] | rest |',
             '|---|---|---:|---:|---:|' + ('---:|' if truth else '') + '---:|---|']
    for name, moves in runs.items():
        for m in moves:
            s = f'{m.settle_ms:.0f}' if math.isfinite(m.settle_ms) else 'no MOTION_DONE'
            true = ('' if not truth else '- | ' if m.true_error is None
                    else f'{m.true_error:+.2f} | ')
            lines.append(f'| {name} | {m.label} | {s} | {m.overshoot:.2f} | '
                         f'{m.final_error:+.2f} | {true}{m.output_pp:.3f} | '
                         f'{m.rest.describe()} |')
    lines.append('')
    lines.append('| gains | median settle [ms] | moves at rest | gain margin [dB] | '
                 'phase margin [°] | crossover [Hz] | bandwidth [Hz] |')
    lines.append('|---|---:|---:|---:|---:|---:|---:|')
    for name, moves in runs.items():
        ev = evaluations[name]
        med = float(np.median([m.settle_ms for m in moves]))
        cross = f'{ev.crossover_hz:.1f}' if ev.crossover_hz is not None else '-'
        rested = sum(m.settled for m in moves)
        lines.append(f'| {name} | {med:.0f} | {rested} of {len(moves)} | '
                     f'{ev.gain_margin_db:.1f} | {ev.phase_margin_deg:.1f} | {cross} | '
                     f'{ev.bandwidth_hz:.1f} |')
    return '\n'.join(lines)
