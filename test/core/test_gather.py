"""Issue 14, the servo side: a test signal added to an axis's output tick by tick, every tick
recorded (PMAC's gather), the run ended by what ends a move; and the records it yields identify
the slide in closed loop (excitation as the instrument)."""
import numpy as np
import pytest

from motion_ctrl.analysis import identify as idf

from motion_ctrl.core import excitation as ex
from motion_ctrl.sim.harness import Harness
from motion_ctrl.core.registers import axis_defaults
from msg_defs.status import Status

T = 1e-3
FS = 1 / T
QUIET = dict(backlash=0.0, motor_coulomb=0.0, motor_stiction=0.0, slide_coulomb=0.0,
             slide_stiction=0.0, pitch_error_slope=0.0, pitch_error_amplitude=0.0)


def _ready(plant=None, **registers):
    h = Harness(axis_defaults() | registers, plant, record=False)
    h.run(0.05)
    assert h.axis.enable(True)[0]
    h.run(0.3)
    return h


def test_the_signal_goes_out_tick_by_tick_and_every_tick_is_recorded():
    h = _ready()
    e = ex.prbs(0.5, (5.0, 200.0), 0.5, FS)
    assert h.axis.excite(e, 0.005) == (True, '')
    servo = []
    for _ in range(e.ticks + 5):
        h.tick()
        servo.append(h.axis.output)               # the servo law's own output, each tick
    g = h.axis.gather
    assert g.ended == 'done' and g.tick == e.ticks
    rec = g.columns()
    assert np.array_equal(rec['excitation'], e.signal)
    assert np.allclose(rec['output'], np.array(servo[:e.ticks]) + e.signal)
    assert np.all(np.isfinite(rec['load'])) and np.ptp(rec['motor']) > 0


@pytest.mark.parametrize('how, why', [('stop', 'STOP'), ('abort', 'ABORT'),
                                      ('move', 'a new move')])
def test_a_stop_abort_or_move_ends_the_run(how, why):
    h = _ready()
    e = ex.log_chirp(0.5, (2.0, 100.0), 2.0, FS)
    assert h.axis.excite(e, 0.005)[0]
    h.run(0.2)
    {'stop': lambda: h.axis.stop('stop'), 'abort': h.axis.abort,
     'move': lambda: h.axis.move_to(h.axis.command_position + 0.001)}[how]()
    h.run(0.05)
    g = h.axis.gather
    assert g.ended == why and 150 <= g.tick <= 250
    assert np.all(np.isfinite(g.columns()['output']))


@pytest.mark.core_slow
def test_the_travel_budget_ends_the_run():
    h = _ready()
    e = ex.log_chirp(3.0, (0.5, 5.0), 4.0, FS)       # slow and large: the slide goes far
    assert h.axis.excite(e, 0.00005)[0]
    h.run(4.0)
    assert (h.axis.gather.ended or '').startswith('the slide left its travel budget of 0.05 mm')


@pytest.mark.parametrize('case', ['disabled', 'moving', 'budget', 'rate'])
def test_refused_unless_enabled_at_rest_with_a_budget(case):
    h = _ready()
    e = ex.prbs(0.5, (5.0, 200.0), 0.5, FS)
    if case == 'disabled':
        h.axis.enable(False)
        ok, reason = h.axis.excite(e, 0.005)
        assert 'not enabled' in reason
    elif case == 'moving':
        h.axis.move_to(0.01)
        h.tick()
        ok, reason = h.axis.excite(e, 0.005)
        assert 'the axis moves' in reason
    elif case == 'budget':
        ok, reason = h.axis.excite(e, float('nan'))
        assert 'travel budget' in reason
    else:
        ok, reason = h.axis.excite(ex.prbs(0.5, (5.0, 200.0), 0.5, 2 * FS), 0.005)
        assert '2000 Hz' in reason
    assert not ok and h.axis.gather is None


@pytest.mark.core_slow
def test_closed_loop_records_identify_the_slide():
    """The slide (backlash and friction off) in closed loop on its motor encoder, a PRBS of 2 V
    added to the output for 8 s: G = S_ry / S_ru from the records, with the excitation as the
    instrument, puts the two-mass resonance within 5 % of the plant's own."""
    h = _ready(QUIET, feedback='motor')
    e = ex.prbs(2.0, (1.0, 500.0), 8.0, FS)
    assert h.axis.excite(e, 0.05)[0]
    h.run(e.duration + 0.01)
    g = h.axis.gather
    assert g.ended == 'done', g.ended
    rec = g.columns()
    motor = idf.frequency_response(rec['output'], rec['motor'], FS, r=rec['excitation'],
                                   difference=True)
    load = idf.frequency_response(rec['output'], rec['load'], FS, r=rec['excitation'],
                                  difference=True)
    fit = idf.fit_two_mass(motor, load, band=(2.0, 400.0),
                           force_per_volt=h.plant._force_per_volt)
    assert fit.resonance_hz == pytest.approx(h.plant.resonance_hz, rel=0.05)


def test_a_base_motion_runs_under_the_signal_and_stops_after_it():
    """TwinCAT's base motion: the axis jogs at the velocity, the signal starts once it is
    MOTION_AT_VELOCITY, every recorded tick moves at about that velocity (the friction keeps
    its sign), and at the end the jog decelerates to rest inside the budget."""
    h = _ready()
    e = ex.stepped_sine(0.05, (20.0, 100.0), 1.0, FS, points=4)
    v = 0.01
    assert h.axis.excite(e, 0.05, v) == (True, '')
    g = h.axis.gather
    assert g.waiting and h.axis.profile.target_velocity == v
    h.run(e.duration + 0.5)
    assert g.ended == 'done' and g.tick == e.ticks
    rec = g.columns()
    assert np.array_equal(rec['excitation'], e.signal)
    speed = np.diff(rec['command']) * FS
    assert np.allclose(speed, v, rtol=1e-6)                 # at velocity from the first tick
    assert np.all(np.diff(rec['load']) > 0)                  # never reversed
    h.run(0.5)
    assert h.axis.status & Status.MOTION_DONE and not h.axis.profile.moving
    assert 0.0 < h.axis.load_pos < 0.05


def test_the_budget_brakes_a_base_motion_inside_it():
    """The budget keeps the braking distance in hand: the run ends before the slide has gone
    budget − braking distance, the jog brakes, the slide stops inside the budget."""
    h = _ready()
    e = ex.prbs(0.05, (5.0, 200.0), 1.0, FS)
    v, budget = 0.05, 0.03            # 1 s at 50 mm/s: refused by the plan ...
    ok, reason = h.axis.excite(e, budget, v)
    assert not ok and 'more than the travel budget 30 mm' in reason and h.axis.gather is None
    # ... so shrink the budget under way: the run ends early and brakes inside it
    assert h.axis.excite(e, 0.06, v)[0]
    h.axis.gather.budget = budget
    h.run(1.5)
    g = h.axis.gather
    assert g.ended.startswith('the slide left its travel budget of 30 mm (less 0.933 mm')
    assert h.axis.status & Status.MOTION_DONE and abs(h.axis.load_pos) <= budget


@pytest.mark.parametrize('case, words', [
    ('fast', 'above max_velocity'), ('limit', 'outside the soft limits'),
    ('running', 'a run is in progress'), ('nan', 'not a finite number')])
def test_base_motion_refusals_change_nothing(case, words):
    h = _ready()
    e = ex.prbs(0.05, (5.0, 200.0), 1.0, FS)
    v = 0.01
    if case == 'fast':
        v = 0.2
    elif case == 'limit':
        h.loop.stage('x', {'soft_limit_max': 0.005})
        h.tick()
    elif case == 'running':
        assert h.axis.excite(e, 0.05)[0]
    elif case == 'nan':
        v = float('nan')
    before = h.axis.gather
    ok, reason = h.axis.excite(e, 0.05, v)
    assert not ok and words in reason, reason
    assert h.axis.gather is before and not h.axis.profile.moving


def test_the_registers_start_a_run_through_the_servo_loop():
    """ServoLoop.excite: the excitation_* registers (staged just before, as a client sets them
    and then calls <axis>/excite) describe the run; a band above Nyquist is refused naming
    the registers."""
    h = _ready()
    regs = dict(excitation_signal='stepped_sine', excitation_amplitude=0.05,
                excitation_band_low=20.0, excitation_band_high=100.0, excitation_duration=1.0,
                excitation_points=4, excitation_budget=0.05, excitation_velocity=0.01)
    h.loop.stage('x', regs | {'excitation_band_high': 600.0})
    ok, reason = h.loop.excite('x')
    assert not ok and 'x.excitation_* registers (stepped_sine)' in reason and 'Nyquist' in reason
    h.loop.stage('x', regs)
    assert h.loop.excite('x') == (True, '')
    h.run(1.6)
    g = h.axis.gather
    assert g.ended == 'done' and g.base_velocity == 0.01
    assert np.array_equal(g.columns()['excitation'],
                          ex.stepped_sine(0.05, (20.0, 100.0), 1.0, FS, points=4).signal)
