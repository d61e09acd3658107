"""`hardware: sim` over ROS (issue 25): the controller alone, the slides simulated inside its loop,
driven through the same topics, services and parameters as with the plant node: moves, jogs,
stops, a two-axis trajectory, an excitation run, the compensation tables, the plant's registers
live on the controller, its amplifier states; the headline in real time and in sim time (the
controller the clock); and bad start-up input refused with one line, exit 2."""
import subprocess
import sys
import time

import pytest

import msg_defs as md
from kit import COUNT, INCH, running_slide, spin_for
from msg_defs.status import Status
from motion_ctrl.ros.client import SlideClient
from motion_ctrl.core.registers import SHIPPED_SLIDE_TUNING, shipped_tuning
from motion_ctrl.ros import processes
from motion_ctrl.ros.processes import params_dir

# No rerun on a stall of the servo link (none in the loop; the amplifier watchdog is a subject).
pytestmark = pytest.mark.servo_link_under_test


def _client(axes=('x', 'y'), context=None):
    return SlideClient(axes=axes, name='sim_client', services=True, context=context)


@pytest.fixture(scope='module')
def sim(rclpy_session, tmp_path_factory):
    """Two axes, real time, the shipped registers (a plant: section from params/plant.yaml)."""
    with running_slide(tmp_path_factory.mktemp('sim'), _client, {'axes': "['x','y']"},
                       hardware='sim', exit_zero=True) as s:
        yield s


def _error_counts(client, axis, target) -> float:
    spin_for(client, 0.05)                   # the latest truth after MOTION_DONE
    return (client.load_position(axis) - target) / COUNT


def _ready(client, axis='x') -> None:
    """The axis at rest with its loop closed (a test before may have left it open)."""
    s = client.status[axis]
    if s is None or not s & Status.ENABLED or s & (Status.FEEDBACK_FAULT
                                                    | Status.FOLLOWING_ERROR_FATAL):
        assert client.call('reset', axis=axis).success
        assert client.call('enable', True, axis=axis).success
    assert client.spin_until(lambda: client.status[axis] & Status.ENABLED, 5.0)


@pytest.mark.timeout(120)
def test_the_headline_in_real_time(sim):
    c = sim.client
    assert c.move({'x': 2 * INCH}, timeout=10.0) is not None, repr(Status(c.status['x']))
    assert c.move({'x': INCH}, timeout=10.0) is not None, repr(Status(c.status['x']))
    error = _error_counts(c, 'x', INCH)
    assert abs(error) <= 1.0, f'slide {error:+.2f} counts from the target'
    assert 'hardware sim' in sim.log('controller')


def test_no_plant_node_and_the_slides_states_published_by_the_controller(sim):
    c = sim.client
    names = {n for n, _ in c.get_node_names_and_namespaces()}
    assert 'controller' in names and 'plant' not in names, names
    assert c.count_publishers(md.ENCODERS) == 0 and c.count_subscribers(md.COMMAND) == 0
    for topic in (md.PLANT_STATES, md.AMPLIFIER_STATES, md.amplifier_fault_topic('x'),
                  md.amplifier_fault_topic('y')):
        assert c.count_publishers(topic) == 1, topic
    assert set(c.truth) == {'x_motor', 'x_load', 'y_motor', 'y_load'}


def test_a_two_axis_trajectory_lands_both_axes(sim):
    c = sim.client
    for a in ('x', 'y'):
        _ready(c, a)
    x0, y0 = (round(c.load_position(a) / COUNT) * COUNT for a in ('x', 'y'))
    dx, dy = 1575 * COUNT, -790 * COUNT            # 4 mm and -2 mm, on whole counts
    t = c.follow(['x', 'y'], [0.5, 1.0], [[x0 + dx / 2, y0 + dy / 2], [x0 + dx, y0 + dy]])
    assert t is not None, {a: repr(Status(c.status[a])) for a in ('x', 'y')}
    # Settled: the middle of the count the load encoder reads (window_centre count_middle, the
    # shipped tuning) within fine_position_tolerance (0.59 counts) of a target on a whole
    # count: the reading is the target's or the one below, the slide within [-1, +1) counts.
    for a, target in (('x', x0 + dx), ('y', y0 + dy)):
        assert -1.0 <= _error_counts(c, a, target) < 1.0, a


def test_a_jog_then_stop_estop_and_abort(sim):
    c = sim.client
    _ready(c, 'y')
    for command, bit in (('stop', Status.STOPPED), ('estop', Status.ESTOPPED),
                         ('abort', Status.ABORTED)):
        mark = len(c.status_log['y'])
        c.pub_velocity.publish(md.joint_state(c.get_clock().now().to_msg(), ['y'],
                                              velocity=[-0.02]))
        assert c.spin_until(lambda: c.status['y'] & Status.MOTION_AT_VELOCITY, 5.0), \
            repr(Status(c.status['y']))
        x_before = c.load_position('y')
        assert c.call(command, axis='y').success
        assert c.wait_moves({'y': mark}, time.monotonic(), 5.0) is not None, \
            repr(Status(c.status['y']))
        assert c.status['y'] & bit
        c.truth_since(time.time())
        assert c.load_position('y') < x_before        # it was moving, and it stopped
        _ready(c, 'y')


def test_an_excitation_run_publishes_its_record(sim):
    from std_msgs.msg import Float64MultiArray
    c = sim.client
    _ready(c, 'x')
    records = []
    c.create_subscription(Float64MultiArray, md.gather_topic('x'), records.append,
                          md.GATHER_QOS)
    from rclpy.parameter import Parameter
    from rclpy.parameter_client import AsyncParameterClient
    params = AsyncParameterClient(c, 'controller')
    assert c.spin_until(params.services_are_ready, 10.0)
    c.answer(lambda: params.set_parameters([Parameter('x.excitation_duration', value=0.5)]))
    answer = c.call('excite', axis='x')
    assert answer.success and answer.message.startswith('x: run 1: prbs'), answer.message
    assert c.spin_until(lambda: records, 10.0), 'no record on x/gather'
    columns, meta = md.read_gather(records[-1])
    assert meta['ended'] == 'done' and meta['ticks'] == 500, meta
    assert len(columns['output']) == 500 and max(map(abs, columns['excitation'])) > 0.1


def test_the_tables_and_the_plant_registers_live_on_the_controller(sim):
    """The reversal on the motor loop alone misses by the backlash; PMAC's Ixx86 matched to the
    slide brings it back; the slide's backlash set on the controller (a plant register) shows
    in the next reversal."""
    c = sim.client
    from rclpy.parameter import Parameter
    from rclpy.parameter_client import AsyncParameterClient
    params = AsyncParameterClient(c, 'controller')
    assert c.spin_until(params.services_are_ready, 10.0)

    def set_(**values):
        r = c.answer(lambda: params.set_parameters_atomically(
            [Parameter(k.replace('__', '.'), value=v) for k, v in values.items()]))
        assert r.result.successful, r.result.reason

    def reversal() -> float:
        _ready(c, 'x')
        start = round(c.load_position('x') / COUNT) * COUNT
        assert c.move({'x': start + 0.004}, timeout=10.0) is not None
        assert c.move({'x': start + 0.002}, timeout=10.0) is not None
        return _error_counts(c, 'x', start + 0.002)
    try:
        set_(x__feedback='motor')
        missed = reversal()
        set_(x__backlash_distance=50.8e-6)
        compensated = reversal()
        set_(x__backlash=2 * 50.8e-6)          # the slide's own gap, doubled
        doubled = reversal()
    finally:
        set_(x__feedback='dual', x__backlash_distance=0.0, x__backlash=50.8e-6)
    assert missed > 15, missed                  # about the 20 counts of backlash
    assert abs(compensated) <= 3, compensated
    assert doubled > 15, doubled                # the compensation covers half of it now


def test_every_axis_of_the_shipped_files_gets_the_slides_tuning(sim):
    """params/controller.yaml tunes x; y, named in `axes` only, runs the same shipped tuning
    (doc/gains.md), not the table's defaults."""
    c = sim.client
    from rclpy.parameter_client import AsyncParameterClient
    params = AsyncParameterClient(c, 'controller')
    assert c.spin_until(params.services_are_ready, 10.0)
    names = [f'{a}.{k}' for a in ('x', 'y') for k in SHIPPED_SLIDE_TUNING]
    got = c.answer(lambda: params.get_parameters(names)).values
    values = dict(zip(names, (v.string_value or v.double_value for v in got)))
    assert values == shipped_tuning(('x', 'y')), values


def test_an_override_of_another_axis_wins_over_the_shipped_tuning(monkeypatch):
    started = {}

    class Recorded:
        def __init__(self, module, params_file=None, params=None, log_path=None, env=None):
            started[module] = params
    monkeypatch.setattr(processes, 'NodeProcess', Recorded)
    processes.start_slide({'axes': "['x', 'y']", 'y.kp': 5000.0})
    assert started['controller_node'] == shipped_tuning(['y']) | {'axes': "['x', 'y']",
                                                                    'y.kp': 5000.0}
    processes.start_slide({'axes': "['x', 'y']"}, params_files=False)
    assert started['controller_node'] == {'axes': "['x', 'y']"}


def test_a_plant_register_is_refused_by_the_plants_rules(sim):
    c = sim.client
    from rclpy.parameter import Parameter
    from rclpy.parameter_client import AsyncParameterClient
    params = AsyncParameterClient(c, 'controller')
    assert c.spin_until(params.services_are_ready, 10.0)
    r = c.answer(lambda: params.set_parameters([Parameter('x.slide_stiction', value=1.0)]))
    assert not r.results[0].successful
    assert r.results[0].reason == 'x.slide_stiction must be >= slide_coulomb'
    r = c.answer(lambda: params.set_parameters([Parameter('hardware', value='topics')]))
    assert not r.results[0].successful and 'read-only' in r.results[0].reason


def test_the_amplifiers_run_while_their_axes_are_commanded(sim):
    """The simulated amplifier's command watchdog: on while the loop commands it (its output
    the controller's, as amplifier_states shows), as the plant node's."""
    from std_msgs.msg import Bool
    c = sim.client
    faults = []
    c.create_subscription(Bool, md.amplifier_fault_topic('x'), lambda m: faults.append(m.data),
                          md.STATUS_QOS)
    # (a late joiner gets the kept history first: the amplifier off before the first command)
    assert c.spin_until(lambda: faults and faults[-1] is False, 5.0), faults
    c.spin_for(0.5)
    assert faults[-1] is False


@pytest.mark.timeout(120)
def test_the_headline_in_sim_time_the_controller_the_clock(own_domain, tmp_path, monkeypatch):
    """use_sim_time: the controller ticks back to back and publishes /clock (its speed is
    measured by `benchmark`); the same moves land. (A domain of its own: the module's slide
    runs meanwhile.)"""
    from rosgraph_msgs.msg import Clock
    monkeypatch.setenv('MOTION_CTRL_SERVO_DOMAIN', 'off')
    with running_slide(tmp_path, lambda: _client(('x',), own_domain), {'use_sim_time': 'true'},
                       hardware='sim', exit_zero=True) as s:
        c = s.client
        clock = []
        c.create_subscription(Clock, md.CLOCK, lambda m: clock.append(
            (time.monotonic(), m.clock.sec + m.clock.nanosec * 1e-9)), 10)
        assert c.spin_until(lambda: clock, 10.0), 'no /clock'
        assert c.move({'x': 2 * INCH}, timeout=10.0) is not None
        assert c.move({'x': INCH}, timeout=10.0) is not None
        # The truth stamped after MOTION_DONE in the controller's time (a reader of a stream
        # published every tick, flat out, takes what it can: wait for a sample that new).
        done = clock[-1][1]
        assert c.truth_since(done, 10.0), f'no plant_states after {done} s'
        error = (c.truth['x_load'] - INCH) / COUNT
        assert abs(error) <= 1.0, f'slide {error:+.2f} counts from the target'
        assert len(clock) > 10
        (w0, s0), (w1, s1) = clock[0], clock[-1]
        print(f'sim time {s1 - s0:.1f} s in {w1 - w0:.1f} s of wall time')   # (benchmark)


def _start(args, env, timeout=60):
    return subprocess.run([sys.executable, '-m', 'motion_ctrl.ros.controller_node',
                           '--ros-args', *args], capture_output=True, text=True,
                          timeout=timeout, env=env)


@pytest.mark.parametrize('args, line', [
    (['-p', 'hardware:=ethercat'],
     "ControllerNode: bad parameter (from -p hardware:=ethercat): hardware: unknown value "
     "'ethercat', expected one of topics, sim, canopen"),
    (['-p', 'hardware:=sim', '-p', 'x.slide_mass:=-1.0'],
     'ControllerNode: bad parameter (from -p x.slide_mass:=-1.0): Parameter x.slide_mass out of '
     'range Min: 0.0, Max: inf, value: -1.0: x.slide_mass'),
    (['-p', 'hardware:=sim', '-p', 'x.slide_stiction:=1.0'],
     'ControllerNode: hardware: sim: x.slide_stiction must be >= slide_coulomb'),
    (['-p', 'x.slide_mass:=10.0'],
     "ControllerNode: bad parameter (from -p x.slide_mass:=10.0): x.slide_mass: no such "
     "parameter on controller (axes ['x'])"),
    (['--params-file', str(params_dir() / 'plant.yaml')],
     f'ControllerNode: bad parameter (from {params_dir() / "plant.yaml"}): hardware: topics: a '
     'plant: section in the params files configures the controller only with hardware: sim'),
], ids=['unknown hardware', 'bad plant register', 'plant rule', 'plant register on topics',
        'plant file on topics'])
def test_bad_hardware_input_is_refused_at_start_with_one_line(node_env, args, line):
    r = _start(args, node_env | {'MOTION_CTRL_SERVO_DOMAIN': 'off'})
    assert r.returncode == 2, r.stderr[-2000:]
    assert r.stderr.strip().splitlines() == [line], r.stderr[-2000:]
