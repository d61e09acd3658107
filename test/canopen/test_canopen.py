"""`hardware: canopen` without ROS: the CiA 402 state machine, the bus-load arithmetic, and the
master backend (motion_ctrl.canopen.master) against emulated drives (motion_ctrl.canopen.
virtual_drive) on python-can's `virtual` bus in this process, the servo loop run in lockstep
(each cycle waits for the TPDOs of the last SYNC; the drives step one period per SYNC)."""
import itertools
import time

import pytest

from msg_defs.status import Status
from motion_ctrl.canopen import busload
from motion_ctrl.canopen import cia402 as c
from motion_ctrl.canopen.master import AxisNodes, CanopenHardware
from motion_ctrl.canopen.objects import cycle_frames
from motion_ctrl.canopen.virtual_drive import DriveConfig, VirtualDrives
from motion_ctrl.core.axis import Axis
from motion_ctrl.core.hardware import HardwareError
from motion_ctrl.core.registers import LOAD_COUNTS_PER_M, MOTOR_COUNTS_PER_M
from motion_ctrl.core.servo_loop import ServoLoop

_channels = itertools.count()


class Bench:
    """Emulated drives and a servo loop on `hardware: canopen`, one virtual bus of their own."""

    def __init__(self, drives: dict[str, DriveConfig], rate: float = 1000.0,
                 realtime: bool = False, start_drives: bool = True, **nodes):
        self.channel = f'test_canopen_{next(_channels)}'
        self.rate = rate
        self.T = 1.0 / rate
        self.drives = VirtualDrives(drives, 'virtual', self.channel, realtime=realtime)
        if start_drives:
            self.drives.start()
        self.log: list[tuple[str, str]] = []
        self.hw = CanopenHardware(
            {a: nodes.get(a, AxisNodes(d.node_id, d.load_encoder_node_id))
             for a, d in drives.items()}, self.T, 'virtual', self.channel,
            log=lambda level, text: self.log.append((level, text)), boot_timeout=0.5)
        self.axes = {a: Axis(a) for a in drives}
        self.loop = ServoLoop(self.axes, {a: x.r for a, x in self.axes.items()}, self.T, 0.02,
                              sim_time=True, hardware=self.hw)
        self.hw.watch(self.axes)
        self.t = 0.0

    def run(self, seconds: float, wait: bool = True) -> list[tuple[str, str]]:
        lines = []
        for _ in range(round(seconds * self.rate)):
            tick = self.loop.cycle(self.t)
            if tick is not None:
                lines += tick.log
            if wait:           # (lockstep: the drives answer every SYNC; a loaded machine
                # can hold their thread up for a while, never this long)
                assert self.hw.wait_for_samples(10.0), f'no answer to SYNC {self.hw.sync_count}'
            self.t = round(self.t + self.T, 9)
        return lines

    def slide_error_counts(self, axis: str, target: float) -> float:
        return (self.drives.axes[axis].plant.x_l - target) * LOAD_COUNTS_PER_M

    def close(self):
        self.hw.deactivate()
        if self.hw.network is not None:
            self.hw.network.disconnect()
        self.drives.stop()


@pytest.fixture
def benches():
    made = []

    def make(*args, **kw):
        made.append(Bench(*args, **kw))
        return made[-1]
    yield make
    for b in made:
        try:
            b.close()
        except Exception:
            pass


# -- the bus's arithmetic ------------------------------------------------------------------------
def test_frame_lengths_and_the_rates_a_megabit_bus_carries():
    assert busload.frame_bits(0) == 55 and busload.frame_bits(4) == 95
    assert busload.frame_bits(8) == 135
    one = cycle_frames([0])             # RPDO1 4 + TPDO1 8 + TPDO2 4 bytes
    assert one == [4, 8, 4] and busload.cycle_bits(one) == 380
    assert cycle_frames([5]) == [4, 8, 4]       # the load on a CiA 406 node: the same bytes
    assert round(busload.max_rate(1e6, one)) == 2105        # 475 us: 80 % of 1 Mbit/s
    two = cycle_frames([0, 0])
    assert busload.cycle_bits(two) == 705 and round(busload.max_rate(1e6, two)) == 1134
    assert busload.refusal(2000.0, 1e6, one) is None
    assert busload.refusal(1000.0, 500e3, one) is None     # 76 %
    reason = busload.refusal(1000.0, 250e3, one)
    assert reason.startswith('1000 Hz needs 152 % of a 250 kbit/s bus (380 bits a cycle')
    assert reason.endswith('526 Hz is the most')


# -- the CiA 402 state machine ------------------------------------------------------------------
def test_the_master_walks_a_drive_to_operation_enabled_and_back():
    sm = c.DriveStateMachine()
    seen = [sm.state]
    for _ in range(4):
        sm.controlword(c.master_controlword(sm.state, True))
        seen.append(sm.state)
    assert seen == [c.SWITCH_ON_DISABLED, c.READY, c.SWITCHED_ON, c.OPERATION_ENABLED,
                    c.OPERATION_ENABLED]
    assert c.state_of(sm.statusword) == c.OPERATION_ENABLED and sm.enabled
    sm.controlword(c.master_controlword(sm.state, False))
    assert sm.state == c.SWITCH_ON_DISABLED and c.state_of(sm.statusword) == sm.state


def test_a_fault_holds_until_the_rising_edge_of_fault_reset():
    sm = c.DriveStateMachine()
    for cw in (c.CW_SHUTDOWN, c.CW_ENABLE_OPERATION):
        sm.controlword(cw)
    sm.fault(0x2310)
    assert sm.state == c.FAULT_REACTION and c.is_fault(sm.statusword)
    sm.fault_reaction_done()
    assert sm.state == c.FAULT and sm.error_code == 0x2310
    sm.controlword(c.CW_ENABLE_OPERATION)
    assert sm.state == c.FAULT                      # no command leaves FAULT but a reset
    sm.controlword(c.CW_FAULT_RESET)
    assert sm.state == c.SWITCH_ON_DISABLED and sm.error_code == 0
    sm.fault(0x4310)
    sm.fault_reaction_done()
    sm.controlword(c.CW_FAULT_RESET)                # bit 7 held high: no new edge
    assert sm.state == c.FAULT
    sm.controlword(0)
    sm.controlword(c.CW_FAULT_RESET)
    assert sm.state == c.SWITCH_ON_DISABLED


def test_quick_stop_options():
    sm = c.DriveStateMachine(quick_stop_option=2)
    for cw in (c.CW_SHUTDOWN, c.CW_ENABLE_OPERATION, c.CW_QUICK_STOP):
        sm.controlword(cw)
    assert sm.state == c.QUICK_STOP_ACTIVE and c.state_of(sm.statusword) == c.QUICK_STOP_ACTIVE
    sm.quick_stop_done()
    assert sm.state == c.SWITCH_ON_DISABLED
    sm = c.DriveStateMachine(quick_stop_option=6)
    for cw in (c.CW_SHUTDOWN, c.CW_ENABLE_OPERATION, c.CW_QUICK_STOP):
        sm.controlword(cw)
    sm.quick_stop_done()
    assert sm.state == c.QUICK_STOP_ACTIVE          # 5-8 stay until enable operation
    sm.controlword(c.CW_ENABLE_OPERATION)
    assert sm.state == c.OPERATION_ENABLED


# -- the master against emulated drives ---------------------------------------------------------
@pytest.mark.core_slow
def test_headline_through_canopen_at_the_highest_rate_with_a_cia406_load_encoder(benches):
    """+2 in, back to +1 in (the reversal), dual feedback, the load encoder on its own CiA 406
    node, at the rate 1 Mbit/s carries: the true slide within 1 count."""
    rate = busload.max_rate(1e6, cycle_frames([5]))
    b = benches({'x': DriveConfig(1, load_encoder_node_id=5)}, rate=rate)
    b.hw.activate()
    assert round(b.hw.bus_load(), 3) == 0.8
    b.run(0.02)
    assert b.hw.drive_states()['x'][0] == c.OPERATION_ENABLED and b.axes['x'].enabled
    for target in (0.0508, 0.0254):
        assert b.axes['x'].move_to(target)[0]
        b.run(1.3)
        assert b.axes['x'].status & Status.MOTION_DONE
        assert abs(b.slide_error_counts('x', target)) <= 1.0, target
    assert b.hw.missed == 0


def test_the_drive_follows_the_loop_and_the_stop_disables_it(benches):
    b = benches({'x': DriveConfig(3)})
    b.hw.activate()
    b.run(0.01)
    drive = b.drives.axes['x']
    assert drive.sm.state == c.OPERATION_ENABLED
    assert b.axes['x'].abort()[0]
    b.run(0.005)
    assert drive.sm.state == c.SWITCH_ON_DISABLED          # ABORT: disable voltage
    assert b.axes['x'].enable(True)[0]
    b.run(0.005)
    assert drive.sm.state == c.OPERATION_ENABLED
    assert b.axes['x'].move_to(0.01)[0]
    b.run(0.1)
    b.hw.deactivate()                                       # the controller's stop
    time.sleep(0.05)
    assert drive.sm.state == c.SWITCH_ON_DISABLED and drive.target == 0
    assert drive.drive.node.nmt.state == 'PRE-OPERATIONAL'


def test_a_drive_fault_aborts_the_axis_with_its_error_code_and_reset_recovers(benches):
    b = benches({'x': DriveConfig(1)})
    b.hw.activate()
    b.run(0.02)
    ax = b.axes['x']
    assert ax.move_to(0.0254)[0]
    b.run(0.1)
    b.drives.inject_fault('x', 0x2310)                      # continuous over-current
    lines = b.run(0.01)
    assert not ax.enabled and ax.status & Status.ABORTED
    assert lines == [('error', 'x: amplifier fault: node 1: drive FAULT, error code 603Fh = '
                               '0x2310 (Current); loop opened (ABORTED), call x/reset')]
    assert ('error', 'x: node 1: EMCY 0x2310 (Current), error register 0x03') in b.log
    ok, reason = ax.enable(True)
    assert not ok and '0x2310' in reason
    b.loop.reset('x')
    b.run(0.01)
    assert b.drives.axes['x'].sm.state == c.SWITCH_ON_DISABLED
    assert ax.enable(True)[0]
    b.run(0.01)
    assert b.drives.axes['x'].sm.state == c.OPERATION_ENABLED and ax.enabled
    where = b.drives.axes['x'].plant.x_l
    assert ax.move_to(0.0254)[0]
    b.run(1.2)
    assert ax.status & Status.MOTION_DONE and b.drives.axes['x'].plant.x_l > where
    assert abs(b.slide_error_counts('x', 0.0254)) <= 1.0


def test_an_estop_is_the_drives_quick_stop_where_the_axis_has_one(benches):
    """estop_quick_stop: the ESTOP makes the drive quick-stop (controlword 02h): it brakes on
    its own at 6085h and disables (605Ah = 2); the next move enables it again."""
    decel = round(10.0 * MOTOR_COUNTS_PER_M)              # estop_deceleration, in 6064h counts
    b = benches({'x': DriveConfig(1)}, x=AxisNodes(1, quick_stop_deceleration=decel))
    b.hw.activate()
    b.run(0.02)
    ax, drive = b.axes['x'], b.drives.axes['x']
    assert drive.quick_stop_decel == decel and drive.sm.quick_stop_option == 2
    assert ax.move_to(0.2)[0]
    while drive.plant.v_l < 0.099:
        b.run(b.T)
    assert ax.stop('estop')[0]
    states = []
    for _ in range(150):
        b.run(b.T)
        states.append(drive.sm.state)
    assert c.QUICK_STOP_ACTIVE in states and states[-1] == c.SWITCH_ON_DISABLED
    assert abs(drive.plant.v_l) < 1e-4 and ax.status & Status.ESTOPPED and ax.enabled
    assert ax.move_to(0.0254)[0]
    b.run(2.5)
    assert drive.sm.state == c.OPERATION_ENABLED and ax.status & Status.MOTION_DONE
    assert abs(b.slide_error_counts('x', 0.0254)) <= 1.0


def test_a_dead_controller_is_stopped_by_the_drive_watchdog(benches):
    """The master stops mid-move at max velocity (as SIGKILLed: no SYNC, no RPDO): the drive's
    own clock runs the slide on, its watchdog trips after command_timeout, torque 0 and the
    dynamic brake. (Lockstep up to the kill; the drives' real-time rules from there on.)"""
    b = benches({'x': DriveConfig(1)})
    b.hw.activate()
    b.run(0.02)
    ax = b.axes['x']
    assert ax.move_to(0.2)[0]
    drive = b.drives.axes['x']
    while drive.plant.v_l < 0.099:
        b.run(b.T)
    at_kill = drive.plant.x_l
    b.drives.realtime = True                        # the master is gone
    time.sleep(0.3)
    assert drive.sm.state == c.FAULT and drive.sm.error_code == 0x8250
    assert abs(drive.plant.v_l) < 1e-6
    travel = drive.plant.x_l - at_kill
    print(f'{travel * 1e3:.2f} mm after the master stopped')
    assert 0.0 < travel <= 0.005, travel


def test_a_missing_drive_is_a_missing_sample_then_a_feedback_fault(benches):
    b = benches({'x': DriveConfig(1)})
    b.hw.activate()
    b.run(0.02)
    b.drives.network.unsubscribe(0x80)              # the drive stops answering SYNCs
    lines = b.run(0.03, wait=False)
    ax = b.axes['x']
    assert ax.status & Status.FEEDBACK_FAULT and not ax.enabled
    assert lines[0][1].startswith('x: FEEDBACK_FAULT: no new encoder sample for 21 ms'), lines


def test_a_drive_that_rebooted_is_a_link_fault(benches):
    """Its heartbeat says PRE-OPERATIONAL (the boot-up of a drive that reset): FEEDBACK_FAULT
    naming the node, while its last TPDOs would still look fine."""
    b = benches({'x': DriveConfig(1)})
    b.hw.activate()
    b.run(0.02)
    time.sleep(0.25)                                # its heartbeat said OPERATIONAL meanwhile
    b.run(0.002)
    node = b.drives.axes['x'].drive.node
    node.nmt.send_command(0x81)                     # reset: boot-up, then PRE-OPERATIONAL
    node.nmt.send_command(0x80)
    time.sleep(0.25)
    lines = b.run(0.002, wait=False)
    assert b.axes['x'].status & Status.FEEDBACK_FAULT
    assert lines[0][1] == ('x: FEEDBACK_FAULT: node 1 left OPERATIONAL (heartbeat: NMT state '
                           'PRE-OPERATIONAL); loop opened, call x/reset'), lines


def test_a_malformed_frame_is_a_link_fault_not_the_end_of_the_loop(benches):
    b = benches({'x': DriveConfig(1)})
    b.hw.activate()
    b.run(0.02)
    b.drives.network.send_message(0x181, b'\x01\x02\x03')   # a 3-byte TPDO1
    time.sleep(0.05)
    lines = b.run(0.002, wait=False)
    ax = b.axes['x']
    assert ax.status & Status.FEEDBACK_FAULT and not ax.enabled
    assert lines[0][1].startswith("x: FEEDBACK_FAULT: canopen: reading the bus failed: "
                                  "error('unpack requires a buffer of 8 bytes')"), lines
    assert sum('reading the bus failed' in text for _, text in b.log) == 1


@pytest.mark.parametrize('drive, nodes, line', [
    (None, None, 'canopen: node 1 (x drive) does not answer: no SDO response to 1000h '
                 '(device type) in 0.3 s, nor in the 0.5 s a node may take to boot'),
    (DriveConfig(1, device_type=0x00020196), None,
     'canopen: node 1 (x drive) is no CiA 402 drive: 1000h (device type) = 0x00020196, '
     'profile 406'),
    (DriveConfig(1, refuse_mapping=0x6071), None,
     'canopen: node 1 (x drive) refused the mapping of 6071h into RPDO1 (1600h:02 = '
     '0x60710010): Code 0x06040041, Object cannot be mapped to the PDO'),
    (DriveConfig(1, supported_modes=1 << 7), None,
     'canopen: node 1 (x drive) has no cyclic synchronous torque mode: 6502h (supported drive '
     'modes) = 0x00000080 (cyclic synchronous position)'),
    (DriveConfig(1, load_encoder_node_id=5), {'x': AxisNodes(1, 6)},
     'canopen: node 6 (x load encoder) does not answer: no SDO response to 1000h (device '
     'type) in 0.3 s, nor in the 0.5 s a node may take to boot'),
])
def test_start_up_refuses_what_it_cannot_drive_in_one_line(benches, drive, nodes, line):
    b = benches({'x': drive or DriveConfig(1)}, start_drives=drive is not None,
                **(nodes or {}))
    with pytest.raises(HardwareError) as e:
        b.hw.configure()
    assert str(e.value) == line
    assert b.hw.network is None


def test_a_rate_the_bus_cannot_carry_is_refused_with_the_figure(benches):
    b = benches({'x': DriveConfig(1), 'y': DriveConfig(2)}, rate=2000.0, start_drives=False)
    with pytest.raises(HardwareError) as e:
        b.hw.configure()
    assert str(e.value).startswith('canopen: servo_rate 2000 Hz needs 141 % of a 1000 kbit/s '
                                   'bus (705 bits a cycle')
    assert str(e.value).endswith('1134 Hz is the most')
