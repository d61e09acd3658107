"""The servo timer moves its phase to just after the encoder samples arrive (feedback_sync)."""
import numpy as np
import pytest

from motion_ctrl.core.feedback_sync import FeedbackSync

T = 1e-3


def run(sync, arrival_phase, jitter, seconds=3.0, seed=1):
    """A 1 kHz timer with rcl semantics (a period set in a tick's callback spaces the next tick
    and the one after) and samples arriving at `arrival_phase` after each nominal sample time,
    plus uniform jitter in [0, jitter). Returns the time each sample waited for its tick."""
    rng = np.random.default_rng(seed)
    arrivals = np.arange(int(seconds / T)) * T + arrival_phase + rng.uniform(0, jitter,
                                                                            int(seconds / T))
    waits, tick, nxt, period, i = [], 0.0, T, T, 0
    while tick < seconds - 2 * T:
        while i < len(arrivals) and arrivals[i] < tick:      # samples before this tick
            sync.arrived(arrivals[i])
            waits.append(tick - arrivals[i])
            i += 1
        p = sync.tick(tick)
        tick, nxt = nxt, nxt + period          # the next tick was set at the last call
        if p is not None:
            period = p
            nxt = tick + period
    return np.array(waits)


def test_samples_arriving_just_after_the_tick_move_the_tick_behind_them():
    # Worst case: every sample lands 50-80 us after a tick and waits ~0.93 ms for the next.
    sync = FeedbackSync(T)
    waits = run(sync, 50e-6, 30e-6)
    assert sync.shifts == 1                          # moved once, then stays
    assert np.mean(waits[:400]) > 0.9 * T
    assert np.max(waits[-1000:]) < 60e-6             # then used within tens of microseconds
    assert np.min(waits[-1000:]) >= 0.0


def test_samples_arriving_just_before_the_tick_leave_it_alone():
    sync = FeedbackSync(T)
    waits = run(sync, 900e-6, 30e-6)
    assert sync.shifts == 0
    assert np.max(waits) < 0.11 * T


def test_samples_straddling_the_tick_are_all_caught_after_the_shift():
    # Arrivals from 30 us before to 30 us after the tick: half wait a whole period.
    sync = FeedbackSync(T)
    waits = run(sync, -30e-6, 60e-6)
    assert np.mean(waits[:400] > 0.5 * T) == pytest.approx(0.5, abs=0.1)
    assert sync.shifts == 1
    assert np.max(waits[-1000:]) < 80e-6


def test_a_late_tail_is_not_chased():
    # 10 % of the samples arrive half a period late: the tick stays behind the other 90 %
    # (chasing the tail would make every sample wait half a period).
    sync = FeedbackSync(T)
    rng = np.random.default_rng(3)
    phases = np.where(rng.uniform(size=500) < 0.1, 600e-6, 100e-6)
    sync.tick(0.0)
    for k, ph in enumerate(phases):
        sync.arrived(k * T + ph)
    period = sync.tick(500 * T)
    assert period == pytest.approx(110e-6, abs=10e-6)     # just after the main group
    assert sync.tick(501 * T) == T                        # and back to the nominal period


def test_mean_wait_counts_a_sample_at_the_tick_as_a_whole_period():
    sync = FeedbackSync(T)
    w = sync.mean_waits(np.array([0.0, 0.4e-3]), np.array([0.0, 0.5e-3]))
    assert w == pytest.approx([(T + 0.6e-3) / 2, (0.5e-3 + 0.1e-3) / 2])
