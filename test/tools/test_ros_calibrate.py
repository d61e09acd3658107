"""`calibrate` over ROS (issue 15, must-shows 1 and 2): plant and controller as two processes in
the lockstep simulation (DDS between them, the plant's clock), the tool run against them as a
user runs it (a process of its own): its ISO 230-2 test before and, with --apply, after its
tables, the figures a user reads in its report; then, with the tables left in the controller,
the headline move judged on the simulation's ground truth, which the tool never reads. A short
travel (0.5 .. 2 in, 5 targets, the ISO minimum) keeps each run near a minute. In real time on
this VM the runs are now and then lost to the machine's stalls (doc/calibration.md, "Calibrating an
axis")."""
import re
import subprocess
import sys

import pytest

from kit import COUNT, INCH, long_run

ARGS = ['--apply', '--keep-motor', '--range', '0.0127,0.0508', '--targets', '5']
# The axis as identify measures it: the friction feedforward is the slide's Coulomb friction in
# volts (0.24 V, doc/identify.md). On the shipped gains alone the motor loop ends a move
# at speed a little past its target and the slide stays there across the backlash gap, where
# tables measured with calibrate's slow final approach do not reach: the headline then ends at
# -1.5 to -1.8 counts over ROS, -2.0 to -2.4 in the harness (test_iso230), at the limit.
TUNED = {'x.friction_ff': '0.24'}


def figures(report: str) -> dict:
    """{'before': {'A': counts, ...}, 'after ...': {...}} from report.md."""
    rows = {}
    for line in report.splitlines():
        m = re.match(r'\| (before|after[^|]*) \|(.*)\|$', line)
        if m:
            cells = [float(c) for c in m.group(2).split('|')[:5]]
            rows[m.group(1).split()[0]] = dict(zip('ABEMR', cells))
    return rows


def headline_error(domain: int) -> float:
    """The headline move (+2 in, back to +1 in) on the running slide: the true slide's final
    error [linear counts]."""
    from motion_ctrl.ros.client import SlideClient
    from motion_ctrl.ros.lockstep import client_context
    context = client_context(domain)
    client = SlideClient(context=context)
    try:
        assert client.wait_ready(30.0), client.not_ready()
        for target in (2 * INCH, INCH):
            assert client.move({'x': target}, timeout=10.0) is not None, client.status
        return (client.load_position() - INCH) / COUNT
    finally:
        client.destroy_node()
        context.try_shutdown()


@pytest.mark.timeout(300)
@pytest.mark.parametrize('plant, backlash_counts', [
    ({}, 20.0),
    pytest.param({'x.backlash': '1.524e-4', 'x.pitch_error_amplitude': '5.08e-6',
                  'x.pitch_error_period': '0.0254'}, 60.0,
                 marks=long_run('31 s; the default slide\'s case runs the same tool')),
], ids=['default', 'backlash x3, other pitch error'])
def test_calibration_takes_out_the_backlash(node_env, module_domain, tmp_path, plant,
                                            backlash_counts):
    from motion_ctrl.ros import lockstep
    nodes = lockstep.start_slide(TUNED, plant, tmp_path, node_env)
    try:
        run = subprocess.run([sys.executable, '-m', 'motion_ctrl.tools.calibrate', *ARGS,
                              '-o', str(tmp_path)], env=node_env, capture_output=True, text=True,
                             timeout=230)
        assert run.returncode == 0, f'calibrate failed, logs in {tmp_path}:\n' + \
            run.stdout[-3000:] + run.stderr[-3000:]
        rows = figures((tmp_path / 'report.md').read_text())
        print(rows)
        assert rows['before']['B'] == pytest.approx(backlash_counts, rel=0.35)
        assert abs(rows['after']['B']) <= 2.0
        assert rows['after']['E'] <= 3.0
        error = headline_error(module_domain)
        print(f'headline move on feedback: motor with the tables: {error:+.2f} counts')
        assert abs(error) <= 2.0
    finally:
        for n in reversed(nodes):
            n.stop()
