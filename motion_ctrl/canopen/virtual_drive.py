"""An emulated CiA 402 servo drive: the backlash slide's physics (sim.plant.SlidePlant) behind
the object dictionary of the shipped EDS, on a CAN bus through `canopen` and `python-can`, and,
for an axis whose load encoder is a node of its own, a CiA 406 encoder node on the slide.

What a drive on the bus does, emulated:

* NMT slave (boot-up message, PRE-OPERATIONAL / OPERATIONAL / STOPPED) and heartbeat producer
  (1017h), SDO server (canopen.LocalNode);
* on each SYNC (1005h), in this order: the RPDO received since the previous SYNC is applied
  (synchronous RPDO: controlword 6040h through the state machine, target torque 6071h), every
  synchronous TPDO is sampled and sent (canopen's LocalNode has no TPDOs, canopen#558: built
  here from the mapping the master wrote), and the slide is integrated one communication cycle
  period (1006h) on the torque the drive applies;
* cyclic synchronous torque (6060h = 10): the torque [‰ of the rated torque 6076h] drives the
  plant's amplifier: volts = torque / 1000 · amplifier_limit, the rated torque being the
  plant's torque at full input (torque_constant · amplifier_gain · amplifier_limit);
* the communication watchdog: while OPERATION ENABLED, a SYNC without an RPDO before it, and a
  cycle with no SYNC at all, count towards the plant's `command_timeout` (drive time); past it
  the drive faults with 8250h (RPDO timeout, CiA 301): EMCY, statusword fault bit, 603Fh, and
  the fault reaction, torque 0 and the dynamic brake (the plant's amplifier watchdog). The SYNC
  is the slide's clock (the controller counts its time in SYNCs too, so a late SYNC stretches a
  cycle for both); with no SYNC for FREE_RUN (0.1 s; a bus quiet for RECEIVE_SLICE: an emulated
  drive that is merely behind with its frames is not without a master), the drive's own clock
  takes over: it runs the slide in real time from the last SYNC on, the watchdog counting those
  periods too: a dead master stops the SYNCs, not the slide. A master killed at 0.1 m/s:
  command_timeout on the last torque (1 mm), then the brake (1 mm), in the slide's time;
* every SYNC is answered, in order, also when the emulated drive's process was held up and
  answers late (the master counts the frames: the m-th answers the m-th SYNC);
* quick stop (605Ah): the drive's own velocity loop brakes the motor at 6085h, then (options
  1-4) disables; fault reset (controlword bit 7) clears a fault (EMCY error reset);
* fault injection (`inject_fault`), and start-up refusals for the master's checks: another
  device type (1000h), an object it will not map, a drive without CST (6502h).
"""
from __future__ import annotations

import ctypes
import math
import multiprocessing
import os
import queue
import signal
import struct
import threading
import time
import traceback
from dataclasses import dataclass, field
from typing import Any, Callable

import can
import canopen
from canopen.objectdictionary import ODVariable
from canopen.sdo import SdoAbortedError

from motion_ctrl.canopen import cia402 as c
from motion_ctrl.canopen.objects import (DRIVE_EDS, ENCODER_EDS, PDO_NOT_VALID, SYNC_COB_ID)
from motion_ctrl.sim.plant import TWO_PI, SlidePlant

DEVICE_TYPE_DRIVE = 0x00020192      # CiA 402, servo drive
CST_ONLY = 1 << c.SUPPORTED_MODE_BIT[c.CST]
DEFAULT_PERIOD = 1e-3               # 1006h = 0: the drive assumes 1 ms
# s without a SYNC after which the master is taken for dead and the drive's own clock runs the
# slide, from the last SYNC on (so the watchdog trips command_timeout after the last RPDO in the
# slide's time, whenever this is decided): longer than the stalls of a master on a loaded
# machine (doc/performance.md: multi-ms, now and then tens of ms), which freeze the emulated
# slide instead (the SYNC is its clock)
FREE_RUN = 0.1
RECEIVE_SLICE = 0.002               # s: a quiet bus this long lets the drives' clock look
RECEIVE_PRIORITY = 40               # SCHED_FIFO of the receive thread in real time (0: none)
HEARTBEAT_MS = 100                  # producer heartbeat at boot-up (the master may change it)
RPDO_TIMEOUT = 0x8250
# SDO abort codes (CiA 301)
ABORT_NOT_MAPPABLE = 0x06040041
ABORT_PDO_LENGTH = 0x06040042
ABORT_VALUE_RANGE = 0x06090030
ABORT_DEVICE_STATE = 0x08000022
ABORT_NO_OBJECT = 0x06020000
# the quick stop's velocity loop: bandwidth [Hz] and the speed it calls standstill [m/s]
QUICK_STOP_BANDWIDTH = 50.0
STANDSTILL = 1e-4


@dataclass
class DriveConfig:
    """One axis's emulated hardware: the drive's node id, the load encoder (0: the drive's
    60E4h, else a CiA 406 node with this id), the plant registers that differ from the table's
    defaults, and what the drive refuses (for the master's start-up checks)."""
    node_id: int
    load_encoder_node_id: int = 0
    plant: dict = field(default_factory=dict)
    device_type: int = DEVICE_TYPE_DRIVE
    supported_modes: int = CST_ONLY
    refuse_mapping: int = 0          # an object index the drive will not map (0: none)


def _get(node: Any, index: int, sub: int = 0) -> int:
    """An integer object of a node's own dictionary (a local SDO upload)."""
    obj = node.sdo[index]
    return int((obj if hasattr(obj, 'raw') else obj[sub]).raw)


def _put(node: Any, index: int, value: int) -> None:
    node.sdo[index].raw = value


def _struct_code(var: ODVariable) -> str:
    return ODVariable.STRUCT_TYPES[var.data_type or 0].format.lstrip('<')


def _error_register(code: int) -> int:
    """1001h for an error code: bit 0 generic, 1 current, 2 voltage, 3 temperature,
    4 communication."""
    group = {0x2: 0x02, 0x3: 0x04, 0x4: 0x08, 0x8: 0x10}.get(code >> 12, 0)
    return 0x01 | group


class _Pdo:
    """A PDO as the mapping in the node's object dictionary says: COB-ID and its objects."""

    def __init__(self, node: canopen.LocalNode, comm: int, mapping: int) -> None:
        cob = _get(node, comm, 1)
        self.enabled = not cob & PDO_NOT_VALID
        self.cob_id = cob & 0x7FF
        self.trans_type = _get(node, comm, 2)
        self.entries: list[tuple[int, int]] = []
        codes = ''
        for k in range(1, _get(node, mapping, 0) + 1):
            value = _get(node, mapping, k)
            index, sub = value >> 16, (value >> 8) & 0xFF
            self.entries.append((index, sub))
            codes += _struct_code(_object(node, index, sub))
        self.codec = struct.Struct('<' + codes)


def _object(node: canopen.LocalNode, index: int, sub: int) -> ODVariable:
    obj = node.object_dictionary[index]
    return obj if isinstance(obj, ODVariable) else obj[sub]


class _Node:
    """A LocalNode with the mapping rules of a device and its PDOs built at NMT start."""

    def __init__(self, node_id: int, eds: str, refuse_mapping: int = 0) -> None:
        self.node = canopen.LocalNode(node_id, eds)
        self.refuse_mapping = refuse_mapping
        self.node.add_write_callback(self._check_write)
        self.rpdos: list[_Pdo] = []
        self.tpdos: list[_Pdo] = []
        self.operational = False
        self._syncs = 0

    def _check_write(self, index: int, subindex: int, od: ODVariable, data: bytes) -> None:
        rx = c.RPDO_MAP <= index < c.RPDO_MAP + 0x200
        tx = c.TPDO_MAP <= index < c.TPDO_MAP + 0x200
        if not (rx or tx):
            return
        if self.operational:
            raise SdoAbortedError(ABORT_DEVICE_STATE)
        value, = struct.unpack('<I' if subindex else '<B', data)
        if subindex == 0:           # the number of entries: their total must fit 8 bytes
            bits = sum(_get(self.node, index, k) & 0xFF for k in range(1, value + 1))
            if bits > 64:
                raise SdoAbortedError(ABORT_PDO_LENGTH)
            return
        if value == 0:
            return
        obj_index, obj_sub, bits = value >> 16, (value >> 8) & 0xFF, value & 0xFF
        try:
            obj = _object(self.node, obj_index, obj_sub)
        except KeyError:
            raise SdoAbortedError(ABORT_NO_OBJECT) from None
        if (obj_index == self.refuse_mapping or not obj.pdo_mappable or bits != len(obj)
                or (rx and not obj.writable) or (tx and not obj.readable)):
            raise SdoAbortedError(ABORT_NOT_MAPPABLE)

    def nmt_changed(self) -> None:
        """Build the PDOs when the node enters OPERATIONAL (the mapping is fixed there)."""
        operational = self.node.nmt.state == 'OPERATIONAL'
        if operational and not self.operational:
            od = self.node.object_dictionary
            self.rpdos = [_Pdo(self.node, c.RPDO_COMM + i, c.RPDO_MAP + i) for i in range(512)
                          if c.RPDO_COMM + i in od]
            self.tpdos = [_Pdo(self.node, c.TPDO_COMM + i, c.TPDO_MAP + i) for i in range(512)
                          if c.TPDO_COMM + i in od]
            self.rpdos = [p for p in self.rpdos if p.enabled and p.entries]
            self.tpdos = [p for p in self.tpdos if p.enabled and p.entries]
            self._syncs = 0
        self.operational = operational

    def send_tpdos(self, value: Callable[[int, int], int]) -> None:
        """The synchronous TPDOs due at this SYNC, each object sampled by `value`."""
        self._syncs += 1
        network = self.node.network
        for p in self.tpdos:
            if 1 <= p.trans_type <= 240 and self._syncs % p.trans_type == 0:
                network.send_message(p.cob_id, p.codec.pack(*(value(i, s) for i, s in
                                                               p.entries)))

    def period(self) -> float:
        us = _get(self.node, c.CYCLE_PERIOD)
        return us * 1e-6 if us else DEFAULT_PERIOD


class VirtualAxis:
    """One emulated drive (and encoder node) on one slide."""

    def __init__(self, name: str, config: DriveConfig, substep_rate: float = 20000.0) -> None:
        self.name = name
        self.config = config
        self.plant = SlidePlant(substep_rate=substep_rate, **config.plant)
        self.sm = c.DriveStateMachine()
        self.drive = _Node(config.node_id, DRIVE_EDS, config.refuse_mapping)
        self.encoder = (_Node(config.load_encoder_node_id, ENCODER_EDS)
                        if config.load_encoder_node_id else None)
        node = self.drive.node
        _put(node, c.DEVICE_TYPE, config.device_type)
        _put(node, c.SUPPORTED_MODES, config.supported_modes)
        node.add_write_callback(self._on_write)
        node.add_read_callback(self._on_read)
        self.mode = _get(node, c.MODES_OF_OPERATION)
        if not config.supported_modes & (1 << c.SUPPORTED_MODE_BIT.get(self.mode, 31)):
            self.mode = 0
        self._rated_torque()
        self.target = 0                 # 6071h applied [‰]
        self._rx: bytes | None = None   # the RPDO received since the last SYNC
        self._values: dict[tuple[int, int], int] = {}
        self._pending_fault = 0
        self._qs_ref = 0.0              # the quick stop's velocity reference [m/s]
        # objects the cycle reads, kept as they are written
        self.period = self.drive.period()
        self.max_torque = _get(node, c.MAX_TORQUE)
        self.quick_stop_decel = _get(node, c.QUICK_STOP_DECELERATION)

    # -- the object dictionary ------------------------------------------------------------------
    def _rated_torque(self) -> None:
        p = self.plant.params
        rated = p['torque_constant'] * p['amplifier_gain'] * p['amplifier_limit']
        _put(self.drive.node, c.RATED_TORQUE, max(1, round(rated * 1000)))

    def _on_write(self, index: int, subindex: int, od: ODVariable, data: bytes) -> None:
        if index == c.MODES_OF_OPERATION:
            mode, = struct.unpack('<b', data)
            if not self.config.supported_modes & (1 << c.SUPPORTED_MODE_BIT.get(mode, 31)):
                raise SdoAbortedError(ABORT_VALUE_RANGE)
            self.mode = mode
        elif index == c.QUICK_STOP_OPTION:
            self.sm.quick_stop_option = struct.unpack('<h', data)[0]
        elif index == c.CYCLE_PERIOD:
            us, = struct.unpack('<I', data)
            self.period = us * 1e-6 if us else DEFAULT_PERIOD
        elif index == c.MAX_TORQUE:
            self.max_torque, = struct.unpack('<H', data)
        elif index == c.QUICK_STOP_DECELERATION:
            self.quick_stop_decel, = struct.unpack('<I', data)
        elif index in (c.CONTROLWORD, c.TARGET_TORQUE):
            self._values[(index, 0)] = int.from_bytes(data, 'little', signed=index != c.CONTROLWORD)

    def _on_read(self, index: int, subindex: int, od: ODVariable):
        if (index, subindex) in self._live:
            return self.value(index, subindex)
        return None

    _live = {(c.STATUSWORD, 0), (c.POSITION_ACTUAL, 0), (c.ERROR_CODE, 0), (c.MODES_DISPLAY, 0),
             (c.ADDITIONAL_POSITION, 1), (c.VELOCITY_ACTUAL, 0), (c.TORQUE_ACTUAL, 0),
             (c.ERROR_REGISTER, 0), (c.ENCODER_POSITION, 0)}

    def value(self, index: int, sub: int) -> int:
        """An object's value now (what a TPDO samples)."""
        p = self.plant
        if index == c.STATUSWORD:
            return self.sm.statusword
        if index == c.POSITION_ACTUAL:
            return p.encoder_counts()[0]
        if index in (c.ADDITIONAL_POSITION, c.ENCODER_POSITION):
            return p.encoder_counts()[1]
        if index == c.ERROR_CODE:
            return self.sm.error_code
        if index == c.MODES_DISPLAY:
            return self.mode
        if index == c.VELOCITY_ACTUAL:
            return round(p.v_m * p.motor_counts_per_m)
        if index == c.TORQUE_ACTUAL:
            return round(p.volts / p.params['amplifier_limit'] * 1000)
        if index == c.ERROR_REGISTER:
            return _error_register(self.sm.error_code) if self.sm.error_code else 0
        return self._values.get((index, sub), 0)

    # -- the cycle ------------------------------------------------------------------------------
    def on_rpdo(self, can_id: int, data: bytearray, timestamp: float) -> None:
        self._rx = bytes(data)

    def sync(self) -> None:
        """A SYNC: apply the RPDO, send the TPDOs (sampled now), integrate one period."""
        commanded = False
        if self.drive.operational:
            rx, self._rx = self._rx, None
            for p in self.drive.rpdos[:1]:
                if rx is not None and len(rx) >= p.codec.size:
                    for key, v in zip(p.entries, p.codec.unpack_from(rx)):
                        self._values[key] = v
                    commanded = True
            if commanded:
                was = self.sm.state
                self.sm.controlword(self._values.get((c.CONTROLWORD, 0), 0))
                if was == c.FAULT and self.sm.state != c.FAULT:
                    self.drive.node.emcy.reset()
                self.target = self._values.get((c.TARGET_TORQUE, 0), 0)
            self.drive.send_tpdos(self.value)
        if self.encoder is not None and self.encoder.operational:
            self.encoder.send_tpdos(self.value)
        self.step(self.period, commanded)

    def step(self, T: float, commanded: bool = False) -> None:
        """One period of the slide on what the drive applies (`commanded`: an RPDO came)."""
        if self._pending_fault:
            self.fault(self._pending_fault)
            self._pending_fault = 0
        p, sm = self.plant, self.sm
        if sm.state == c.OPERATION_ENABLED and self.mode == c.CST:
            if commanded:
                p.command(self._volts(self.target))
            p.advance(T, T)
            if p.tripped:               # the communication watchdog
                self.fault(RPDO_TIMEOUT)
        elif sm.state == c.QUICK_STOP_ACTIVE:
            p.command(self._quick_stop_volts(T))
            p.advance(T, T)
            if self._qs_ref == 0.0 and abs(p.v_m) < STANDSTILL:
                sm.quick_stop_done()
        else:                           # disabled, or the fault reaction: 0 V, dynamic brake
            p.disable()
            p.advance(T, T)
            if sm.state == c.FAULT_REACTION:
                sm.fault_reaction_done()
        if sm.state != c.QUICK_STOP_ACTIVE:
            self._qs_ref = p.v_m

    def _volts(self, permille: int) -> float:
        limit = self.max_torque
        permille = max(-limit, min(limit, permille))
        return permille / 1000.0 * self.plant.params['amplifier_limit']

    def _quick_stop_volts(self, T: float) -> float:
        """The drive's velocity loop on a ramp to standstill at the quick stop deceleration."""
        p = self.plant
        decel = self.quick_stop_decel / p.motor_counts_per_m
        ref = self._qs_ref
        ref = math.copysign(max(0.0, abs(ref) - decel * T), ref)
        self._qs_ref = ref
        q = p.params
        force_per_volt = q['amplifier_gain'] * q['torque_constant'] * TWO_PI / q['lead']
        kv = TWO_PI * QUICK_STOP_BANDWIDTH * (p.motor_mass + q['slide_mass']) / force_per_volt
        limit = q['amplifier_limit']
        return max(-limit, min(limit, kv * (ref - p.v_m)))

    def fault(self, code: int) -> None:
        """The drive faults with error code `code`: EMCY, the fault reaction (0 V, brake)."""
        if self.sm.state in (c.FAULT, c.FAULT_REACTION):
            return
        self.sm.fault(code)
        self.plant.disable()
        if self.drive.node.nmt.state in ('OPERATIONAL', 'PRE-OPERATIONAL'):
            self.drive.node.emcy.send(code, _error_register(code))

    def inject_fault(self, code: int) -> None:
        """Fault with `code` at the next cycle (an overcurrent, an overtemperature, ...)."""
        self._pending_fault = code


class VirtualDrives:
    """The emulated drives of a machine on one bus, served by one receive thread: SYNC consumer
    for all of them, and, while no SYNC comes, the drives' own clock. One thread for both: a
    drive process held up by its machine finds the SYNCs queued when it runs again and steps on
    them, instead of mistaking the silence for a dead master."""

    def __init__(self, axes: dict[str, DriveConfig], interface: str, channel: str,
                 bitrate: int = 1_000_000, substep_rate: float = 20000.0,
                 realtime: bool = True, log: Callable[[str, str], None] | None = None,
                 priority: int = RECEIVE_PRIORITY) -> None:
        """`realtime`: the drives' own clock runs the slides when SYNCs stop; off, the drives
        only follow the SYNCs (a lockstep run)."""
        self.bus_args: dict[str, Any] = {'interface': interface, 'channel': channel,
                                         'bitrate': bitrate}
        self.axes = {a: VirtualAxis(a, cfg, substep_rate) for a, cfg in axes.items()}
        self.realtime = realtime
        self.priority = priority
        self._log = log or (lambda level, text: None)
        self._failed: set[str] = set()      # what went wrong in the receive thread (logged once)
        self.network = canopen.Network()
        self.lock = threading.Lock()        # the drives' state, against the ROS shell's reads
        self.syncs = 0
        self.sampled: tuple[float, list[float], list[float], list[float]] | None = None
        self.free = False                   # the drives' own clock runs the slides
        self.free_steps = 0                 # periods the drives' own clock ran (no SYNC)
        self._last_step = time.monotonic()
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None

    def _nodes(self):
        for ax in self.axes.values():
            yield ax.drive
            if ax.encoder is not None:
                yield ax.encoder

    def start(self) -> None:
        """Open the bus, boot every node (boot-up message, PRE-OPERATIONAL, heartbeat)."""
        self.network.bus = can.Bus(**self.bus_args)
        for n in self._nodes():
            self.network.add_node(n.node)
        self.network.subscribe(0, self._on_nmt)      # after the nodes' own NMT handlers
        self.network.subscribe(SYNC_COB_ID, self._on_sync)
        for ax in self.axes.values():
            self.network.subscribe(0x200 + ax.config.node_id, ax.on_rpdo)
        self._thread = threading.Thread(target=self._receive, name='virtual drives',
                                        daemon=True)
        self._thread.start()
        for n in self._nodes():
            _put(n.node, c.PRODUCER_HEARTBEAT, HEARTBEAT_MS)
            n.node.nmt.send_command(0x81)       # reset: boot-up message
            n.node.nmt.send_command(0x80)       # PRE-OPERATIONAL, heartbeat on

    def stop(self) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join(1.0)
        for n in self._nodes():
            n.node.nmt.stop_heartbeat()
        self.network.disconnect()

    def _receive(self) -> None:
        if self.realtime and self.priority:
            # A drive is hardware: its cycle does not wait on the PC's scheduler. This thread
            # alone runs at SCHED_FIFO (where allowed: root, CAP_SYS_NICE, an rtprio limit).
            try:
                os.sched_setscheduler(threading.get_native_id(), os.SCHED_FIFO,
                                      os.sched_param(self.priority))
            except (OSError, AttributeError) as e:
                self._log('info', f'virtual drives: normal scheduling ({e})')
        bus, network = self.network.bus, self.network
        assert bus is not None
        while not self._stop.is_set():
            msg = bus.recv(RECEIVE_SLICE)
            if msg is None:
                if self.realtime:
                    self._run_clock()
                continue
            if msg.is_error_frame or msg.is_remote_frame:
                continue
            try:
                network.notify(msg.arbitration_id, msg.data, msg.timestamp)
            except Exception as e:      # a bad frame must not stop the drives
                what = f'frame 0x{msg.arbitration_id:03X}: {e!r}'
                if what not in self._failed:
                    self._failed.add(what)
                    self._log('error', f'virtual drives: {what} (once):\n'
                                       f'{traceback.format_exc()}')

    def _on_nmt(self, can_id: int, data: bytearray, timestamp: float) -> None:
        with self.lock:
            for n in self._nodes():
                n.nmt_changed()

    def _on_sync(self, can_id: int, data: bytearray, timestamp: float) -> None:
        self.free = False
        with self.lock:
            self.syncs += 1
            # (timestamp: when the frame came in, on time.time()'s clock for udp_multicast,
            # virtual and socketcan; plant_states is stamped with it, as the controller stamps
            # the tick that sent this SYNC)
            now = time.time()
            self.sampled = (timestamp if now - 1.0 < timestamp <= now else now, *self._state())
            for ax in self.axes.values():
                ax.sync()
        self._last_step = time.monotonic()

    def _run_clock(self) -> None:
        """The bus was quiet for RECEIVE_SLICE: without SYNC for FREE_RUN the slides run on in
        real time from the last SYNC, a period a step, until a SYNC comes (the watchdog counts
        the periods: a dead master's drives fault and brake)."""
        now = time.monotonic()
        if not self.free and now - self._last_step < FREE_RUN:
            return
        self.free = True
        T = min(ax.period for ax in self.axes.values())
        steps = min(int((now - self._last_step) / T), 1000)
        if not steps:
            return
        with self.lock:
            for _ in range(steps):
                for ax in self.axes.values():
                    ax.step(T)
            self.free_steps += steps
        self._last_step += steps * T

    # -- what the ROS shell and tests use ---------------------------------------------------------
    def inject_fault(self, axis: str, code: int) -> None:
        with self.lock:
            self.axes[axis].inject_fault(code)

    def configure_plant(self, axis: str, changes: dict) -> None:
        """New plant registers for one axis (validated together; ValueError refuses all)."""
        with self.lock:
            ax = self.axes[axis]
            ax.plant.configure(**changes)
            ax._rated_torque()

    def truth(self) -> tuple[float, list[float], list[float], list[float]]:
        """The slides as the last SYNC found them (what the TPDOs sampled), with the time.time()
        that SYNC came at; or, while the drives' own clock runs (no SYNC), as they are now:
        (time [s], positions, velocities [m, m/s] (motor then load, axis by axis:
        plant_states' order), the volts each amplifier applied)."""
        with self.lock:
            if self.sampled is not None and not self.free:
                return self.sampled
            return (time.time(), *self._state())

    def _state(self) -> tuple[list[float], list[float], list[float]]:
        pos: list[float] = []
        vel: list[float] = []
        volts: list[float] = []
        for ax in self.axes.values():
            p = ax.plant
            pos += [p.x_m, p.x_l]
            vel += [p.v_m, p.v_l]
            volts.append(p.volts)
        return pos, vel, volts


# -- the emulated drives in a process of their own ----------------------------------------------
_STATES = (c.NOT_READY, c.SWITCH_ON_DISABLED, c.READY, c.SWITCHED_ON, c.OPERATION_ENABLED,
           c.QUICK_STOP_ACTIVE, c.FAULT_REACTION, c.FAULT)
SHARE_PERIOD = 1e-3                 # s: how often the drives' process shares the slides' state


class DrivesProcess:
    """`VirtualDrives` in a process of their own, beside the one that publishes them: a drive
    is hardware, and the emulated drives' thread must not share an interpreter (its lock) with
    a ROS node's threads. The slides' state comes back through shared memory (SHARE_PERIOD);
    fault injection and plant registers go there through a queue; the drives' log lines come
    back through another."""

    def __init__(self, axes: dict[str, DriveConfig], interface: str, channel: str,
                 bitrate: int = 1_000_000, substep_rate: float = 20000.0) -> None:
        ctx = multiprocessing.get_context('spawn')     # (never fork a process with ROS threads)
        self.names = list(axes)
        n = len(axes)
        # time, then per axis x_m, x_l, v_m, v_l, volts; and per axis state index, error code
        self._floats = ctx.Array('d', 1 + 5 * n)
        self._ints = ctx.Array('i', 2 * n)
        self._commands = ctx.Queue()
        self._logs = ctx.Queue()
        self._stop = ctx.Event()
        self._started = ctx.Event()
        self._proc = ctx.Process(target=_serve, name='virtual drives', daemon=True, args=(
            axes, interface, channel, bitrate, substep_rate, self._floats, self._ints,
            self._commands, self._logs, self._stop, self._started))

    def start(self, timeout: float = 30.0) -> None:
        """Start the drives; raises RuntimeError with the reason when their bus cannot open."""
        self._proc.start()
        end = time.monotonic() + timeout
        while not self._started.wait(0.05):
            if not self._proc.is_alive() or time.monotonic() > end:
                reasons = [text for level, text in self.logs() if level == 'fatal']
                self.stop()
                raise RuntimeError(reasons[0] if reasons else 'the drives did not start')

    def stop(self) -> None:
        self._stop.set()
        self._proc.join(2.0)
        if self._proc.is_alive():
            self._proc.kill()
            self._proc.join(1.0)

    def inject_fault(self, axis: str, code: int) -> None:
        self._commands.put(('fault', axis, code))

    def configure_plant(self, axis: str, changes: dict) -> None:
        """(validated by the caller; a refusal there is logged)"""
        self._commands.put(('plant', axis, changes))

    def truth(self) -> tuple[float, list[float], list[float], list[float]]:
        """As VirtualDrives.truth, as the drives' process last shared it."""
        with self._floats.get_lock():
            f = self._floats[:]
        pos, vel, volts = [], [], []
        for i in range(len(self.names)):
            x_m, x_l, v_m, v_l, v = f[1 + 5 * i:6 + 5 * i]
            pos += [x_m, x_l]
            vel += [v_m, v_l]
            volts.append(v)
        return f[0], pos, vel, volts

    def states(self) -> list[tuple[str, int]]:
        """Per axis: the drive's state and its error code (603Fh)."""
        with self._ints.get_lock():
            i = self._ints[:]
        return [(_STATES[i[2 * k]], i[2 * k + 1]) for k in range(len(self.names))]

    def logs(self) -> list[tuple[str, str]]:
        """The drives' log lines since the last call."""
        lines = []
        while True:
            try:
                lines.append(self._logs.get_nowait())
            except queue.Empty:
                return lines


def _serve(axes, interface, channel, bitrate, substep_rate, floats, ints, commands, logs, stop,
           started) -> None:
    """The drives' process: VirtualDrives in real time, their state shared every SHARE_PERIOD,
    commands applied as they come; ends with `stop` or with its parent."""
    try:                            # (Linux: SIGKILL when the parent dies)
        ctypes.CDLL(None, use_errno=True).prctl(1, signal.SIGKILL)
    except (OSError, AttributeError):
        pass
    signal.signal(signal.SIGINT, signal.SIG_IGN)    # (the parent stops it)
    try:        # every thread of this process (they inherit it): no lock of this interpreter
        # is held by a thread at normal scheduling while the drives' thread waits for it
        os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(RECEIVE_PRIORITY))
    except (OSError, AttributeError):
        pass
    drives = VirtualDrives(axes, interface, channel, bitrate, substep_rate,
                           log=lambda level, text: logs.put((level, text)))
    try:
        drives.start()
    except Exception as e:          # python-can raises per interface
        logs.put(('fatal', f'cannot open the bus (can_interface {interface!r}, can_channel '
                           f'{channel!r}): {e}'))
        return
    started.set()
    index = {s: i for i, s in enumerate(_STATES)}
    try:
        while not stop.wait(SHARE_PERIOD):
            t, pos, vel, volts = drives.truth()
            with drives.lock:
                codes = [(index.get(ax.sm.state, 0), ax.sm.error_code)
                         for ax in drives.axes.values()]
            with floats.get_lock():
                floats[0] = t
                for i in range(len(volts)):
                    floats[1 + 5 * i:6 + 5 * i] = [pos[2 * i], pos[2 * i + 1], vel[2 * i],
                                                   vel[2 * i + 1], volts[i]]
            with ints.get_lock():
                for i, (state, code) in enumerate(codes):
                    ints[2 * i:2 * i + 2] = [state, code]
            while True:
                try:
                    what, axis, value = commands.get_nowait()
                except queue.Empty:
                    break
                try:
                    if what == 'fault':
                        drives.inject_fault(axis, value)
                    else:
                        drives.configure_plant(axis, value)
                except ValueError as e:
                    logs.put(('error', f'{axis}: plant registers not applied: {e}'))
    finally:
        drives.stop()
