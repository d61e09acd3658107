"""The headline scenario table: the Galil 1-inch move after a reversal, by every method.

From the start-up state of doc/interface.md (both encoders 0, nut on the positive flank) the
slide moves to +2 in, settles, then moves back to +1 in: the 1-inch move after a reversal,
where the whole backlash (20 linear counts) stands between motor and slide. Each configuration runs
in the in-process harness on the same plant; the table gives the true slide error at the end, the
time from move start to MOTION_DONE, the peak following error and the number of sampled correction
moves. `ros2 run motion_ctrl scenarios` prints it.
"""
from __future__ import annotations

import argparse
import functools
import sys
from dataclasses import dataclass

import numpy as np

from motion_ctrl.sim.harness import Harness
from motion_ctrl.sim.plant import SlidePlant
from motion_ctrl.core.registers import INCH

FIRST, SECOND = 2 * INCH, 1 * INCH
TIMEOUT = 4.0          # s per move; a move that has not settled by then limit-cycles or hangs


@functools.lru_cache(maxsize=4)
def calibrate(plant_items: tuple = (), spacing: float = 0.005, length: float = 0.06):
    """Compensation tables measured as a laser calibration would (Delta Tau's Flycal does this).

    With the motor loop and no compensation, the slide is stepped to every table point going
    positive, then going negative, and the true slide error is read at each: e+ and e−. The
    leadscrew table (DEFINE COMP) is −e+ in both directions; moving negative the slide is off
    by e− − e+ more, which is the backlash: its mean is backlash_distance (Ixx86) and the rest
    the backlash table (DEFINE BLCOMP). Both include the screw's elastic deflection under the
    slide's friction, which no pitch model would. Returns register overrides.
    """
    plant = dict(plant_items)
    n = int(round(length / spacing)) + 1
    points = [i * spacing for i in range(n)]
    h = Harness(dict(feedback='motor'), plant, record=False)
    e_pos, e_neg = [], []
    for p in points:                                   # positive-going pass
        h.move(p, TIMEOUT)
        e_pos.append(h.plant.x_l - p)
    h.move(points[-1] + spacing, TIMEOUT)
    for p in reversed(points):                         # negative-going pass
        h.move(p, TIMEOUT)
        e_neg.append(h.plant.x_l - p)
    e_neg.reverse()
    diff = [n_ - p_ for n_, p_ in zip(e_neg, e_pos)]
    distance = sum(diff) / len(diff)
    return dict(leadscrew_table=[-e for e in e_pos], leadscrew_table_spacing=spacing,
                backlash_distance=distance, backlash_table=[d - distance for d in diff],
                backlash_table_spacing=spacing)


def configurations(plant: dict | None = None) -> dict:
    """Register overrides per configuration. The compensation is measured on the *default*
    slide, as a user would set it up once; `plant` changes the slide it then runs on."""
    tables = calibrate()
    return {
        'motor, no compensation': dict(feedback='motor'),
        'motor + backlash comp': dict(feedback='motor',
                                      backlash_distance=SlidePlant().params['backlash']),
        'motor + backlash + leadscrew tables': dict(feedback='motor') | tables,
        'load': dict(feedback='load'),
        'dual': dict(feedback='dual'),
        'sampled': dict(feedback='sampled'),
    }


@dataclass
class Row:
    name: str
    first_error_counts: float    # true slide error after the +2 in move [linear counts]
    error_counts: float          # true slide error at the end [linear counts]
    done_ms: float | None        # move start -> MOTION_DONE [ms]; None = never
    peak_fe_counts: float        # peak |following error| during the move [linear counts]
    corrections: int             # sampled correction moves
    output_reversals: int        # output sign changes in the last 0.5 s (a limit cycle shows)
    note: str = ''


def run_configuration(name: str, registers: dict, plant: dict | None = None,
                      latency_ticks: int = 0) -> Row:
    h = Harness(registers, plant, latency_ticks=latency_ticks)
    cpm = h.plant.load_counts_per_m
    h.move(FIRST, TIMEOUT)
    first = (h.plant.x_l - FIRST) * cpm
    assert h.trace is not None
    start = len(h.trace.t)
    t_done = h.move(SECOND, TIMEOUT)
    if t_done is not None:
        h.run(0.2)                   # the slide after MOTION_DONE: does it stay?
    fe = np.abs(np.array(h.trace.following_error[start:])) * cpm
    out = np.array(h.trace.output[-500:])
    signs = np.sign(out[np.abs(out) > 1e-3])
    reversals = int(np.count_nonzero(np.diff(signs)))
    note = ''
    if t_done is None:
        load = np.array(h.trace.load[-1000:]) * cpm
        note = (f'limit cycle: slide moving {load.max() - load.min():.0f} counts p-p, '
                f'{reversals} output reversals in 0.5 s') if reversals > 5 else 'did not settle'
    return Row(name, first, (h.plant.x_l - SECOND) * cpm, None if t_done is None else t_done * 1e3,
               float(fe.max()), h.axis.correction_moves, reversals, note)


def table(plant: dict | None = None, latency_ticks: int = 0, only=None) -> list[Row]:
    confs = configurations()
    return [run_configuration(n, r, plant, latency_ticks) for n, r in confs.items()
            if only is None or n in only]


def format_table(rows) -> str:
    head = ('| configuration | after +2 in [counts] | final slide error [counts] | '
            'move start → MOTION_DONE [ms] | peak following error [counts] | correction moves '
            '| note |\n|---|---:|---:|---:|---:|---:|---|')
    lines = [head]
    for r in rows:
        done = f'{r.done_ms:.0f}' if r.done_ms is not None else 'never'
        lines.append(f'| {r.name} | {r.first_error_counts:+.2f} | {r.error_counts:+.2f} | '
                     f'{done} | {r.peak_fe_counts:.1f} | '
                     f'{r.corrections} | {r.note} |')
    return '\n'.join(lines)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(
        description='Print the 1-inch-after-reversal scenario table (in-process harness).')
    ap.add_argument('--backlash', type=float, help='plant backlash [m] (default 50.8e-6)')
    ap.add_argument('--slide-mass', type=float, help='plant slide mass [kg] (default 5)')
    ap.add_argument('--latency-ticks', type=int, default=0,
                    help='encoder->command transport delay in servo ticks (DDS ~ 1)')
    a = ap.parse_args(argv)
    plant = {}
    if a.backlash is not None:
        plant['backlash'] = a.backlash
    if a.slide_mass is not None:
        plant['slide_mass'] = a.slide_mass
    p = SlidePlant(**plant)
    print(f'Galil 1-inch move after a reversal (+2 in, then back to +1 in); plant: backlash '
          f'{p.params["backlash"] * 1e6:.1f} um, slide {p.params["slide_mass"]:g} kg, '
          f'resonance {p.resonance_hz:.0f} Hz; latency {a.latency_ticks} tick(s)\n')
    print(format_table(table(plant, a.latency_ticks)))
    return 0


if __name__ == '__main__':
    sys.exit(main())
