"""Galil's sampled dual loop on the backlash slide: how its correction moves meet the slide
(correction_acceleration) and where they judge the load (window_centre)."""
import pytest

from kit import COUNT
from msg_defs.status import Status
from motion_ctrl.core.config import CorrectionConfig
from motion_ctrl.core.dual_loop import SampledCorrection
from motion_ctrl.core.registers import INCH, SHIPPED_SLIDE_TUNING, axis_defaults
from motion_ctrl.sim.harness import Harness


def _headline(latency_ticks: int, **registers):
    """The headline's two moves (+2 in, back to +1 in), sampled: (seconds to each MOTION_DONE,
    the slide's fastest speed while correcting [m/s], its final error [counts])."""
    h = Harness(axis_defaults() | dict(SHIPPED_SLIDE_TUNING) | {'feedback': 'sampled'}
                | registers, record=False, latency_ticks=latency_ticks)
    peak = [0.0]

    def watch(hh):
        if hh.axis.word & Status.CORRECTING:
            peak[0] = max(peak[0], abs(hh.plant.v_l))
    times = []
    for target in (2 * INCH, INCH):
        assert h.axis.move_to(target)[0]
        start = h.time
        assert h.run(20.0, until=lambda hh: hh.axis.word & Status.MOTION_DONE, disturbance=watch)
        times.append(h.time - start)
    return times, peak[0], h.load_error_counts(INCH)


@pytest.mark.core_slow
def test_correction_moves_meet_the_slide_gently():
    """At the corrections' own 0.1 m/s² the motor crossing the backlash does not throw the
    slide: at 0-3 ticks of latency it never moves faster than 6 mm/s while correcting (with the
    move's 1.5 m/s², as Galil's example runs them: up to 20 mm/s, the slide thrown from flank to
    flank) and the headline's moves take 18 s in all (25.6 s with 1.5 m/s²), each within a
    count."""
    runs = [_headline(lat) for lat in range(4)]
    assert max(peak for _, peak, _ in runs) < 6e-3
    assert sum(sum(times) for times, _, _ in runs) < 18.0
    assert all(abs(error) <= 1.0 for _, _, error in runs)


def _correction(window_centre: str) -> SampledCorrection:
    c = SampledCorrection(CorrectionConfig.of(dict(
        correction_tolerance=COUNT, correction_max_moves=200, load_counts_per_m=1 / COUNT,
        settling_time=0.02, coarse_position_tolerance=10 * COUNT, correction_acceleration=0.1,
        window_centre=window_centre)))
    c.start_now()
    return c


def _settled(c: SampledCorrection, error_counts: int):
    """Ticks at rest with the load `error_counts` short of the target until a correction is
    due (its V2 [counts]) or the corrections end (None)."""
    for _ in range(200):
        v2 = c.update(1e-3, profile_done=True, motor_settled=True, motor_counts=0, load_counts=0,
                      load_error_counts=error_counts, motor_error=0.0,
                      load_error=error_counts * COUNT)
        if v2 is not None or c.phase == c.DONE:
            return None if v2 is None else v2 / COUNT
    raise AssertionError('neither a correction nor the end')


@pytest.mark.parametrize('window_centre, error, v2', [
    ('reading', 0, None), ('reading', 1, 1.0), ('reading', -1, -1.0), ('reading', 2, 2.0),
    ('count_middle', 0, None), ('count_middle', 1, None), ('count_middle', -1, -1.5),
    ('count_middle', 2, 1.5)])
def test_the_load_is_judged_where_the_other_windows_judge_it(window_centre, error, v2):
    """A quadrature counter reads the lower edge of its count. With window_centre reading only
    the target's own reading ends the corrections (the slide 0 ... +1 count from it); with
    count_middle the reading one below it ends them too (the slide within a count either
    way), and a correction aims the count's middle at the target."""
    assert _settled(_correction(window_centre), error) == (None if v2 is None
                                                            else pytest.approx(v2))
