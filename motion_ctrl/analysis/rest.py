"""The settings of an axis at rest on a sticky slide, and the judgement of rest: what autotune
proposes besides the gains, and how its verification tells a settled axis from a hunting one.

A slide whose breakaway friction F_b exceeds its sliding (Coulomb) friction F_c, driven through
a compliant screw, cannot be pushed a small distance: the motor compresses the screw until the
spring force reaches F_b, the slide breaks away, friction drops to F_c, and the spring's stored
excess throws it on by the slip

    slip = 2·(F_b − F_c) / k · J_motor / J                                            (1)

(a mass released on a spring against a constant friction travels twice the spring's excess
deflection; the motor side, J_motor of the total inertia J, takes the rest of the spring's
relaxation: J_motor / J = (f_a / f_r)², the anti-resonance over the resonance). On the default
slide that is 0.03 counts; with twice its stiction on a screw five times softer, 1.4 counts. A
window narrower than the slip can be jumped: the slide sticks a count short, the integrator
winds up until it breaks away, it sticks a count past, and so on (a stick-slip limit cycle,
never MOTION_DONE). The RMC's answer (Deadband Tolerance, shared/seeds/000): inside a window
around the target the integrator may only wind down, so a slide that lands inside stays; the
window must then be at least one slip wide, and MOTION_DONE's fine window the same.

The rule (`candidates`, then test moves over the axis, `search`):

* **Window** (`deadband_tolerance`, `fine_position_tolerance`, `window_centre`): the exact
  count as shipped (the encoder's reading, half a count: the slide within 0 ... +1 count of a
  target on a whole count) where the slip of (1), from identify's breakaway, Coulomb friction,
  stiffness and inertia split, is under a count; else the narrowest of ±1, ±1.5, ±2, ±3 counts
  that covers it: judged on the middle of the count the encoder reads (`window_centre`
  count_middle: a quadrature counter reads the lower edge of its count, so a window of whole
  readings around the target would lie half a count high on the slide), ±W counts around the
  target hold at least floor(2W) readings, the slide within ±(W + ½) counts of any target and
  ±W of one on a whole count (±1 count: the two readings either side of it). The tolerances are
  W + 0.01 counts so that a reading exactly W off is inside.
* **Breakaway aid** (`friction_ff_at_rest`): 0.75 × the Coulomb friction as autotune's gains
  proposal has it, or 0.5 × if the test moves hunt with 0.75 (the aid is a relay outside the
  window: too strong, it throws the motor across the backlash and the slide through the window).
* The candidates are tried in that order (none where the slip is under half a count: the exact
  count holds it twice over), windows from the narrowest the slip allows up, each
  with the two aids: the first under which none of the short test moves (both ways, long and
  short, on and between counts, steps of a few counts from rest) hunts is proposed (hunting:
  the slide pushed past the window and back, or moving after MOTION_DONE; a move that is only
  slow, or whose output rings with the slide still, is not the window's to fix). The accuracy
  promised is its window's.
* **Settling time**: at least one period of the slide on its screw (1 / f_a: a slip in progress
  ends within half of one), else as the axis has it.
* **Output deadband**: 0. It compensates an amplifier or valve deadband (none is measured: the
  jogs' output is Coulomb plus viscous) and, ratioed inside the window, it would keep pushing
  there, where the slide must be left alone.
* **Ixx34** (`integration_mode`): always, as shipped. Holding the integrator during moves
  starts each rest with the previous rest's push, whichever way that was; with the window it
  settled the sticky slides no better in the harness (doc/rest.md), without it left more moves
  unsettled.

Rest, judged from samples (`judge`): a move is settled when MOTION_DONE came and afterwards, for
the whole rest watched, the slide's reading does not change and the output does not turn back
(a turn: the output, its 5-sample median taken so that one tick's kd kick on a motor count is
not one, moving back by more than TURN_SHARE of the Coulomb friction; a monotonic wind-down of
the integrator is not a turn). Without MOTION_DONE the record is described as a limit cycle:
its period (twice the mean time between reversals of the output's sign, each side held
REVERSAL_HOLD_S, as core.hunting counts them) and its amplitude (half the slide's spread from
the first reversal on).
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Callable

import numpy as np
from numpy.lib.stride_tricks import sliding_window_view

__all__ = ['WINDOWS', 'AID_SHARES', 'TURN_SHARE', 'slip', 'coverage', 'promise', 'Candidate',
           'candidates', 'Plan', 'plan', 'Trial', 'search', 'Judgement', 'judge', 'turns',
           'sign_reversals', 'REST_REGISTERS', 'describe_promise', 'TEST_MOVES',
           'TEST_TIMEOUT', 'TEST_REST']

#: anti-hunting half-widths tried [counts]; 0 is the exact count as shipped
WINDOWS = (0.0, 1.0, 1.5, 2.0, 3.0)
#: breakaway aid tried, as a share of the Coulomb friction (autotune's gains proposal: 0.75)
AID_SHARES = (0.75, 0.5)
#: a slip under this [counts] the exact count holds twice over: no test moves are made
SURE_SLIP = 0.5
#: the tolerances are this much [counts] over the window: a reading exactly on it is inside
WINDOW_HAIR = 0.01
#: an output that moves back by this share of the Coulomb friction has turned
TURN_SHARE = 0.05
#: a reversal of the output's sign counts once the new side has held this long [s]
REVERSAL_HOLD_S = 0.01
REVERSAL_BAND_V = 1e-3
#: the test moves of a trial [counts of the slide's encoder from 0]: both ways, long and short,
#: on whole counts and between them, then steps of a few counts from rest (each a breakaway)
TEST_MOVES = (200, -200.5, 40, -40.5, 7, -7, 1000, -1000.3,
              -997, -1000, -995, -994, -998, -996, -998.5, -992)
TEST_TIMEOUT = 2.0          # s from a test move's command to MOTION_DONE, else it fails
TEST_REST = 0.5             # s watched at rest after a test move's MOTION_DONE
#: what the rule sets (and the verification puts back on failure)
REST_REGISTERS = ('deadband_tolerance', 'fine_position_tolerance', 'window_centre',
                  'friction_ff_at_rest', 'settling_time', 'output_deadband', 'integration_mode')
#: the exact count as shipped (the register table's values; params/controller.yaml sets
#: window_centre count_middle for the shipped slide by hand, doc/gains.md)
SHIPPED = dict(deadband_tolerance=0.0, window_centre='reading', fine_position_tolerance=1.5e-6)


def slip(model, breakaway: float, coulomb: float) -> float:
    """The slip (1) [m] of a slide that breaks away at `breakaway` [V] and slides at `coulomb`
    [V], on the two-mass `model` (identify's: total inertia 1/K, resonance and anti-resonance);
    0 when the breakaway is not above the sliding friction."""
    fr, fa = model.resonance_hz, model.antiresonance_hz
    share = (fa / fr) ** 2                        # J_motor / J
    inertia = 1.0 / model.accel_per_volt
    stiffness = inertia * (1.0 - share) * (2.0 * math.pi * fa) ** 2     # J_slide·ω_a² [V/m]
    return max(0.0, 2.0 * (breakaway - coulomb) / stiffness * share)


def coverage(window: float) -> int:
    """Readings [counts of slide] a window of ±`window` counts (count_middle) holds around any
    target at the least; the exact count (0) holds one."""
    return 1 if window == 0.0 else int(math.floor(2.0 * window + 1e-9))


def promise(window_centre: str, fine_counts: float) -> tuple[tuple[float, float],
                                                              tuple[float, float]]:
    """Where the slide stops relative to the target [counts], given a fine window of
    ±`fine_counts` counts: ((low, high) for a target on a whole count, (low, high) for any
    target). The encoder reads the lower edge of the count the slide is in."""
    f = fine_counts
    if window_centre == 'count_middle':
        return ((float(math.ceil(-f - 0.5 - 1e-9)), float(math.floor(f - 0.5 + 1e-9) + 1)),
                (-f - 0.5, f + 0.5))
    n = math.floor(f + 1e-9)
    return (float(-n), float(n + 1)), (-f, f + 1.0)


def describe_promise(window_centre: str, fine_counts: float) -> str:
    (lo, hi), (alo, ahi) = promise(window_centre, fine_counts)
    on = f'±{hi:g} count{"s" if hi != 1 else ""}' if lo == -hi else f'{lo:+g} ... {hi:+g} count'
    return (f'{on} of a target on a whole count of the encoder, {alo:+.2f} ... {ahi:+.2f} of one '
            'between counts')


@dataclass(frozen=True)
class Candidate:
    """Rest settings to try: the anti-hunting window ±`window` counts (0: the exact count as
    shipped) and the breakaway aid as a share of the Coulomb friction."""
    window: float
    aid_share: float

    def registers(self, current: dict, counts_per_m: float, coulomb: float,
                  antiresonance_hz: float) -> dict:
        """The REST_REGISTERS for an axis with `current` registers, an encoder of
        `counts_per_m` on its position loop, `coulomb` [V] and its slide on the screw at
        `antiresonance_hz`."""
        if self.window == 0.0:
            out = dict(SHIPPED)
        else:
            tol = (self.window + WINDOW_HAIR) / counts_per_m
            out = dict(deadband_tolerance=tol, fine_position_tolerance=tol,
                       window_centre='count_middle')
        settle = max(float(current.get('settling_time', 0.02)),
                     math.ceil(1e3 / antiresonance_hz) / 1e3)
        return out | dict(friction_ff_at_rest=_round(self.aid_share * coulomb),
                          settling_time=settle, output_deadband=0.0, integration_mode='always')

    def __str__(self) -> str:
        w = 'the exact count (as shipped)' if self.window == 0.0 else f'±{self.window:g} counts'
        return f'window {w}, breakaway aid {self.aid_share:g} × Coulomb'


def _round(v: float, digits: int = 4) -> float:
    return 0.0 if v == 0.0 else float(f'{v:.{digits}g}')


def candidates(slip_counts: float) -> list[Candidate]:
    """The rest settings to try, in order: from the narrowest window that holds a slip of
    `slip_counts` (the exact count only where the slip is under a count) up, each with the
    aids of AID_SHARES."""
    if not (math.isfinite(slip_counts) and slip_counts >= 0.0):
        raise ValueError(f'slip must be a finite number >= 0 counts, got {slip_counts!r}')
    first = next((i for i, w in enumerate(WINDOWS) if coverage(w) >= slip_counts
                  and (w > 0.0 or slip_counts < 1.0)), len(WINDOWS) - 1)
    return [Candidate(w, s) for w in WINDOWS[first:] for s in AID_SHARES]


@dataclass
class Plan:
    """What the rule will try on an axis: the slip it predicts [counts] (None: identify
    measured no breakaway), the candidates in order, and a control: the rest settings as
    shipped, tried first for the record where the plan leaves them out (they are what the gains
    alone would run with)."""
    slip_counts: float | None
    candidates: list
    control: Candidate | None
    notes: list = field(default_factory=list)

    @property
    def test(self) -> bool:
        """Whether test moves are worth making: not where the slip is known to be under
        SURE_SLIP (the exact count holds it twice over) or the loop does not see the slide."""
        return len(self.candidates) > 1 and (self.slip_counts is None
                                             or self.slip_counts >= SURE_SLIP)


def plan(slip_m: float | None, counts_per_m: float, feedback: str) -> Plan:
    """The rule's plan for an axis whose slide slips `slip_m` [m] when it breaks away (None:
    not measured), its position loop on an encoder of `counts_per_m`, `feedback` as tuned."""
    if feedback not in ('dual', 'load'):
        return Plan(None, [Candidate(0.0, 0.0)], None, [
            f'rest: feedback {feedback}: the position loop does not see the slide, so its '
            'stick-slip is not the loop\'s to settle; the windows as shipped, no breakaway aid '
            '(pushed by the motor\'s error the motor breaks away alone in the backlash)'])
    if slip_m is None:
        return Plan(None, candidates(0.0), None, [
            'rest: identify measured no breakaway friction (no creep): the slip is not '
            'predicted; windows tried from the exact count up'])
    counts = slip_m * counts_per_m
    cands = candidates(counts)
    control = None if cands[0].window == 0.0 else Candidate(0.0, AID_SHARES[0])
    how = ('under a count: the exact count holds it' if cands[0].window == 0.0 else
           f'a window of ±{cands[0].window:g} counts is the narrowest that holds it')
    return Plan(counts, cands, control, [
        f'rest: the slide slips {counts:.2f} counts when it breaks away (2·(breakaway − '
        f'Coulomb) / stiffness · motor share of the inertia, from identify): {how}'])


@dataclass
class Trial:
    """What the test moves of one candidate gave: all at rest or not, why not, the settle times
    [ms] of those that rested."""
    candidate: Candidate
    ok: bool
    reason: str = ''
    settle_ms: list = field(default_factory=list)
    failed: object = None           # the record of the move that did not rest, when kept
    moves: int = 0                  # test moves made
    hunted: int = 0                 # ... of which hunted

    def describe(self) -> str:
        if not self.ok:
            return self.reason
        med = f', median settle {float(np.median(self.settle_ms)):.0f} ms' \
            if self.settle_ms else ''
        return f'no test move hunted ({len(self.settle_ms)} reached MOTION_DONE{med})'


def search(cands: list[Candidate], trial: Callable[[Candidate], Trial],
           log=print) -> tuple[Candidate | None, list[Trial]]:
    """The first candidate whose test moves all come to rest (None: none did), and every
    trial made."""
    made = []
    for c in cands:
        t = trial(c)
        made.append(t)
        if t.ok:
            log(f'rest: {c}: {t.describe()}')
            return c, made
        log(f'rest: {c}: {t.reason}')
    return None, made


# ------------------------------------------------------------------------------------------------
# rest, judged from samples

def _median5(x: np.ndarray) -> np.ndarray:
    if x.size < 5:
        return x
    return np.median(sliding_window_view(x, 5), axis=1)


def turns(output, band: float) -> int:
    """How often the output turns back by more than `band` [V] (a peak detector with
    hysteresis on its 5-sample median)."""
    x = _median5(np.asarray(output, dtype=float))
    if x.size < 2:
        return 0
    n, direction, extreme = 0, 0, x[0]
    for v in x[1:]:
        if direction == 0:                      # no direction yet: from the first sample
            if abs(v - x[0]) > band:
                direction, extreme = (1 if v > x[0] else -1), v
        elif direction * (v - extreme) > 0.0:
            extreme = v                         # further the same way
        elif abs(v - extreme) > band:
            n += 1
            direction, extreme = -direction, v
    return n


def sign_reversals(t, output, hold: float = REVERSAL_HOLD_S,
                   band: float = REVERSAL_BAND_V) -> list:
    """Times [s] at which the output's sign reversed, each new side held `hold` beyond `band`
    (core.hunting's count, from samples)."""
    t = np.asarray(t, dtype=float)
    u = np.asarray(output, dtype=float)
    out, side, pending, since = [], 0, 0, 0.0
    for ti, ui in zip(t, u):
        s = 1 if ui > band else -1 if ui < -band else 0
        if s == 0 or s == side:
            pending = 0
            continue
        if s != pending:
            pending, since = s, ti
        if ti - since + 1e-9 >= hold:
            if side:
                out.append(float(ti))
            side, pending = s, 0
    return out


@dataclass
class Judgement:
    """A move's rest: `settled` (MOTION_DONE, then neither the slide's reading changed nor the
    output turned for the rest watched); `moved` [counts] the reading's spread after
    MOTION_DONE (or after the profile without it), `output_turns`; without MOTION_DONE the
    limit cycle: `period` [s] (nan: fewer than two reversals) and `amplitude` [counts]."""
    settled: bool
    done: bool
    moved: float
    output_turns: int
    period: float = float('nan')
    amplitude: float = 0.0
    reversals: int = 0

    @property
    def hunts(self) -> bool:
        """The slide was pushed past the window and back (no MOTION_DONE, the output reversed
        and the slide moved since), or it moved after MOTION_DONE: what a wider window is for.
        A move that is only slow (no MOTION_DONE yet, the slide still: the integrator winding
        against stiction), or whose output rings after MOTION_DONE with the slide still, is not
        settled but not hunting: no window moves that."""
        return (not self.done and self.reversals >= 1 and self.amplitude > 0.0) or \
            (self.done and self.moved > 0)

    def short(self) -> str:
        """describe() in a few words, for a plot's legend."""
        if self.settled:
            return 'at rest'
        if not self.done:
            cyc = f'{self.period:.2f} s, ' if math.isfinite(self.period) else ''
            return f'limit cycle {cyc}±{self.amplitude:.1f} counts'
        return 'not at rest after MOTION_DONE'

    def describe(self) -> str:
        if self.settled:
            return 'at rest'
        if not self.done:
            cyc = (f'period {self.period:.2f} s, ' if math.isfinite(self.period) else '')
            return (f'limit cycle: {cyc}slide ±{self.amplitude:.1f} counts, '
                    f'{self.reversals} output reversals, no MOTION_DONE')
        what = []
        if self.moved:
            what.append(f'the slide moved {self.moved:.0f} count{"s" if self.moved != 1 else ""}')
        if self.output_turns:
            what.append(f'the output turned back {self.output_turns} times')
        return 'not at rest after MOTION_DONE: ' + ', '.join(what)


def judge(t, position, output, t_end, t_done, counts_per_m: float, coulomb: float) -> Judgement:
    """Rest of one move from its samples (stamps [s], slide position [m], output [V]), the end
    of its profile `t_end` and MOTION_DONE `t_done` [s] (None: not raised); the slide's
    reading is position × counts_per_m (whole counts as the encoder gives them)."""
    t = np.asarray(t, dtype=float)
    pos = np.asarray(position, dtype=float) * counts_per_m
    u = np.asarray(output, dtype=float)
    band = TURN_SHARE * max(coulomb, 0.01)
    if t_done is not None:
        after = t >= t_done
        reading = np.round(pos[after])
        moved = float(np.ptp(reading)) if reading.size else 0.0
        n = turns(u[after], band)
        return Judgement(moved == 0.0 and n == 0, True, moved, n)
    start = t_end if t_end is not None else float(t[0])
    after = t >= start
    rev = sign_reversals(t[after], u[after])
    period = 2.0 * (rev[-1] - rev[0]) / (len(rev) - 1) if len(rev) >= 2 else float('nan')
    cycle = t >= rev[0] if rev else after          # the cycle's spread, not the approach's
    spread = float(np.ptp(pos[cycle])) if np.any(cycle) else 0.0
    return Judgement(False, False, spread, turns(u[after], band), period, 0.5 * spread,
                     len(rev))
