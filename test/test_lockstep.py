"""Lockstep simulation over DDS: the same move twice gives identical plant_states (issue 6)."""
import pytest

from motion_ctrl.ros.lockstep import run_lockstep

COUNT = 0.0254 / 10000
START = 20.0           # sim time of the move [s]


@pytest.mark.timeout(180)
def test_same_move_twice_is_bit_identical(rclpy_session, tmp_path):
    runs = []
    for i in range(2):
        (tmp_path / str(i)).mkdir()
        truth, speed = run_lockstep(target=0.0254, start=START, end=START + 2.0,
                                    log_dir=tmp_path / str(i))
        runs.append(truth)
        print(f'run {i}: {len(truth)} samples, {speed:.2f} sim s per wall s')
    a, b = runs
    window = [s for s in a if START * 1e9 <= s <= (START + 2.0) * 1e9]   # move and settling
    common = [s for s in window if s in b]
    assert len(common) >= 1800, f'only {len(common)} common samples in the 2 s window'
    assert [a[s] for s in common] == [b[s] for s in common]       # bit-identical
    # And the move happened: the slide ends within a few counts of the target.
    last = max(common)
    assert abs(a[last][1] - 0.0254) < 3 * COUNT
