"""The two-process loop on its own clocks: the slide on the plant's ticks, the servo loop on the
controller's, a transport delay each way (what `hardware: topics` runs: doc/gains.md).

The harness (motion_ctrl.sim.harness) steps controller and slide in lockstep: every sample is
read the instant it is taken and every command holds for exactly the next period, with whole
ticks of latency at most. Over DDS the plant node and the controller tick on two timers of
their own, and where the controller's tick falls between the plant's decides which sample it
uses and which of the plant's periods its command holds for. `TwoClockHardware` replays that: a
list of plant tick times and the loop's own tick times (regular, jittered, or the stamps of a
recording), a sample reaching the loop `d_in` after its plant tick and a command reaching the
plant `d_out` after the loop's tick. The plant integrates each of its periods on the latest
command that has arrived by the period's end, as `plant_node` does (a command that arrives
during a period holds for the whole of it).

`demo_moves` runs the demo's three moves (1 in forward, +2 in, back to +1 in) on such clocks
through the same `ServoLoop` the node drives, and returns, per move, the time from the end of
the profile to MOTION_DONE, the overshoot and the slide's final error in linear counts, and how
fast the motor ran back against the move just after the profile's end (it leaves the slide and
opens the backlash gap: doc/gains.md).
"""
from __future__ import annotations

from dataclasses import dataclass

from msg_defs.status import Status
from motion_ctrl.core.axis import Axis
from motion_ctrl.core.hardware import HardwareInterface
from motion_ctrl.core.registers import CONTROLLER_GLOBAL, INCH
from motion_ctrl.core.servo_loop import ServoLoop
from motion_ctrl.sim.plant import SlidePlant

DEMO_MOVES = ((0.2, INCH), (1.2, 2 * INCH), (2.2, INCH))   # (start [s], target [m])
DEMO_END = 3.2     # s: a second for each move and its rest
BACK_WINDOW = 0.04  # s after the profile's end in which MoveResult.motor_back is taken
_DONE = int(Status.MOTION_DONE)


class TwoClockHardware(HardwareInterface):
    """One slide (axis `axis`) ticking at `plant_ticks` [s], behind a transport: samples reach
    the loop `d_in` after their tick, commands reach the plant `d_out` after the loop's.
    `held_samples` (start, end) [s]: the samples taken within it reach the loop only `d_in`
    after `end` (both processes held up: the samples of the hold-up wait behind the loop's
    first tick after it)."""
    kind = 'two_clocks'

    def __init__(self, axis: str, plant: dict, plant_ticks: list[float], d_in: float,
                 d_out: float, substep_rate: float = 20000.0,
                 held_samples: tuple[float, float] | None = None) -> None:
        super().__init__((axis,))
        self.held_samples = held_samples
        self.plant = SlidePlant(substep_rate=substep_rate, **plant)
        self.ticks = plant_ticks
        self.d_in = d_in
        self.d_out = d_out
        self.next = 1                  # the plant's next tick
        self.time = plant_ticks[0]     # where the plant's integration ended
        self.sent: list[tuple[float, float]] = []   # (arrival [s], volts), in arrival order
        self.applied = 0               # commands of `sent` the plant has taken
        self.slide = self.io[axis]
        m, load = self.plant.encoder_counts()
        self.slide.sample(m, load, self.time)

    def read(self, now: float) -> None:
        """Run the plant through every tick whose sample has reached the loop by `now`."""
        plant, ticks, sent = self.plant, self.ticks, self.sent
        while self.next < len(ticks) and self._arrival(ticks[self.next]) <= now:
            t = ticks[self.next]
            while self.applied < len(sent) and sent[self.applied][0] <= t:
                plant.command(sent[self.applied][1])
                self.applied += 1
            plant.advance(t - self.time, t - self.time)
            self.time = t
            self.next += 1
            m, load = plant.encoder_counts()
            self.slide.sample(m, load, t)

    def _arrival(self, tick: float) -> float:
        held = self.held_samples
        if held is not None and held[0] <= tick <= held[1]:
            return held[1] + self.d_in
        return tick + self.d_in

    def write(self, now: float) -> None:
        if self.slide.commanded:
            self.sent.append((now + self.d_out, self.slide.output))


def repeat(times: list[float], until: float) -> list[float]:
    """`times` [s], continued with its own periods over again until it passes `until` (a
    recording shorter than the run)."""
    out = list(times)
    periods = [b - a for a, b in zip(times, times[1:])]
    i = 0
    while out[-1] <= until:
        out.append(out[-1] + periods[i % len(periods)])
        i += 1
    return out


@dataclass(frozen=True)
class MoveResult:
    after_profile: float | None    # s from the end of the profile to MOTION_DONE (None: never)
    overshoot: float               # counts past the target, in the move's direction
    error: float                   # counts: the slide's final error
    motor_back: float              # m/s: the motor's fastest run against the move in the
                                   # BACK_WINDOW after the profile's end (0: none)


def demo_loop(registers: dict, plant: dict, plant_ticks: list[float], d_in: float = 0.15e-3,
              d_out: float = 0.25e-3, held_samples: tuple[float, float] | None = None
              ) -> tuple[TwoClockHardware, Axis, ServoLoop]:
    """The demo's axis `x` (`registers`) in a servo loop on the slide (`plant`) ticking at
    `plant_ticks`, behind the transport (TwoClockHardware), the hardware activated."""
    hw = TwoClockHardware('x', plant, plant_ticks, d_in, d_out, held_samples=held_samples)
    hw.activate()
    axis = Axis('x', registers, 1e-3)
    loop = ServoLoop({'x': axis}, {'x': axis.r}, 1e-3,
                     float(CONTROLLER_GLOBAL['feedback_timeout'].default),  # type: ignore[arg-type]
                     sim_time=True, hardware=hw)
    return hw, axis, loop


def demo_moves(registers: dict, plant: dict, plant_ticks: list[float],
               loop_ticks: list[float], d_in: float = 0.15e-3, d_out: float = 0.25e-3,
               moves=DEMO_MOVES, end: float = DEMO_END) -> list[MoveResult]:
    """The demo's moves on these clocks (each a sorted list of times [s] reaching `end`)."""
    hw, axis, loop = demo_loop(registers, plant, plant_ticks, d_in, d_out)
    counts_per_m = hw.plant.load_counts_per_m
    pending = list(moves)
    trace: list[tuple[float, float, bool, int, float, float]] = []
    for now in loop_ticks:
        if now > end:
            break
        if pending and now >= pending[0][0]:
            loop.move({'x': pending.pop(0)[1]})
        loop.cycle(now)
        p = axis.profile
        trace.append((now, p.position, p.moving, axis.word, hw.plant.x_l, hw.plant.v_m))
    results = []
    before = 0.0
    for (start, target), stop in zip(moves, [m[0] for m in moves[1:]] + [end]):
        seg = [x for x in trace if start <= x[0] < stop]
        ended = next((x[0] for x in seg[1:] if not x[2] and x[1] == target), None)
        done = next((x[0] for x in seg if ended is not None and x[0] >= ended
                     and x[3] & _DONE), None)
        sign = 1.0 if target > before else -1.0
        before = target
        back = [-sign * x[5] for x in seg
                if ended is not None and ended <= x[0] < ended + BACK_WINDOW]
        results.append(MoveResult(
            None if done is None or ended is None else done - ended,
            max(sign * (x[4] - target) for x in seg) * counts_per_m,
            (seg[-1][4] - target) * counts_per_m,
            max(back + [0.0])))
    return results
