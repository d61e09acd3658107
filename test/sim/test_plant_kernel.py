"""The plant's fast integration is the same physics, bit for bit (issue 13).

SlidePlant.step integrates with `_substeps`: the Karnopp friction step written out inline, the
parameters looked up once per configure, and the loop left early once both masses are stuck and
held. `reference_step` below is the integration as it was written before (one `_friction_step`
per mass and substep, every substep run): the kernel must give the same floats as it in every
regime (rest, stiction, breakaway, contact on
either flank, crossing the gap, end stops, brake, dynamic brake, saturation, non-finite commands,
other substep rates and step lengths, a state written from outside).
"""
import math
import random

import pytest

from motion_ctrl.sim.plant import _STICK_SPEED, _WALL_DAMPING, _WALL_STIFFNESS, SlidePlant


def _friction_step(v, force, mass, viscous, coulomb, stiction, dt):
    if v == 0.0:
        if abs(force) <= stiction:
            return 0.0
        f = force - math.copysign(coulomb, force)
        return f / mass * dt
    f = force - viscous * v - math.copysign(coulomb, v)
    v_new = v + f / mass * dt
    if v_new * v < 0.0 or abs(v_new) < _STICK_SPEED and abs(force) <= stiction:
        return 0.0
    return v_new


def reference_step(self, volts, dt, braking=False):
    """SlidePlant.step as first written (commit 91917d5), on a SlidePlant's state."""
    if not math.isfinite(volts):
        volts = 0.0
    p = self.params
    lim = p['amplifier_limit']
    volts = min(lim, max(-lim, volts))
    self.volts = volts
    n = max(1, math.ceil(dt * self.substep_rate - 1e-9))
    h = dt / n
    drive = self._force_per_volt * volts
    k, c, b = p['screw_stiffness'], p['screw_damping'], p['backlash']
    mm, ml = self.motor_mass, p['slide_mass']
    brake = p['brake'] == 1
    m_visc = self._m_visc_braked if braking else self._m_visc
    pitch = (p['pitch_error_slope'] * self.x_m + p['pitch_error_amplitude']
             * math.sin(2.0 * math.pi * self.x_m / p['pitch_error_period']))
    for _ in range(n):
        x_m, v_m, x_l, v_l = self.x_m, self.v_m, self.x_l, self.v_l
        d = x_m + pitch - x_l
        dv = v_m - v_l
        if d > 0.0:
            fc = max(0.0, k * d + c * dv)
        elif d < -b:
            fc = min(0.0, k * (d + b) + c * dv)
        else:
            fc = 0.0
        fw = 0.0
        if x_l > p['travel_max']:
            fw = -_WALL_STIFFNESS * (x_l - p['travel_max']) - _WALL_DAMPING * v_l
        elif x_l < p['travel_min']:
            fw = -_WALL_STIFFNESS * (x_l - p['travel_min']) - _WALL_DAMPING * v_l
        v_m = _friction_step(v_m, drive - fc, mm, m_visc, self._m_coul, self._m_stic, h)
        if brake:
            v_l = 0.0
        else:
            v_l = _friction_step(v_l, fc + fw, ml, p['slide_viscous'], p['slide_coulomb'],
                                 p['slide_stiction'], h)
        self.x_m = x_m + v_m * h
        self.v_m = v_m
        self.x_l = x_l + v_l * h
        self.v_l = v_l
    self.time += dt


def _cases():
    rng = random.Random(13)
    walk = [rng.uniform(-4.0, 4.0) for _ in range(600)]
    small = [rng.gauss(0.0, 0.3) for _ in range(600)]
    reversal = [1.5] * 300 + [0.0] * 200 + [-1.5] * 150 + [0.0] * 300
    return [
        ('rest', {}, [0.0] * 100, 1e-3),
        ('held by stiction', {}, [0.08] * 200, 1e-3),
        ('reversal: both flanks, the gap', {}, reversal, 1e-3),
        ('no pitch error', dict(pitch_error_slope=0.0, pitch_error_amplitude=0.0), reversal,
         1e-3),
        ('random commands', {}, walk, 1e-3),
        ('small commands: stick-slip', {}, small, 1e-3),
        ('saturation, nan, inf', {}, [50.0] * 50 + [-50.0] * 60 + [math.nan] * 20
         + [math.inf, -math.inf] * 5 + [-10.0, 10.0] * 5, 1e-3),
        ('brake', dict(brake=1), [3.0] * 200 + [-3.0] * 200, 1e-3),
        ('end stop max', dict(travel_max=0.004), [3.0] * 400 + [-0.5] * 100, 1e-3),
        ('end stop min', dict(travel_min=-0.003), [-3.0] * 400 + [0.5] * 100, 1e-3),
        ('5 kHz substeps', dict(substep_rate=5000.0), walk, 1e-3),
        ('1 substep per step', dict(substep_rate=1000.0), walk, 1e-3),
        ('odd step length', {}, walk[:300], 3.7e-4),
        ('long steps', {}, [2.0] * 40 + [-2.0] * 40, 5.3e-3),
        ('stiff screw, wide gap', dict(screw_stiffness=5e7, backlash=1e-4, slide_mass=2.0),
         walk, 1e-3),
        ('no friction', dict(slide_stiction=0.0, slide_coulomb=0.0, motor_stiction=0.0,
                             motor_coulomb=0.0), [v / 4 for v in walk], 1e-3),
    ]


def _run(step, params, volts, dt):
    p = SlidePlant(**params)
    states = []
    for i, v in enumerate(volts):
        step(p, v, dt, braking=i % 7 == 3)      # the dynamic brake now and then
        states.append((p.x_m, p.v_m, p.x_l, p.v_l, p.volts, p.time, p.encoder_counts()))
    return states


@pytest.mark.parametrize('name, params, volts, dt', _cases(), ids=[c[0] for c in _cases()])
def test_the_kernel_gives_the_reference_floats(name, params, volts, dt):
    expected = _run(reference_step, params, volts, dt)
    got = _run(SlidePlant.step, params, volts, dt)
    first = next((i for i, (e, g) in enumerate(zip(expected, got)) if e != g), None)
    assert first is None, f'step {first}: {got[first]} != {expected[first]}'


def test_a_state_written_from_outside():
    """tuning.py kicks the plant by writing its velocities."""
    a, b = SlidePlant(), SlidePlant()
    for p in (a, b):
        p.v_m = p.v_l = 0.005
    for _ in range(200):
        reference_step(a, 0.0, 1e-3)
        b.step(0.0, 1e-3)
        assert (b.x_m, b.v_m, b.x_l, b.v_l) == (a.x_m, a.v_m, a.x_l, a.v_l)

