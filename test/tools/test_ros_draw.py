"""Issue 16 over ROS: the draw example (plant and controller as two processes, two axes x and y
on the default slide, dual feedback) draws the circle and both axes end with MOTION_DONE within
1 count of its last point; the figures are the example's own printout.

The contour error (<= 5 counts RMS, <= 15 peak) is asserted where the machine cannot touch it,
on the same servo loop in process (test_coordinated.py). Over DDS on this VM it follows the
machine's stalls (issue 11, doc/design_notes.md): by hand 0.82-0.92 RMS and 6.3-6.7 peak, but one CI
run had a 22-count peak from a stall mid-path, and one run here an amplifier-watchdog trip
mid-path (commands late > 10 ms, the slide braked): 278 counts peak, 18 RMS, and still both
axes within a count at the end."""
import re
import subprocess
import sys


def test_draw_circle_over_dds(tmp_path, node_env):
    run = subprocess.run([sys.executable, '-m', 'motion_ctrl.tools.draw', '--shapes', 'circle',
                          '-o', str(tmp_path)], env=node_env, capture_output=True,
                         text=True, timeout=120)
    out = run.stdout + run.stderr
    row = re.search(r'^circle\s+(\d+)\s+([\d.]+)\s+([\d.]+)\s+([\d.]+)\s+([+-][\d.]+)\s+'
                    r'([+-][\d.]+)\s+yes', run.stdout, re.M)
    assert run.returncode == 0 and row, out
    rms, peak, ex, ey = map(float, row.groups()[2:6])
    print(f'contour error over DDS: RMS {rms:.2f}, peak {peak:.2f} counts')
    assert abs(ex) <= 1.0 and abs(ey) <= 1.0, out
    assert (tmp_path / 'draw.png').stat().st_size > 10_000
    assert 'nodes stopped (exit codes 0, 0)' in out, out
