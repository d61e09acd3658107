"""motion_ctrl.analysis.autotune on synthetic two-mass plants with a known answer.

The "measured" responses are the exact zero-order-hold frequency responses of a physical
two-mass state space (motor mass, screw spring and damper, slide mass, viscous friction on
both; scipy.signal.cont2discrete), sampled where identify's stepped sine measures, with 1 % of
complex noise; the model handed to autotune is the two-mass model at the true resonances. The
margins the proposal promises are then checked independently, on the exact discrete plant over
a dense grid.
"""
import dataclasses
import math

import numpy as np
import pytest
import yaml

from test_identify import BL, BM, C_S, FS, K_S, KF, ML, MM, T, two_mass

from motion_ctrl.analysis import autotune as at
from motion_ctrl.analysis import identify as idf
from motion_ctrl.core import notch as nt
from motion_ctrl.core import registers
from motion_ctrl.core.registers import INCH
from motion_ctrl.sim.harness import Harness
from motion_ctrl.tools import autotune as tool
from msg_defs.status import Status



def plant(k=K_S, ml=ML):
    """(A, B) discrete, state [xm, vm, xl, vl] (test_identify's two-mass plant, the default
    slide in load-equivalent linear terms), and the two-mass model at its exact continuous
    resonances."""
    ad, bd, truth = two_mass(k=k, ml=ml)
    model = idf.TwoMassModel(KF / (MM + ml), (BM + BL) / (MM + ml), truth['resonance'],
                             truth['resonance_damping'], truth['antiresonance'],
                             truth['antiresonance_damping'], C_S / k)
    return ad, bd, model


def exact(ad, bd, freq):
    """(motor, load) responses [m/V] of the discrete plant: y[n] sampled before u[n] applies."""
    out = []
    for f in np.asarray(freq, dtype=float):
        z = np.exp(2j * math.pi * f * T)
        x = np.linalg.solve(z * np.eye(4) - ad, bd)
        out.append((x[0], x[2]))
    a = np.array(out)
    return a[:, 0], a[:, 1]


def axis(k=K_S, noise=0.01, seed=1, ml=ML):
    ad, bd, model = plant(k, ml)
    f = np.unique(np.concatenate([np.geomspace(20.0, 400.0, 48),
                                  np.linspace(0.8, 1.1, 16) * model.resonance_hz]))
    m, ld = exact(ad, bd, f)
    rng = np.random.default_rng(seed)

    def noisy(g):
        return g * (1 + noise * (rng.standard_normal(g.size) + 1j * rng.standard_normal(g.size)))
    coh = np.full(f.size, 0.99)
    motor = idf.FrequencyResponse(f, noisy(m), coh, FS, 'stepped_sine')
    load = idf.FrequencyResponse(f, noisy(ld), coh.copy(), FS, 'stepped_sine')
    return at.AxisResponse(model, T, 0, coulomb=0.24, viscous=(BM + BL) / KF,
                           motor=motor, load=load), (ad, bd)


def check(regs, feedback, ad, bd):
    """Margins of the registers on the exact discrete plant, dense grid, one tick of latency."""
    f = np.geomspace(0.2, 499.5, 6000)
    m, ld = exact(ad, bd, f)
    pos, vel = (ld, m) if feedback == 'dual' else (m, m)
    return idf.margins(f, idf.pid_open_loop(f, regs, T, pos, vel, latency_ticks=1))


@pytest.mark.parametrize('preset,feedback', [('stiff', 'dual'), ('soft', 'motor')])
def test_proposal_meets_its_margins_on_the_plant(preset, feedback):
    ax, (ad, bd) = axis()
    p = at.propose(ax, preset, feedback)
    target = at.PRESETS[preset]
    assert p.ok, at.format_proposal(p)
    assert p.evaluation.measured is not None       # the measured points took part
    exact_margins = check(p.registers, feedback, ad, bd)
    assert exact_margins.gain_margin_db >= target.gain_margin_db
    assert exact_margins.phase_margin_deg >= target.phase_margin_deg
    # what it promises is what the plant has (the model is exact; 1 % noise on the points)
    assert exact_margins.phase_margin_deg == pytest.approx(p.evaluation.phase_margin_deg, abs=1.0)
    assert exact_margins.crossover_hz <= target.bandwidth_fraction * ax.model.antiresonance_hz
    assert p.registers['kaff'] == pytest.approx(1.0 / ax.model.accel_per_volt, rel=1e-3)
    assert p.registers['kvff'] == pytest.approx(p.registers['kd'] + ax.viscous, rel=1e-3)
    assert p.registers['friction_ff'] == pytest.approx(0.24)


def test_low_resonance_defaults_lose_margin_and_the_proposal_meets_it():
    """Screw stiffness / 10 (resonance 77 Hz, anti-resonance 71 Hz): the shipped gains lose
    margin on it; autotune's stiff proposal meets 8 dB / 45° on the plant, dual and motor. No
    notch by the rule: without one the gains stop at the phase margin at their crossover
    (dual, 32 Hz) or at the preset's crossover limit (motor, half the anti-resonance), not at
    the resonance; and a notch, forced, costs ki (its phase lag below its centre, 0.4-0.5 of the
    way up to it at these crossovers). Asked for one, it designs one around the resonance that
    cuts it and meets the margins too."""
    ax, (ad, bd) = axis(k=K_S / 10)
    fr = ax.model.resonance_hz
    assert fr == pytest.approx(76.8, abs=0.5)
    before = at.evaluate(ax, registers.axis_defaults())
    assert not before.ok(at.PRESETS['stiff'])
    shipped = check(registers.axis_defaults(), 'dual', ad, bd)
    assert shipped.gain_margin_db < 8.0 and shipped.phase_margin_deg < 45.0     # 3.9 dB, 27°
    for feedback in ('dual', 'motor'):
        plain_ki = None
        for notch in (None, True):
            p = at.propose(ax, 'stiff', feedback, notch=notch)
            m = check(p.registers, feedback, ad, bd)
            assert p.ok and m.gain_margin_db >= 8.0 and m.phase_margin_deg >= 45.0, \
                at.format_proposal(p)
            if notch:
                assert p.notch is not None
                assert fr <= p.notch.f_zero <= 1.1 * fr + 1e-9
                assert nt.gain_db(tuple(p.registers[k] for k in at.NOTCH_REGISTERS), fr, T) \
                    <= -at.NOTCH_MIN_CUT_DB
                assert p.registers['ki'] < plain_ki                  # 0.65 × dual, 0.62 × motor
            else:
                assert p.notch is None and p.registers['notch_n1'] == 0.0, at.format_proposal(p)
                assert not p.resonance_limits
                assert any(n.startswith('no notch: the resonance does not limit the loop')
                           for n in p.notes)
                plain_ki = p.registers['ki']


HEAVY = dict(k=K_S / 10, ml=4 * ML)     # the screw / 10 under a slide 4 × as heavy


@pytest.mark.parametrize('feedback', ['dual', 'motor'])
def test_a_resonance_that_limits_the_loop_gets_a_notch(feedback):
    """Issue 14, must-show 2 where the resonance does limit the loop: the screw / 10 under a
    slide four times as heavy (20 kg; resonance 46 Hz, anti-resonance 36 Hz, slide / motor
    0.65). Without a notch the resonance's peak crosses 0 dB: the best gains keep under a tenth
    of the ki (dual 4,121, motor 7,103). By default (no notch argument) autotune proposes a
    notch (the rule: the shape it uses is held back at the resonance without it, and it buys
    over 10 % more ki), which meets 8 dB / 45° on the plant itself; in the harness (friction,
    backlash, one tick of latency) the demo's moves end without ringing at rest."""
    ax, (ad, bd) = axis(**HEAVY)
    fr = ax.model.resonance_hz
    assert fr == pytest.approx(45.8, abs=0.5)
    shipped = check(registers.axis_defaults(), feedback, ad, bd)
    assert shipped.phase_margin_deg < 45.0
    p = at.propose(ax, 'stiff', feedback)
    assert p.notch is not None and p.resonance_limits, at.format_proposal(p)
    assert p.registers['notch_n1'] != 0.0 and p.registers['notch_d2'] != 0.0
    assert nt.gain_db(tuple(p.registers[k] for k in at.NOTCH_REGISTERS), fr, T) \
        <= -at.NOTCH_MIN_CUT_DB
    m = check(p.registers, feedback, ad, bd)
    assert p.ok and m.gain_margin_db >= 8.0 and m.phase_margin_deg >= 45.0, at.format_proposal(p)
    plain = at.propose(ax, 'stiff', feedback, notch=False)
    assert p.registers['ki'] >= at.NOTCH_KEEP_GAIN * plain.registers['ki']
    print(at.format_proposal(p))
    moves = _demo_moves(p.registers | {'feedback': feedback},
                        plant=dict(screw_stiffness=1e6, slide_mass=20.0))
    print('settle [ms], overshoot, final error [counts], output p-p at rest [V]:', moves)
    for settle, _, err, pp in moves:
        assert math.isfinite(settle) and pp < 0.2, moves
        if feedback == 'dual':
            assert abs(err) <= 1.0, moves


def test_bad_input_is_refused_with_a_reason():
    ax, _ = axis()
    with pytest.raises(ValueError, match='preset'):
        at.propose(ax, 'rigid')
    with pytest.raises(ValueError, match='feedback'):
        at.propose(ax, 'stiff', 'load')
    with pytest.raises(ValueError, match='notch_d2'):
        at.evaluate(ax, dict(kp=1.0, notch_d2=3.0))
    with pytest.raises(ValueError, match='kp'):
        at.evaluate(ax, dict(ki=1.0))
    with pytest.raises(ValueError, match='anti-resonance < resonance'):
        at.AxisResponse(idf.TwoMassModel(1.7, 1.0, 200.0, 0.02, 250.0, 0.01), T)
    with pytest.raises(ValueError, match='both'):
        at.AxisResponse(ax.model, T, motor=ax.motor)


def _write_identify(folder, ax) -> None:
    """What identify writes into `folder` (identify.yaml, the response) for axis `ax`."""
    m = ax.model
    (folder / 'identify.yaml').write_text(yaml.safe_dump({k: float(v) for k, v in dict(
        accel_per_volt=m.accel_per_volt, viscous_pole=m.viscous_pole,
        resonance_hz=m.resonance_hz, resonance_damping=m.resonance_damping,
        antiresonance_hz=m.antiresonance_hz, antiresonance_damping=m.antiresonance_damping,
        load_zero=m.load_zero, delay_ticks=0, sample_period=T, coulomb=0.24,
        viscous=ax.viscous).items()}))
    at.write_response(folder / at.RESPONSE_FILE, ax.motor, ax.load)


def test_files_round_trip(tmp_path):
    ax, _ = axis()
    with pytest.raises(ValueError, match='identify.yaml'):
        at.read_identify(tmp_path)
    m = ax.model
    _write_identify(tmp_path, ax)
    back = at.read_identify(tmp_path / 'identify.yaml')
    assert back.model == m
    assert back.motor is not None
    np.testing.assert_allclose(back.motor.response, ax.motor.response, rtol=1e-8)
    text = at.params_yaml(dict(kp=7000.0, ki=1.5e5, friction_ff=1e-6), 'x', comment='hi')
    doc = yaml.safe_load(text)
    assert doc == {'controller': {'ros__parameters': {'x.kp': 7000.0, 'x.ki': 150000.0,
                                                      'x.friction_ff': 1e-6}}}
    assert all(isinstance(v, float) for v in doc['controller']['ros__parameters'].values())


def _demo_moves(regs, plant=None):
    """The demo's three moves (1 in, +2 in, back to +1 in) in the harness, one tick of
    latency: per move (ms from the end of the profile to MOTION_DONE, overshoot [counts],
    final slide error [counts] 0.1 s after MOTION_DONE, the output's peak-to-peak [V] over
    that 0.1 s)."""
    h = Harness(regs, plant=plant, latency_ticks=1)
    h.run(0.1)
    out = []
    for target in (INCH, 2 * INCH, INCH):
        sign = 1.0 if target > h.plant.x_l else -1.0
        ok, why = h.axis.move_to(target)
        assert ok, why
        h.tick()
        end = done = None
        peak = 0.0
        for _ in range(5000):
            h.tick()
            if end is None and h.axis.status & Status.AT_TARGET:
                end = h.time
            if end is not None:
                peak = max(peak, sign * h.load_error_counts(target))
            if h.axis.status & Status.MOTION_DONE:
                done = h.time
                break
        rest = []
        for _ in range(100):
            h.tick()
            rest.append(h.axis.output)
        settle = (done - end) * 1e3 if done is not None and end is not None else math.inf
        out.append((settle, peak, h.load_error_counts(target), float(np.ptp(rest))))
    return out


def test_a_viscous_pole_fitted_high_does_not_leave_the_search_without_a_start():
    """identify's band starts at 20 Hz, so the viscous pole it fits is barely seen and may come
    out at 10 rad/s (the stiffness/10 slide in lockstep, 2026-11-24; the plant's own is 0.1):
    then the lowest design crossover (0.5 Hz) puts no gain crossover on the grid at all. Each
    shape's search starts at the lowest crossover that is feasible (it used to give the shape
    up, and with every shape given up: "no gains meet stiff")."""
    ax, (ad, bd) = axis()
    high = dataclasses.replace(ax, model=dataclasses.replace(ax.model, viscous_pole=10.3))
    p = at.propose(high, 'stiff', 'dual')
    assert p.ok, at.format_proposal(p)
    assert check(p.registers, 'dual', ad, bd).phase_margin_deg >= 44.0


def test_stiff_preset_settles_the_demo_moves_faster_than_the_defaults():
    """Issue 14, must-show 3 in the harness (the DDS run is the tool's --apply): the stiff
    preset from the two-mass model of the default slide, on the simulated slide with its
    friction and backlash, settles each of the three moves faster than the shipped gains, the
    median within the issue's 150 ms, within 1 count and with at most 2 counts of overshoot.
    The last counts are the breakaway aid's (friction_ff_at_rest, 0.75 of the Coulomb
    friction): without it the same gains creep them out on the integrator. Measured
    2026-11-24: defaults 713 / 706 / 653 ms; stiff 30 / 30 / 32 ms, without the aid 309 / 311 /
    319 ms."""
    ax, _ = axis()
    p = at.propose(ax, 'stiff', 'dual')
    assert p.registers['friction_ff_at_rest'] == pytest.approx(0.75 * 0.24, rel=0.01)
    before = _demo_moves({})
    after = _demo_moves(p.registers)
    creeping = _demo_moves(p.registers | {'friction_ff_at_rest': 0.0})
    print('settle [ms] defaults, stiff, stiff without the aid:',
          [[round(m[0]) for m in r] for r in (before, after, creeping)])
    for (s0, _, _, _), (s1, over, err, _) in zip(before, after):
        assert s1 < s0, (before, after)
        assert abs(err) <= 1.0 and over <= 2.0, after
    assert np.median([m[0] for m in after]) <= 150.0
    assert np.median([m[0] for m in creeping]) > 150.0


def test_the_tool_offline(tmp_path, capsys):
    """`autotune --from DIR` needs no ROS: the proposal against the register table's defaults
    or a --current file, YAML and the Bode plot written; bad input is a clear error, exit 1."""
    ax, _ = axis()
    m = ax.model
    src = tmp_path / 'identify'
    src.mkdir()
    _write_identify(src, ax)
    out = tmp_path / 'out'
    assert tool.main(['--from', str(src), '-o', str(out)]) == 0
    regs = yaml.safe_load((out / 'autotune.yaml').read_text())['controller']['ros__parameters']
    assert regs['x.kaff'] == pytest.approx(1.0 / m.accel_per_volt, rel=1e-3)
    assert (out / 'open_loop.png').stat().st_size > 10_000
    text = capsys.readouterr().out
    assert 'before:   gain margin' in text and "meets the preset's 8 dB / 45°" in text
    cur = tmp_path / 'current.yaml'
    cur.write_text(at.params_yaml(dict(kp=8000.0, ki=50000.0, kd=100.0)))
    assert tool.main(['--from', str(src), '--current', str(cur), '-o', str(out)]) == 0
    assert '| kp | 8000 |' in capsys.readouterr().out
    assert tool.main(['--from', str(src), '--feedback', 'motor', '-o', str(out)]) == 0
    regs = yaml.safe_load((out / 'autotune.yaml').read_text())['controller']['ros__parameters']
    assert regs['x.feedback'] == 'motor'
    assert tool.main(['--from', str(tmp_path / 'nothing'), '-o', str(out)]) == 1
    assert 'identify.yaml: not found' in capsys.readouterr().err
    assert tool.main(['--from', str(src), '--current', str(cur), '--axis', 'y',
                      '-o', str(out)]) == 1
    assert 'no registers of axis y' in capsys.readouterr().err
