"""ISO 230-2 positioning test of one axis and the compensation tables built from it (core).

Plain Python + numpy, no ROS: the `calibrate` tool (motion_ctrl/tools/calibrate.py) drives the axis
over ROS with the plan made here and hands the readings back here. Standard and vendor rules:

* **Test plan** — ISO 230-2:2014, "Test of positioning accuracy and repeatability": m target
  positions over the measuring travel, ``P_i = (i − 1)·p + r_i`` with a different offset r_i at
  each target so that periodic errors (the screw's pitch error) are not sampled at one phase
  (aliased); at least 5 targets for a travel up to 2 m; the "standard test cycle": each target
  approached from one side, 5 times in each direction (here: ``cycles``), every approach of a
  direction coming from beyond the first target by an overtravel, so that the backlash is
  always taken up the same way (the linear cycle of the standard's figure).
* **Statistics** — ISO 230-2:2014 clause 3 (definitions) and annex of evaluation: deviation
  x_ij = P_ij − P_i (actual minus target), per direction mean x̄_i↑ / x̄_i↓ and standard
  uncertainty (estimator of the standard deviation, n − 1) s_i↑ / s_i↓; reversal value
  B_i = x̄_i↑ − x̄_i↓, axis reversal B = max|B_i| and mean reversal B̄; unidirectional
  repeatability R_i↑ = 4·s_i↑ (R_i↓ likewise); bidirectional repeatability
  ``R_i = max(2·s_i↑ + 2·s_i↓ + |B_i|, R_i↑, R_i↓)`` and R = max R_i (the formula as in the 2006
  edition, which the 2014 edition keeps as far as the public summaries of it show; the text of
  the standard was not at hand: buy it to check this formula); unidirectional
  systematic error E↑ = max x̄_i↑ − min x̄_i↑ and the bidirectional E = max(x̄↑, x̄↓) −
  min(x̄↑, x̄↓) over all targets; mean bidirectional deviation x̄_i = (x̄_i↑ + x̄_i↓)/2 and the
  mean bidirectional positioning error M = max x̄_i − min x̄_i; accuracy A↑ = max(x̄_i↑ + 2s_i↑)
  − min(x̄_i↑ − 2s_i↑) and the bidirectional A = max(x̄↑ + 2s↑, x̄↓ + 2s↓) − min(x̄↑ − 2s↑,
  x̄↓ − 2s↓).
* **Tables** — Turbo PMAC, in this product's register conventions (motion_ctrl/core/backlash.py:
  uniform spacing from position 0, linear interpolation, end values held; indexed by the nominal
  commanded position, which is the ISO target): DEFINE COMP (``leadscrew_table``, added in both
  directions) = −x̄↑, so a positive approach lands on the target; the constant backlash Ixx86
  (``backlash_distance``) = the mean of x̄↓ − x̄↑ = −B̄ (the backlash register is subtracted from
  the command while moving negative); DEFINE BLCOMP (``backlash_table``, added to Ixx86 while
  moving negative) = (x̄↓ − x̄↑) − Ixx86, the position-dependent rest — the manual's
  "difference between the positive-going compensation and the negative-going compensation".
* **LinuxCNC COMP_FILE** — type 1 (``COMP_FILE_TYPE = 1``): one line per target, "nominal
  forward_trim reverse_trim", the trims being what LinuxCNC adds to the commanded joint position
  moving forward / in reverse (src/emc/motion/usrmotintf.cc, usrmotLoadComp: type 0 files give
  the positions reached instead and are converted to these differences as nominal − actual).
  So trim = −x̄↑ and −x̄↓. No comment or header line: the loader stops at the first line that is
  not three numbers. Nominal positions need not be evenly spaced (the targets are written as
  measured), at most 256 lines per joint; units are the machine's (mm by default here). With a
  comp file LinuxCNC's own BACKLASH must be 0: the backlash is the difference of the two trims.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Protocol

import numpy as np

from motion_ctrl.core.backlash import interpolate_table
from motion_ctrl.core.registers import yaml_float

GOLDEN = (math.sqrt(5.0) - 1.0) / 2.0
MIN_TARGETS = 5          # ISO 230-2: at least five targets for a travel up to 2 m
MIN_CYCLES = 5           # ISO 230-2: five approaches per target and direction
MAX_TABLE_ENTRIES = 256  # LinuxCNC's comp-file limit; PMAC tables are larger, none needs more


# -- the test plan ---------------------------------------------------------------------------------
def plan_targets(start: float, end: float, count: int) -> np.ndarray:
    """ISO 230-2 target positions from `start` to `end` [m], `count` of them, not evenly spaced.

    ``P_i = start + (i − 1)·p + r_i`` with p = (end − start)/(count − 1). The standard asks for a
    different r_i at each target (random within the interval); a deterministic low-discrepancy
    sequence is used instead (golden-ratio steps, r_i within ±p/4) so a run repeats exactly and
    the intervals take three or four different lengths between p/2 and 3p/2 (the three-gap
    theorem) in no regular order: a screw error of any period is sampled at many phases. The
    two ends are kept exactly: the tables must cover the travel the user asked for.
    """
    if not (math.isfinite(start) and math.isfinite(end) and end > start):
        raise ValueError(f'the travel must run from a lower to a higher position, got '
                         f'{start!r} .. {end!r}')
    if count < 2:
        raise ValueError(f'at least 2 targets, got {count}')
    p = (end - start) / (count - 1)
    i = np.arange(count)
    r = ((i * GOLDEN) % 1.0 - 0.5) * 0.5 * p
    r[0] = r[-1] = 0.0
    return start + i * p + r


@dataclass(frozen=True)
class Step:
    """One move of the test: go to `position`; when `target` is not None, read the deviation of
    that target index approached in `direction` (+1 / −1) in `cycle`."""
    position: float
    target: int | None
    direction: int
    cycle: int


def approach_sequence(targets, cycles: int, overtravel: float) -> list[Step]:
    """The ISO 230-2 linear test cycle, `cycles` times: to the first target − overtravel, up
    through every target (approached positive), to the last target + overtravel, down through
    every target (approached negative). Each target is reached from one side, and the backlash
    is taken up by the overtravel before the first reading of each direction.

    (The overtravel must exceed the backlash plus the controller's reversal hysteresis Ixx87;
    the tool checks that against the registers.)
    """
    targets = list(map(float, targets))
    if overtravel <= 0.0:
        raise ValueError(f'overtravel must be > 0, got {overtravel!r}')
    steps: list[Step] = []
    for c in range(cycles):
        steps.append(Step(targets[0] - overtravel, None, +1, c))
        steps += [Step(p, i, +1, c) for i, p in enumerate(targets)]
        steps.append(Step(targets[-1] + overtravel, None, -1, c))
        steps += [Step(targets[i], i, -1, c) for i in reversed(range(len(targets)))]
    return steps


# -- statistics ------------------------------------------------------------------------------------
@dataclass
class Iso230:
    """ISO 230-2:2014 evaluation of a bidirectional test (all lengths in metres).

    Per target i (arrays of length m): mean_up/mean_down x̄_i↑/x̄_i↓, s_up/s_down, reversal
    B_i, repeatability R_up_i/R_down_i/R_i, mean bidirectional deviation mean_bi. Axis values:
    B (max |B_i|), B_mean, R_up, R_down, R, E_up, E_down, E, M, A_up, A_down, A."""
    targets: np.ndarray
    up: np.ndarray            # deviations, shape (m, n): target i, approach j, moving positive
    down: np.ndarray
    mean_up: np.ndarray
    mean_down: np.ndarray
    s_up: np.ndarray
    s_down: np.ndarray
    B_i: np.ndarray
    R_up_i: np.ndarray
    R_down_i: np.ndarray
    R_i: np.ndarray
    mean_bi: np.ndarray
    B: float
    B_mean: float
    R_up: float
    R_down: float
    R: float
    E_up: float
    E_down: float
    E: float
    M: float
    A_up: float
    A_down: float
    A: float

    def headline(self) -> dict:
        """The five figures of the report: A, B, E, M, R."""
        return dict(A=self.A, B=self.B, E=self.E, M=self.M, R=self.R)


def evaluate(targets, up, down) -> Iso230:
    """ISO 230-2:2014 figures from the deviations x_ij = P_ij − P_i [m], arrays of shape
    (m targets, n approaches), `up` approached positive, `down` negative (n ≥ 2 for s)."""
    t = np.asarray(targets, dtype=float)
    up = np.asarray(up, dtype=float)
    down = np.asarray(down, dtype=float)
    if up.shape != down.shape or up.ndim != 2 or up.shape[0] != t.size:
        raise ValueError(f'deviations must be (targets, approaches) for {t.size} targets, got '
                         f'{up.shape} and {down.shape}')
    if up.shape[1] < 2:
        raise ValueError('at least 2 approaches per target and direction (for s)')
    mu, md = up.mean(axis=1), down.mean(axis=1)
    su, sd = up.std(axis=1, ddof=1), down.std(axis=1, ddof=1)     # n − 1: the estimator
    b = mu - md
    ru, rd = 4.0 * su, 4.0 * sd
    ri = np.maximum(2.0 * su + 2.0 * sd + np.abs(b), np.maximum(ru, rd))
    mbi = (mu + md) / 2.0
    both = np.concatenate([mu, md])
    hi = np.concatenate([mu + 2.0 * su, md + 2.0 * sd])
    lo = np.concatenate([mu - 2.0 * su, md - 2.0 * sd])
    return Iso230(
        targets=t, up=up, down=down, mean_up=mu, mean_down=md, s_up=su, s_down=sd, B_i=b,
        R_up_i=ru, R_down_i=rd, R_i=ri, mean_bi=mbi,
        B=float(np.max(np.abs(b))), B_mean=float(np.mean(b)),
        R_up=float(ru.max()), R_down=float(rd.max()), R=float(ri.max()),
        E_up=float(mu.max() - mu.min()), E_down=float(md.max() - md.min()),
        E=float(both.max() - both.min()), M=float(mbi.max() - mbi.min()),
        A_up=float((mu + 2 * su).max() - (mu - 2 * su).min()),
        A_down=float((md + 2 * sd).max() - (md - 2 * sd).min()),
        A=float(hi.max() - lo.min()))


def deviations(targets, readings, cycles: int) -> tuple[np.ndarray, np.ndarray]:
    """Arrange readings {(target index, direction, cycle): deviation [m]} into the (m, n)
    arrays `evaluate` takes."""
    m = len(targets)
    up, down = np.full((m, cycles), np.nan), np.full((m, cycles), np.nan)
    for (i, direction, c), x in readings.items():
        (up if direction > 0 else down)[i, c] = x
    if np.isnan(up).any() or np.isnan(down).any():
        raise ValueError('readings missing for some targets / cycles')
    return up, down


# -- compensation tables ---------------------------------------------------------------------------
@dataclass
class Tables:
    """PMAC compensation from one ISO test, in this product's registers (metres)."""
    leadscrew_table: list[float]      # DEFINE COMP, entry k at k·spacing
    backlash_table: list[float]       # DEFINE BLCOMP, added to backlash_distance moving negative
    backlash_distance: float          # Ixx86
    spacing: float                    # both tables' spacing [m]
    residual: float                   # largest |table − measured| at a target [m]
    targets: np.ndarray
    correction_up: np.ndarray         # what the tables command at each target moving positive
    correction_down: np.ndarray       # ... and moving negative (−x̄↑, −x̄↓)

    def registers(self, axis: str = 'x') -> dict:
        """Register values, spacings first (a table needs its spacing set before it)."""
        return {f'{axis}.backlash_distance': self.backlash_distance,
                f'{axis}.leadscrew_table_spacing': self.spacing,
                f'{axis}.leadscrew_table': list(self.leadscrew_table),
                f'{axis}.backlash_table_spacing': self.spacing,
                f'{axis}.backlash_table': list(self.backlash_table)}


def _grid_values(targets, values, spacing, n):
    # np.interp holds the end values outside the targets, as the controller holds a table's.
    return np.interp(np.arange(n) * spacing, targets, values)


def table_fit(targets, values, spacing) -> tuple[list[float], float]:
    """A uniform table from 0 at `spacing` through the last target, sampling the measured curve
    (linear between targets) at its entries; and its largest deviation from `values` at the
    targets, interpolated as the controller interpolates (backlash.interpolate_table)."""
    targets = np.asarray(targets, dtype=float)
    n = int(math.ceil(targets[-1] / spacing - 1e-9)) + 1
    table = [float(v) for v in _grid_values(targets, values, spacing, max(n, 2))]
    fit = np.array([interpolate_table(table, spacing, p) for p in targets])
    return table, float(np.max(np.abs(fit - np.asarray(values))))


def build_tables(result: Iso230, tolerance: float, spacing: float | None = None) -> Tables:
    """COMP, BLCOMP and Ixx86 from an ISO 230-2 result (see the module docstring for the rule).

    The spacing: given, or the largest of end/k (k = 1, 2, ... intervals from position 0 to the
    last target) whose tables, interpolated as the controller does, reproduce the measured
    corrections at every target within `tolerance` [m] — so the table resolves what the test
    measured and no more (the test cannot see an error shorter than about twice its target
    interval). Capped at MAX_TABLE_ENTRIES. Tables start at position 0 (the product's
    convention): the travel must not run below 0.
    """
    t = result.targets
    if t[0] < 0.0:
        raise ValueError(f'the tables start at position 0 and hold their first entry below it: '
                         f'calibrate a travel at or above 0 (first target {t[0]:g} m)')
    comp = -result.mean_up
    diff = result.mean_down - result.mean_up
    distance = float(np.mean(diff))
    bl = diff - distance
    if spacing is None:
        for k in range(1, MAX_TABLE_ENTRIES):
            s = float(t[-1]) / k
            worst = max(table_fit(t, comp, s)[1], table_fit(t, bl, s)[1])
            if worst <= tolerance:
                spacing = s
                break
        else:
            spacing = float(t[-1]) / (MAX_TABLE_ENTRIES - 1)
    if not spacing > 0.0:
        raise ValueError(f'spacing must be > 0, got {spacing!r}')
    ls_table, ls_res = table_fit(t, comp, spacing)
    bl_table, bl_res = table_fit(t, bl, spacing)
    up = np.array([interpolate_table(ls_table, spacing, p) for p in t])
    down = up - distance - np.array([interpolate_table(bl_table, spacing, p) for p in t])
    return Tables(ls_table, bl_table, distance, spacing, max(ls_res, bl_res), t, up, down)


# -- files -----------------------------------------------------------------------------------------
def _array_entry(value: float) -> float:
    """rclpy's parameter_dict_from_yaml_file (what `ros2 param load` uses) types an array by
    parsing str() of the list again: Python writes 1e-06 without a '.', which YAML 1.1 reads as
    text, and the whole array arrives as a string. Such a value is moved by one ulp
    (1.0000000000000002e-06: 1e-22 m) so that its repr has a '.'."""
    value = float(value)
    text = repr(value)
    if 'e' in text and '.' not in text.split('e')[0]:
        value = float(np.nextafter(value, math.inf))
    return value


def params_yaml(tables: Tables, axis: str = 'x', node: str = 'controller',
                comment: str = '') -> str:
    """`ros2 param load` YAML of the compensation registers (node key, ros__parameters).

    Spacings come before their tables: a file is applied in its order and a table is refused
    while its spacing is 0. Every value is written as a double (1.0e-06, never 1e-06, which
    YAML 1.1 reads as text); the tables are never empty (an empty YAML sequence has no type for
    rcl's parser)."""
    lines = [f'# {line}' for line in comment.splitlines()]
    lines += [f'{node}:', '  ros__parameters:']
    for name, value in tables.registers(axis).items():
        if isinstance(value, list):
            text = '[' + ', '.join(yaml_float(_array_entry(v)) for v in value) + ']'
        else:
            text = yaml_float(value)
        lines.append(f'    {name}: {text}')
    return '\n'.join(lines) + '\n'


UNITS = {'m': 1.0, 'mm': 1e3, 'inch': 1.0 / 0.0254}


def linuxcnc_comp_file(result: Iso230, units: str = 'mm') -> str:
    """LinuxCNC COMP_FILE, type 1: "nominal forward_trim reverse_trim" per target, in machine
    `units` (see the module docstring)."""
    k = UNITS[units]
    if len(result.targets) > MAX_TABLE_ENTRIES:
        raise ValueError(f'LinuxCNC takes at most {MAX_TABLE_ENTRIES} lines per joint')
    return ''.join(f'{p * k:.6f} {-u * k:.6f} {-d * k:.6f}\n'
                   for p, u, d in zip(result.targets, result.mean_up, result.mean_down))


# -- report ----------------------------------------------------------------------------------------
FIGURES = ('A', 'B', 'E', 'M', 'R')


def format_report(runs: dict, counts_per_m: float) -> str:
    """A markdown table of A, B, E, M, R in linear counts and µm for each run {label: Iso230}."""
    head = ('| ISO 230-2 | ' + ' | '.join(f'{f} [counts]' for f in FIGURES) + ' | '
            + ' | '.join(f'{f} [µm]' for f in FIGURES) + ' |')
    lines = [head, '|---|' + '---:|' * (2 * len(FIGURES))]
    for label, r in runs.items():
        h = r.headline()
        lines.append(f'| {label} | '
                     + ' | '.join(f'{h[f] * counts_per_m:.2f}' for f in FIGURES) + ' | '
                     + ' | '.join(f'{h[f] * 1e6:.2f}' for f in FIGURES) + ' |')
    return '\n'.join(lines)


class AxisUnderTest(Protocol):
    """What the test cycle needs of an axis: a move, a move with a slow final approach (a
    PVT segment of `distance` in `duration`), and the reference reading at rest (procedures.
    session.AxisUnderTest over ROS; a harness in the tests)."""

    def move(self, position: float, timeout: float) -> None: ...

    def approach(self, position: float, direction: int, distance: float, duration: float,
                 timeout: float) -> None: ...

    def read_load(self, dwell: int, average: int) -> float: ...


def run_cycle(axis: AxisUnderTest, targets, cycles: int, overtravel: float, dwell: int,
              average: int, move_timeout: float = 10.0, progress=None,
              approach: tuple[float, float] = (0.0, 0.0)) -> Iso230:
    """The standard's linear cycle (approach_sequence) on the axis as it is configured, each
    target reached with `approach` = (distance [m], duration [s]) of slow final segment; the
    reference read after `dwell` ms as the mean of `average` samples; returns the
    evaluation. `progress(done, total)` after each step, when given."""
    readings = {}
    steps = approach_sequence(targets, cycles, overtravel)
    for k, step in enumerate(steps):
        if step.target is None or approach[0] <= 0.0:
            axis.move(step.position, move_timeout)
        else:
            axis.approach(step.position, step.direction, *approach, move_timeout)
        if step.target is not None:
            readings[(step.target, step.direction, step.cycle)] = \
                axis.read_load(dwell, average) - step.position
        if progress is not None:
            progress(k + 1, len(steps))
    up, down = deviations(targets, readings, cycles)
    return evaluate(targets, up, down)
