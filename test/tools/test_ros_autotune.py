"""`autotune` over ROS (issue 14, must-show 3 in lockstep): plant and controller as two processes
(DDS between them, the plant's clock), the tool measuring the default slide (identify), proposing
the stiff preset and verifying it with the demo's three moves before and after, from the
controller's own joint_states and status. What it must show: the proposal meets 8 dB / 45° on
the measured open loop, and after it every move settles faster than with the table's default
gains (UNTUNED, below; params/controller.yaml has carried the slide's tuning since issue 29),
within 1 count and with at most 2 counts of overshoot, no ringing at rest (output p-p < 0.2 V),
and the median settle within the issue's 150 ms (2026-11-24: 717-731 ms before, 33-37 after;
253-313 before the breakaway aid, friction_ff_at_rest; three runs after identify's ratio runs,
the same day: 666-734 ms before, 29-35 after, 8.2-10.6 dB / 45.5-47.6° on the model)."""
import math
import os
import subprocess
import sys

import pytest
import yaml

from kit import long_run
from motion_ctrl.core.registers import CONTROLLER_AXIS, LOAD_COUNTS_PER_M, SHIPPED_SLIDE_TUNING

# Each run starts from the register table's default gains (Galil's tuning procedure), not from
# params/controller.yaml, which carries the shipped slide's tuning (doc/gains.md): the tool's
# question is what it makes of gains that nobody tuned on the measurement.
UNTUNED = [a for name in SHIPPED_SLIDE_TUNING
           for a in ('--controller', f'x.{name}:={CONTROLLER_AXIS[name].default!r}')]


@pytest.mark.timeout(300)
def test_autotune_stiff_verified_with_the_demo_moves(node_env, tmp_path):
    run = subprocess.run([sys.executable, '-m', 'motion_ctrl.tools.autotune', '--spawn',
                          '--lockstep', '--apply', '--preset', 'stiff', '-o', str(tmp_path)]
                         + UNTUNED, env=node_env, capture_output=True, text=True, timeout=290)
    print(run.stdout[-4000:])
    assert run.returncode == 0, f'autotune failed, logs in {tmp_path}:\n' + run.stdout[-3000:] \
        + run.stderr[-3000:]
    doc = yaml.safe_load((tmp_path / 'autotune.yaml').read_text())
    regs = doc['controller']['ros__parameters']
    assert {'x.kp', 'x.ki', 'x.kd', 'x.kvff', 'x.kaff', 'x.friction_ff'} <= set(regs)
    v = yaml.safe_load((tmp_path / 'verification.yaml').read_text())
    assert v['after']['gain_margin_db'] >= 8.0 and v['after']['phase_margin_deg'] >= 45.0
    for b, a in zip(v['before']['moves'], v['after']['moves']):
        assert a['settle_ms'] < b['settle_ms'], (b, a)
        assert abs(a['final_error_counts']) <= 1.0 and a['overshoot_counts'] <= 2.0, a
        assert a['output_pp_v'] < 0.2, a
    assert sorted(m['settle_ms'] for m in v['after']['moves'])[1] <= 150.0
    assert 'x.friction_ff_at_rest' in regs
    # issue 30, must-show 2: the default slide slips a few hundredths of a count; its rest
    # settings stay as shipped (the exact count), and every move is at rest for 2 s
    assert v['rest']['slip_counts'] < 0.5 and v['rest']['window_counts'] == 0.0, v['rest']
    assert regs['x.window_centre'] == 'reading' and regs['x.deadband_tolerance'] == 0.0
    assert regs['x.fine_position_tolerance'] == 1.5e-6
    assert all(m['at_rest'] for m in v['after']['moves']), v['after']
    for name in ('open_loop.png', 'steps.png'):
        assert (tmp_path / name).stat().st_size > 10_000


# Issue 14, must-show 2 where the resonance limits the loop. The screw ten times softer
# alone (resonance 77 Hz) is not such a plant: there autotune rightly proposes no notch
# (doc/autotune.md; test_autotune). Under a slide four times as heavy (20 kg, slide / motor 0.65;
# its friction four times too, so that it is held against the nut as firmly as the default slide)
# the resonance (46 Hz) does. Lockstep runs of 2026-11-24: identify 46.0-47.6 Hz in eight runs of
# nine (the plant's 45.8; the ninth went wrong, below); the shipped gains 0.5-0.7 dB and a
# negative phase margin on the measured loop, and one of their moves never came to rest
# (output p-p 0.14 V); the proposal a notch at 46.0-49.0 Hz, 1.6-7.2 × the ki without one,
# 8.2-13.4 dB / 45.5-52.1°, every move at rest, output p-p 0.000-0.001 V, final error 0
# (settle 0.01-5.1 s, overshoot 0-101 counts: identify's kaff is -41 % to +12 % on this slide,
# and the last count is crept in against the slide's stiction; doc/autotune.md).
HEAVY_SLIDE = ['--plant', 'x.screw_stiffness:=1.0e6', '--plant', 'x.slide_mass:=20.0',
               '--plant', 'x.slide_coulomb:=40.0', '--plant', 'x.slide_stiction:=42.0']


def _autotune(node_env, tmp_path, plant: list[str], resonance_hz: float):
    """`autotune --spawn --lockstep --apply` on the plant of `plant` (launch arguments): the run
    and the registers it proposed. An identify that measured the resonance more than 5 % off
    `resonance_hz` makes the test an XFAIL with the number: identify's known failure
    (doc/autotune.md, test_ros_identify), its first stepped sine gone wrong and the fine one
    searching around a wrong resonance (one run of six on the heavy slide, 2026-11-24: 178 Hz,
    damping 0.93). Not autotune's to judge. Each move is watched 0.5 s at rest (`--rest`; the
    resonance, not the rest, is these tests' question: the suite's time)."""
    run = subprocess.run([sys.executable, '-m', 'motion_ctrl.tools.autotune', '--spawn',
                          '--lockstep', '--apply', '--rest', '0.5', '-o', str(tmp_path)] + plant
                         + UNTUNED,
                         env=node_env, capture_output=True, text=True, timeout=290)
    print(run.stdout[-5000:])
    path = tmp_path / 'identify' / 'identify.yaml'
    assert path.is_file(), f'identify failed, logs in {tmp_path}:\n' + run.stdout[-3000:] \
        + run.stderr[-3000:]
    ident = yaml.safe_load(path.read_text())
    if ident['resonance_hz'] != pytest.approx(resonance_hz, rel=0.05):
        pytest.xfail(f'identify measured a resonance of {ident["resonance_hz"]:.1f} Hz (the '
                     f'plant: {resonance_hz} Hz): its first stepped sine went wrong')
    assert run.returncode == 0, f'autotune failed, logs in {tmp_path}:\n' + run.stdout[-3000:] \
        + run.stderr[-3000:]
    regs = yaml.safe_load((tmp_path / 'autotune.yaml').read_text())['controller'][
        'ros__parameters']
    return run, regs


# Opt-in (60 s): test_autotune.test_a_resonance_that_limits_the_loop_gets_a_notch holds the same
# rule on this plant without ROS, and the stiff run above takes the whole tool over ROS in the
# default suite, which is kept well under CI's 15 minutes.
@long_run('60 s; test_autotune gives this plant its notch without ROS, the stiff run above '
          'takes the tool over ROS')
@pytest.mark.timeout(300)
def test_autotune_notch_where_the_resonance_limits_the_loop(node_env, tmp_path):
    run, regs = _autotune(node_env, tmp_path, HEAVY_SLIDE, resonance_hz=45.8)
    assert regs['x.notch_n1'] != 0.0 and regs['x.notch_d2'] != 0.0, run.stdout[-3000:]
    assert 'the resonance limits the loop' in run.stdout
    v = yaml.safe_load((tmp_path / 'verification.yaml').read_text())
    assert v['before']['gain_margin_db'] < 8.0 or v['before']['phase_margin_deg'] < 45.0
    assert v['after']['gain_margin_db'] >= 8.0 and v['after']['phase_margin_deg'] >= 45.0
    assert len(v['after']['moves']) == 3
    # The accuracy autotune promises on this slide: its rest window (the exact count, or ±W
    # counts where the slide slips more than a count as it breaks away: ±1.5 when identify put
    # the slip at 2.0 counts), judged at the middle of the count read (doc/rest.md).
    window = regs.get('x.fine_position_tolerance',
                      CONTROLLER_AXIS['fine_position_tolerance'].default) * LOAD_COUNTS_PER_M
    for a in v['after']['moves']:
        # every move ends (MOTION_DONE within the tool's 10 s): how soon is not must-show 2's
        # question; on this slide the last count is crept in against 42 N of stiction (runs of
        # 2026-11-24: 10 ms to 5.1 s)
        assert math.isfinite(a['settle_ms']), a
        assert a['output_pp_v'] < 0.2, a
        assert abs(a['final_error_counts']) <= max(1.0, window + 0.5), (window, a)


# Opt-in (48 s): test_autotune holds the same rule on this plant without ROS, and the suite's
# time is kept well under CI's 15 minutes.
# MOTION_CTRL_LONG=1 scripts/test test/tools/test_ros_autotune.py
@pytest.mark.skipif(os.environ.get('MOTION_CTRL_LONG') != '1',
                    reason='opt-in, 48 s: MOTION_CTRL_LONG=1 (test_autotune checks the rule on '
                           'this plant without ROS)')
@pytest.mark.timeout(300)
def test_autotune_no_notch_where_the_resonance_does_not_limit_the_loop(node_env, tmp_path):
    """The screw ten times softer (resonance 76.8 Hz) under the default 5 kg slide: the shipped
    gains lose margin (2026-11-24: 3.7 dB / 27.0° measured), autotune finds the resonance and,
    by its rule, no notch (the loop is bounded by the phase margin at its 32 Hz crossover, not
    at the resonance); the proposal meets 8 dB / 45° on the measured loop and every move ends
    at rest without ringing (11.1 dB / 45.6°, 39 / 38 / 38 ms against 665 / 669 / 660 ms,
    output p-p 0.000 V)."""
    run, regs = _autotune(node_env, tmp_path, ['--plant', 'x.screw_stiffness:=1.0e6'],
                          resonance_hz=76.8)
    assert regs['x.notch_n1'] == 0.0 and regs['x.notch_d2'] == 0.0, run.stdout[-3000:]
    assert 'no notch: the resonance does not limit the loop' in run.stdout
    v = yaml.safe_load((tmp_path / 'verification.yaml').read_text())
    assert v['before']['gain_margin_db'] < 8.0 and v['before']['phase_margin_deg'] < 45.0
    assert v['after']['gain_margin_db'] >= 8.0 and v['after']['phase_margin_deg'] >= 45.0
    assert len(v['after']['moves']) == 3
    for b, a in zip(v['before']['moves'], v['after']['moves']):
        assert a['settle_ms'] < b['settle_ms'], (b, a)
        assert a['output_pp_v'] < 0.2 and abs(a['final_error_counts']) <= 1.0, a
        assert a['overshoot_counts'] <= 2.0, a


# Issue 30, must-show 1 over ROS: sticky slides (stiction above the sliding friction on a screw
# several times softer than the default: the slide slips 1.4-1.8 counts when it breaks away),
# the whole tool in lockstep. The first in the default suite; the other two opt-in (about two
# minutes each; test_rest holds the rule on all three without ROS).
STICKY = {
    'screw_5x_softer_stiction_2x': ['x.screw_stiffness:=2.0e6', 'x.slide_stiction:=21.0',
                                    'x.slide_coulomb:=17.0'],
    'screw_2_5x_softer_stiction_4x': ['x.screw_stiffness:=4.0e6', 'x.slide_stiction:=42.0',
                                      'x.slide_coulomb:=34.0'],
    'slide_8kg_screw_5x_softer': ['x.screw_stiffness:=2.0e6', 'x.slide_mass:=8.0',
                                  'x.slide_stiction:=34.0', 'x.slide_coulomb:=30.0'],
}
LONG = pytest.mark.skipif(os.environ.get('MOTION_CTRL_LONG') != '1',
                          reason='opt-in, about 2 min: MOTION_CTRL_LONG=1 (test_rest holds the '
                                 'rule on this slide without ROS)')


@pytest.mark.timeout(300)
@pytest.mark.parametrize('name', [
    # (opt-in since the sim clock is held to 4x real time: 56 s; test_rest holds the rule on
    # this slide without ROS, the notch and stiff runs above autotune over ROS)
    pytest.param('screw_5x_softer_stiction_2x', marks=LONG),
    pytest.param('screw_2_5x_softer_stiction_4x', marks=LONG),
    pytest.param('slide_8kg_screw_5x_softer', marks=LONG)])
def test_autotune_brings_a_sticky_slide_to_rest(node_env, tmp_path, name):
    """`autotune --spawn --lockstep --apply` on a sticky slide. identify's creeps measure the
    breakaway, and the rest rule predicts the slip and proposes ±1 count; today's autotune
    (the gains with the rest as shipped, tried for the record on every test move) leaves some
    of them hunting; where the shipped gains hunt (a stick-slip limit cycle, reported with
    its period and amplitude), the controller reports it in its log and /diagnostics; after the
    proposal every verification move reaches MOTION_DONE, the median within 300 ms of the end
    of the profile, the simulated slide within 1 count of the target, and stays: 2 s with
    neither the reading nor the output turning back."""
    plant = [a for p in STICKY[name] for a in ('--plant', p)]
    run = subprocess.run([sys.executable, '-m', 'motion_ctrl.tools.autotune', '--spawn',
                          '--lockstep', '--apply', '-o', str(tmp_path)] + plant + UNTUNED,
                         env=node_env, capture_output=True, text=True, timeout=290)
    print(run.stdout[-6000:])
    assert run.returncode == 0, f'autotune failed, logs in {tmp_path}:\n' + run.stdout[-3000:] \
        + run.stderr[-3000:]
    ident = yaml.safe_load((tmp_path / 'identify' / 'identify.yaml').read_text())
    assert ident['stick_slips_pos'] > 5 and ident['stick_slips_neg'] > 5, ident
    assert ident['breakaway_pos'] > ident['coulomb_pos'], ident
    v = yaml.safe_load((tmp_path / 'verification.yaml').read_text())
    r = v['rest']
    assert 1.0 < r['slip_counts'] < 2.0 and r['window_counts'] == 1.0, r
    assert r['promise'].startswith('±1 count of a target on a whole count'), r
    # the gains alone, the rest as shipped (today's autotune): a test move or more not at rest
    assert not r['control']['at_rest'] and r['control']['hunted'] >= 1, r
    before = v['before']['moves'][0]
    if not before['at_rest']:
        # the shipped gains hunt (on this slide, always in the harness): the verification
        # says with what period and amplitude, and the controller has said so in its log
        assert before['limit_cycle_period_s'] > 0.5, before
        assert 'x: hunting: ' in (tmp_path / 'controller.log').read_text()
        assert "the controller's /diagnostics: hunting: " in run.stdout
    after = v['after']['moves']
    assert len(after) == 3
    for m in after:
        assert m['at_rest'] and math.isfinite(m['settle_ms']), m
        assert abs(m['true_final_error_counts']) <= 1.0, m
        assert m['moved_counts'] == 0 and m['output_turns'] == 0, m
    assert sorted(m['settle_ms'] for m in after)[1] <= 300.0, after
    assert (tmp_path / 'steps.png').stat().st_size > 10_000
