"""Issue 16 must-show 1 over ROS: the draw example (plant and controller as two processes, two
axes x and y on the default slide, dual feedback) draws the circle with a contour error of at
most 5 counts RMS after the first quarter, both axes ending with MOTION_DONE within 1 count;
the figures are the example's own printout.

The peak (<= 15 counts) is asserted where the machine cannot touch it, on the same servo loop
in process (test_coordinated.py): over DDS on this VM it depends on the machine's stalls
(issue 11, README Notes). Runs by hand: peaks 6.3-6.7 counts; one CI run: 22.3 counts from a
stall 3 s into the path, away from any quadrant point, with the RMS still 2.6."""
import re
import subprocess
import sys


def test_draw_circle_over_dds(tmp_path, node_env, slow_watchdog):
    # The DDS tests' wider feedback watchdog (conftest.slow_watchdog, README Notes, issue 11).
    params = [f'--param={k}:={v}' for k, v in slow_watchdog.items()]
    run = subprocess.run([sys.executable, '-m', 'motion_ctrl.draw', '--shapes', 'circle',
                          '-o', str(tmp_path), *params], env=node_env, capture_output=True,
                         text=True, timeout=120)
    out = run.stdout + run.stderr
    row = re.search(r'^circle\s+(\d+)\s+([\d.]+)\s+([\d.]+)\s+([\d.]+)\s+([+-][\d.]+)\s+'
                    r'([+-][\d.]+)\s+yes', run.stdout, re.M)
    assert run.returncode == 0 and row, out
    rms, peak, ex, ey = map(float, row.groups()[2:6])
    assert rms <= 5.0, out
    print(f'contour error over DDS: RMS {rms:.2f}, peak {peak:.2f} counts')
    assert abs(ex) <= 1.0 and abs(ey) <= 1.0, out
    assert (tmp_path / 'draw.png').stat().st_size > 10_000
    assert 'nodes stopped (exit codes 0, 0)' in out, out
