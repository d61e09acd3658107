"""Issue 14, the servo side: a test signal added to an axis's output tick by tick, every tick
recorded (PMAC's gather), the run ended by what ends a move; and the records it yields identify
the slide in closed loop (excitation as the instrument)."""
import numpy as np
import pytest

from motion_ctrl.analysis import identify as idf

from motion_ctrl.core import excitation as ex
from motion_ctrl.sim.harness import Harness
from motion_ctrl.core.registers import axis_defaults

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
