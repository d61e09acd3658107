"""The servo loop's hardware interface (core.hardware) and the `sim` backend (sim.hardware):
the cycle's order, the lifecycle, faults turned into the status the axis has, the amplifiers
following the loops, and the simulated amplifier's watchdog and dynamic brake."""
import math

import pytest

from msg_defs.status import Status
from motion_ctrl.core.axis import Axis
from motion_ctrl.core.hardware import (ACTIVE, DRIVE, INACTIVE, LINK, UNCONFIGURED,
                                       HardwareError, HardwareInterface)
from motion_ctrl.core.registers import INCH, LOAD_COUNTS_PER_M
from motion_ctrl.core.servo_loop import ServoLoop
from motion_ctrl.sim.hardware import SimHardware
from motion_ctrl.sim.plant import SlidePlant

T = 1e-3


class Recording(HardwareInterface):
    """Encoders that read 0; every call noted, and the amplifier enables as a drive with an
    enable sequence would see them (on a change of the loop's state)."""

    kind = 'recording'

    def __init__(self, axes):
        super().__init__(axes)
        self.calls = []
        self.faults = {}                    # axis -> (kind, reason), set on every read
        self.amplifier = {a: False for a in self.axes}

    def on_configure(self):
        self.calls.append('configure')

    def on_activate(self):
        self.calls.append('activate')

    def on_deactivate(self):
        self.calls.append('deactivate')

    def read(self, now):
        self.calls.append(('read', now))
        for a, io in self.io.items():
            io.fault_kind, io.fault_reason = self.faults.get(a, ('', ''))
            io.sample(0, 0, now)

    def write(self, now):
        for a, io in self.io.items():
            if io.commanded and io.enabled != self.amplifier[a]:
                self.amplifier[a] = io.enabled
                self.calls.append(('enable', a, io.enabled))
        self.calls.append(('write', now, [a for a, io in self.io.items() if io.commanded]))

    def reset(self, axis):
        self.calls.append(('reset', axis))


def loop_on(hardware, axes=('x',)):
    ax = {a: Axis(a) for a in axes}
    return ServoLoop(ax, {a: x.r for a, x in ax.items()}, T, 0.02, sim_time=True,
                     hardware=hardware)


def test_a_cycle_reads_ticks_and_writes_in_that_order():
    hw = Recording(['x'])
    hw.activate()
    loop = loop_on(hw)
    loop.cycle(0.0)
    loop.cycle(T)
    assert hw.calls == ['configure', 'activate',
                        ('read', 0.0), ('enable', 'x', True), ('write', 0.0, ['x']),
                        ('read', T), ('write', T, ['x'])]      # the amplifier told once


def test_the_amplifier_follows_the_loop_abort_and_enable():
    hw = Recording(['x'])
    loop = loop_on(hw)
    loop.cycle(0.0)
    assert loop.axes['x'].abort()[0]
    loop.cycle(T)
    assert ('enable', 'x', False) in hw.calls
    assert loop.axes['x'].enable(True)[0]
    loop.cycle(2 * T)
    assert hw.calls[-2:] == [('enable', 'x', True), ('write', 2 * T, ['x'])]


def test_the_lifecycle_runs_in_order_and_deactivate_is_safe_twice():
    hw = Recording(['x'])
    assert hw.state == UNCONFIGURED
    hw.configure()
    assert hw.state == INACTIVE
    with pytest.raises(HardwareError):
        hw.configure()
    hw.activate()
    assert hw.state == ACTIVE
    hw.deactivate()
    hw.deactivate()
    assert hw.calls == ['configure', 'activate', 'deactivate']
    assert hw.state == INACTIVE


def test_a_link_fault_is_a_feedback_fault_at_once_logged_once():
    hw = Recording(['x'])
    loop = loop_on(hw)
    loop.cycle(0.0)
    hw.faults['x'] = (LINK, 'heartbeat of node 1 lost')
    lines = loop.cycle(T).log + loop.cycle(2 * T).log
    ax = loop.axes['x']
    assert ax.status & Status.FEEDBACK_FAULT and not ax.enabled
    assert lines == [('error', 'x: FEEDBACK_FAULT: heartbeat of node 1 lost; loop opened, '
                               'call x/reset')]
    assert ('enable', 'x', False) in hw.calls


def test_a_drive_fault_aborts_and_holds_until_reset_which_resets_the_drive():
    hw = Recording(['x'])
    loop = loop_on(hw)
    loop.cycle(0.0)
    ax = loop.axes['x']
    assert ax.move_to(0.01)[0]
    loop.cycle(T)
    hw.faults['x'] = (DRIVE, 'overcurrent (603Fh = 0x2310)')
    log = loop.cycle(2 * T).log
    assert log == [('error', 'x: amplifier fault: overcurrent (603Fh = 0x2310); loop opened '
                             '(ABORTED), call x/reset')]
    assert ax.status & Status.ABORTED and ax.status & Status.MOTION_DONE
    assert not ax.enabled and ax.output == 0.0
    ok, reason = ax.enable(True)
    assert not ok and reason == ('x: amplifier fault (overcurrent (603Fh = 0x2310)), call '
                                 'x/reset first')
    assert ax.move_to(0.0)[1] == 'x: amplifier fault (overcurrent (603Fh = 0x2310)), call x/reset'
    # The cause persists: reset clears it, the next read brings it back.
    loop.reset('x')
    assert ('reset', 'x') in hw.calls
    loop.cycle(3 * T)
    assert ax.drive_fault_reason
    # Cleared at the drive: reset and enable close the loop again.
    del hw.faults['x']
    loop.reset('x')
    loop.cycle(4 * T)
    assert ax.enable(True)[0]
    loop.cycle(5 * T)
    assert ax.enabled and not ax.status & Status.ABORTED


# -- the sim backend -----------------------------------------------------------------------------
def sim(axes=('x',), **plant):
    hw = SimHardware(axes, T, {a: plant for a in axes})
    hw.activate()
    return hw


def test_a_bad_plant_register_is_refused_at_configure_naming_the_axis():
    hw = SimHardware(['x', 'y'], T, {'y': {'slide_mass': -1.0}})
    with pytest.raises(HardwareError, match=r'^sim: y.slide_mass: -1 kg is out of range'):
        hw.configure()
    assert hw.state == UNCONFIGURED


def test_sim_steps_one_period_per_write_like_the_plant_on_a_held_command():
    hw = sim()
    ref = SlidePlant()
    io = hw.io['x']
    io.output, io.commanded = 2.0, True
    stamps = []
    for k in range(50):
        hw.read(k * T)
        stamps.append(io.stamp)
        assert (io.motor, io.load) == ref.encoder_counts()
        hw.write(k * T)
        ref.command(2.0)
        ref.advance(T, T)
    assert hw.plants['x'].x_m == ref.x_m and hw.plants['x'].x_l == ref.x_l
    assert stamps == [k * T for k in range(50)]


def _held_up(late: float):
    """The sim backend and a reference slide, both commanded 3 V for a period; then the
    loop's next tick `late` s late."""
    hw = sim()
    ref = SlidePlant()
    hw.read(0.0)
    hw.io['x'].output, hw.io['x'].commanded = 3.0, True
    hw.write(0.0)
    ref.command(3.0)
    ref.advance(T, T)
    hw.read(T + late)
    return hw, ref


def test_a_late_tick_integrates_its_lateness_on_the_held_command():
    """Held up 4 ms: the slide ran on the held 3 V for those four periods."""
    hw, ref = _held_up(0.004)
    for _ in range(4):
        ref.advance(T)
    assert hw.plants['x'].x_m == ref.x_m and not hw.tripped()[0]
    assert hw.time == pytest.approx(T + 0.004) and hw.io['x'].stamp == hw.time


def test_a_loop_held_up_longer_than_the_watchdog_finds_the_amplifier_braked():
    """Held up 25 ms: no command came in those periods, so the amplifier's watchdog tripped
    after command_timeout (10 ms) and the dynamic brake stopped the motor, as a drive does when
    its controller stops sending; the 3 V did not run on for the whole 25 ms (the sprint the
    loop then found: a motor at 0.2 m/s, OVERSPEED, with the lateness counted as two periods)."""
    hw, ref = _held_up(0.025)
    for _ in range(25):
        ref.advance(T)
    assert ref.tripped and hw.tripped() == [True]
    assert hw.plants['x'].x_m == ref.x_m and hw.plants['x'].v_m == ref.v_m
    assert abs(ref.v_m) < 0.01


def test_an_axis_left_without_commands_trips_its_watchdog_and_brakes():
    """As the plant node's amplifier: an axis the loop does not write (the tick leaves out an
    axis whose encoder stream is not established) gets 0 V and the dynamic brake after
    command_timeout (10 ms); a commanded one runs."""
    hw = sim(('x', 'y'))
    y = hw.plants['y']
    y.command(2.0)
    y.v_m = y.v_l = 0.05                          # moving when its commands stop
    hw.io['x'].output, hw.io['x'].commanded = 0.5, True
    for k in range(100):
        hw.write(k * T)
        if k == 8:
            assert hw.tripped() == [False, False] and hw.applied() == [0.5, 2.0]
    assert hw.tripped() == [False, True]
    assert hw.applied() == [0.5, 0.0]
    assert y.v_m == 0.0                           # braked to rest


def test_deactivate_leaves_every_amplifier_at_zero_with_the_brake_closed():
    hw = sim()
    loop = loop_on(hw)
    loop.cycle(0.0)
    assert loop.axes['x'].jog(0.05)[0]
    for k in range(1, 200):
        loop.cycle(k * T)
    p = hw.plants['x']
    assert p.v_m > 0.04
    hw.deactivate()
    travel0 = p.x_l
    for _ in range(100):                          # the machine runs on, no controller
        p.advance(T, T)
    assert p.tripped and p.volts == 0.0 and p.v_m == 0.0
    assert (p.x_l - travel0) < 0.002              # braked within 2 mm from 50 mm/s


def test_the_harness_runs_the_headline_through_the_sim_backend():
    from motion_ctrl.sim.harness import Harness
    h = Harness()
    assert isinstance(h.loop.hardware, SimHardware) and h.plant is h.hardware.plants['x']
    assert h.move(2 * INCH) is not None and h.move(INCH) is not None
    assert abs(h.load_error_counts(INCH)) <= 1.0
    assert math.isclose(h.plant.x_l * LOAD_COUNTS_PER_M, INCH * LOAD_COUNTS_PER_M, abs_tol=1.0)
