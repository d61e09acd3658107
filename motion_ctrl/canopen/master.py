"""`hardware: canopen`: the servo loop's hardware interface (core.hardware) on a CAN bus of
CiA 402 drives in cyclic synchronous torque mode, through `canopen` (SDO, NMT, EMCY, heartbeat)
and `python-can` (the bus: socketcan, pcan, kvaser, virtual, udp_multicast, ...).

The controller is the SYNC producer and the PC closes the position loop: the drive is a
torque-mode amplifier on the bus (CST, 6060h = 10), the loop's output [V] becomes the target
torque 6071h [‰ of the rated torque 6076h] by the axis's `torque_per_volt`.

Start-up (`configure`), per drive, by SDO, each step checked: every node is put in
PRE-OPERATIONAL; its device type 1000h must be a CiA 402 drive (an encoder node CiA 406); its
supported modes 6502h must have CST; 6060h = 10 is written and 6061h must read it back; the PDO
mapping of `objects` is written (COB-ID invalid, transmission type 1, entries, COB-ID valid),
the PDOs it does not use are switched off, and everything is read back; 1006h (the SYNC period)
and 1017h (the heartbeat) are written. The servo rate must fit the bus (`busload`). Any of
these that fails raises HardwareError, one line naming the node id, the axis and the object:
the node exits 2. `activate` starts the nodes (NMT OPERATIONAL).

The cycle (`read` / `write` of ServoLoop.cycle), as a CANopen manager's task runs it:

* `read`: the frames waiting on the bus are taken (by the servo thread itself: from `activate`
  on there is no receive thread, which would wait on the interpreter's lock while the loop
  ticks on); the newest TPDOs, sampled by the drives at a SYNC (normally the last), become each
  axis's sample (motor 6064h, load 60E4h or the encoder's 6004h), stamped with that SYNC's
  time (`_Slot`: which SYNC a frame answers is counted); an axis whose TPDOs of no newer SYNC
  have all come has no new sample (a missing sample: feedback_timeout counts it). The
  statusword's fault bit is a DRIVE fault with the error code 603Fh it carries; a lost
  heartbeat, or a node that left OPERATIONAL, a LINK fault; an EMCY is logged.
* `write`: per drive, the RPDO (controlword, target torque), then the SYNC: the drives apply
  the RPDO at this SYNC and sample their TPDOs, which the next cycle reads. The loop's delay is
  one period (the sample's age), which the loop takes out as it does a network's.

The CiA 402 state machine follows the axis's loop (AxisIO.enabled): its closing walks the drive
through shutdown, switch on, enable operation (one transition a cycle, from the statusword it
reports); its opening (ABORT, disable, a fault) is disable voltage; `reset` is a fault
reset (a rising edge of controlword bit 7), and a FAULT the drive reports from a sample taken
before the reset took effect is not reported again. An axis with a quick stop deceleration
(`estop_quick_stop`) has the drive quick-stop (controlword 02h) while its status says ESTOPPED
(`watch` gives the axes): the drive brakes at 6085h on its own and disables (605Ah = 2); the
next move, which clears ESTOPPED, enables it again. `deactivate` (the controller's stop) sends
torque 0 with disable voltage, applied by a last SYNC, and returns the nodes to
PRE-OPERATIONAL.
"""
from __future__ import annotations

import dataclasses
import logging
import os
import threading
import time
from collections import deque
from dataclasses import dataclass
from typing import Any, Callable

import canopen
from canopen.emcy import EmcyError
from canopen.sdo import SdoAbortedError, SdoCommunicationError

from motion_ctrl.canopen import busload
from motion_ctrl.canopen import cia402 as c
from motion_ctrl.canopen.objects import (DRIVE_EDS, ENCODER_EDS, ENCODER_TPDO1, PDO_NOT_VALID,
                                         RPDO1, SYNCHRONOUS, TPDO1, Pdo, cycle_frames,
                                         drive_pdos, mapping_entry)
from motion_ctrl.core.hardware import DRIVE, LINK, HardwareError, HardwareInterface
from msg_defs.status import Status

_ESTOPPED = int(Status.ESTOPPED)

HEARTBEAT_MS = 100              # 1017h written to every node
HEARTBEAT_LOST = 5              # heartbeat periods without one: the node is lost (CiA 301:
                                # consumer time > producer time; a drive with no TPDOs is found
                                # by feedback_timeout long before, this is for the NMT link)
SDO_TIMEOUT = 0.3               # s for an SDO answer (canopen's default)
BOOT_TIMEOUT = 5.0              # s a node may take to answer its first SDO (it may be booting)
ENABLE_TIMEOUT = 0.5            # s for a drive to reach OPERATION ENABLED
START_TIMEOUT = 2.0             # s for a node to say OPERATIONAL after its NMT start
RESET_CYCLES = 2                # samples after a fault reset that may still show the fault
NOTIFIER_CYCLE = 0.1            # s: the receive thread's poll (how long a stop waits for it)
RECEIVE_MAX = 1000              # frames taken off the bus at most in one read
KEPT = 8                        # frames kept per TPDO (their SYNCs: the last KEPT)
WINDOW = 200                    # frames over which a TPDO count's lag is judged
STATS = 100_000                 # cycles of latency kept for the benchmark


@dataclass(frozen=True)
class AxisNodes:
    """One axis on the bus: the drive's node id, the load encoder (0: the drive's additional
    position actual value 60E4h, else a CiA 406 encoder node with this id), the drive's EDS
    ('' = the shipped generic CiA 402 one) and the output scaling [‰ of rated torque per V]."""
    node_id: int
    load_encoder_node_id: int = 0
    eds: str = ''
    torque_per_volt: float = 100.0
    # an ESTOP of the axis is the drive's quick stop too (605Ah = 2, at 6085h [counts/s²]);
    # 0: the controller's ESTOP profile alone
    quick_stop_deceleration: int = 0


class _Slot:
    """The frames of one TPDO, by the SYNC they answer: a drive answers every SYNC, in order,
    from the first after its NMT start (CAN delivers every frame, in order, or goes bus-off), so
    the m-th frame answers the m-th SYNC, however late it comes (a sample more than KEPT SYNCs
    old is not used).

    Two checks keep the count right when frames are lost after all (an adapter's overrun, an
    emulated bus's datagrams): a count ahead of the SYNCs sent is set back to the last one; and
    when every frame of a WINDOW came at least one SYNC after the one its count names (the
    count lags: a late frame comes late now and then, not always), the count moves on by the
    least of those lags."""
    __slots__ = ('frames', 'count', 'realigned', 'lag', 'seen')

    def __init__(self) -> None:
        self.frames: deque = deque(maxlen=KEPT)     # (SYNC count, data, arrival [s])
        self.count = 0
        self.realigned = 0
        self.lag = 1 << 30              # the least lag of the frames of this window
        self.seen = 0                   # frames of this window

    def counted(self, after: int, sent: int) -> int:
        """The SYNC the next frame answers, `after` being the last SYNC sent before it came
        and `sent` the SYNCs sent so far."""
        n = self.count + 1
        self.lag = min(self.lag, after - n)
        self.seen += 1
        if self.seen >= WINDOW:
            if self.lag > 0:
                n += self.lag
                self.realigned += 1
            self.lag, self.seen = 1 << 30, 0
        if n > sent:
            n = sent
            self.realigned += 1
        self.count = n
        return n

    def newest(self) -> tuple[int, bytes, float] | None:
        frames = list(self.frames)
        return frames[-1] if frames else None

    def answering(self, n: int) -> tuple[int, bytes, float] | None:
        # (list(): a copy made in one C call, which the receive thread's appends cannot
        # interleave; a Python loop over the deque itself can meet one)
        for frame in reversed(list(self.frames)):
            if frame[0] == n:
                return frame
        return None


class _Axis:
    def __init__(self, name: str, cfg: AxisNodes) -> None:
        self.name = name
        self.cfg = cfg
        self.node = None                    # canopen.RemoteNode
        self.encoder = None
        self.tpdo1 = _Slot()
        self.load = _Slot()
        self.used = -1                      # the SYNC count of the last sample handed on
        self.statusword = 0
        self.error_code = 0
        self.want = False                   # the loop is closed: the drive should be enabled
        self.want_since = 0.0
        self.cw = c.CW_DISABLE_VOLTAGE      # the controlword last sent
        self.reset_pending = False
        self.ignore_fault_until = -1        # SYNC count: a FAULT sampled before is stale
        self.heartbeat: dict[int, tuple[float, int]] = {}   # node id -> (arrival, NMT state)
        self.operational: set[int] = set()  # nodes whose heartbeat said OPERATIONAL
        self.emcy: deque = deque(maxlen=16)  # (node id, code, register) not yet logged
        self.fault: str | None = None       # the DRIVE fault being reported
        self.quick_stop = False             # the drive is told to quick-stop (an ESTOP)


def _hex(index: int, sub: int = 0) -> str:
    return f'{index:04X}h' + (f':{sub:02X}' if sub else '')


class CanopenHardware(HardwareInterface):
    """CiA 402 drives on one CAN bus (module docstring)."""

    kind = 'canopen'

    def __init__(self, axes: dict[str, AxisNodes], period: float, interface: str,
                 channel: str, bitrate: int = 1_000_000,
                 log: Callable[[str, str], None] | None = None,
                 boot_timeout: float = BOOT_TIMEOUT) -> None:
        super().__init__(list(axes))
        self.boot_timeout = boot_timeout
        self.period = period
        self.bus_args: dict[str, Any] = {'interface': interface, 'channel': channel,
                                         'bitrate': bitrate}
        self.bitrate = bitrate
        self._ax = {a: _Axis(a, cfg) for a, cfg in axes.items()}
        self._log = log or (lambda level, text: None)
        self.network: Any = None            # canopen.Network, while configured
        self.sync_count = 0                 # SYNCs sent
        self._sync_stamp: dict[int, float] = {}     # SYNC count -> its `now` [s]
        self._sync_sent = 0.0               # monotonic time of the last SYNC
        self._lock = threading.Lock()
        # the cycle's timing, for the benchmark: SYNC -> last TPDO, SYNC -> the RPDO computed
        # from its samples [s], and the cycles whose samples had not all come by the read
        self.response: deque = deque(maxlen=STATS)
        self.cycle_latency: deque = deque(maxlen=STATS)
        self.missed = 0
        self.cycles = 0
        self._started = 0.0
        self._axes: dict = {}               # the servo loop's axes (watch): their status
        self._said: set[str] = set()        # what went wrong, logged once
        self._faults_now: dict[str, tuple[str, str]] = {}   # this read's: axis -> (kind, why)
        self._window: list[float] = []      # SYNC -> TPDO since the last `figures`
        self._intervals: list[float] = []   # between SYNCs [s, monotonic], likewise
        self._to_rpdo: list[float] = []     # SYNC -> the RPDO computed from its samples
        self._sync_wall: deque = deque(maxlen=KEPT * 4)     # (time.time() at send, count)

    # -- the bus's figures ---------------------------------------------------------------------
    @property
    def frames(self) -> list[int]:
        return cycle_frames([x.cfg.load_encoder_node_id for x in self._ax.values()])

    def bus_load(self) -> float:
        return busload.load(1.0 / self.period, self.bitrate, self.frames)

    # -- lifecycle -------------------------------------------------------------------------------
    def on_configure(self) -> None:
        ids: dict[int, str] = {}
        for a, x in self._ax.items():
            for nid, what in ((x.cfg.node_id, 'can_node_id'),
                              (x.cfg.load_encoder_node_id, 'load_encoder_node_id')):
                if nid and nid in ids:
                    raise HardwareError(f'canopen: node {nid} is both {ids[nid]} and {a}.{what}')
                if nid:
                    ids[nid] = f'{a}.{what}'
            if not os.path.isfile(x.cfg.eds or DRIVE_EDS):
                raise HardwareError(f'canopen: {a}: EDS file {x.cfg.eds!r} not found')
        reason = busload.refusal(1.0 / self.period, self.bitrate, self.frames)
        if reason:
            raise HardwareError(f'canopen: servo_rate {reason}')
        network = canopen.Network()
        network.NOTIFIER_CYCLE = NOTIFIER_CYCLE
        try:
            network.connect(**self.bus_args)
        except Exception as e:      # python-can raises per interface (CanError, OSError, ...)
            raise HardwareError(f'canopen: cannot open the bus (can_interface '
                                f'{self.bus_args["interface"]!r}, can_channel '
                                f'{self.bus_args["channel"]!r}): {e}') from None
        self.network = network
        try:
            for a, x in self._ax.items():
                self._configure_drive(network, a, x)
                if x.cfg.load_encoder_node_id:
                    self._configure_encoder(network, a, x)
        except HardwareError:
            network.disconnect()
            self.network = None
            raise

    def _node(self, network, node_id: int, eds: str, a: str, what: str):
        try:
            node = canopen.RemoteNode(node_id, eds)
        except Exception as e:
            raise HardwareError(f'canopen: {a}: EDS {eds!r}: {e}') from None
        node.sdo.RESPONSE_TIMEOUT = SDO_TIMEOUT
        network.add_node(node)
        end = time.monotonic() + self.boot_timeout
        sdo_log = logging.getLogger('canopen.sdo.client')
        level = sdo_log.level
        sdo_log.setLevel(logging.CRITICAL)  # (each unanswered try logs an abort: said once below)
        try:
            while True:             # a node still booting answers its first SDO late
                try:
                    device = self._sdo_read(node, a, what, c.DEVICE_TYPE, 0, 'device type')
                    break
                except HardwareError as e:
                    if 'does not answer' not in str(e) or time.monotonic() > end:
                        if 'does not answer' in str(e):
                            raise HardwareError(f'{e}, nor in the {self.boot_timeout:g} s a '
                                                f'node may take to boot') from None
                        raise
        finally:
            sdo_log.setLevel(level)
        node.nmt.state = 'PRE-OPERATIONAL'
        return node, device

    def _sdo_read(self, node, a: str, what: str, index: int, sub: int, name: str) -> int:
        try:
            return _raw(node, index, sub)
        except SdoCommunicationError:
            raise HardwareError(f'canopen: node {node.id} ({a} {what}) does not answer: no SDO '
                                f'response to {_hex(index, sub)} ({name}) in '
                                f'{SDO_TIMEOUT:g} s') from None
        except SdoAbortedError as e:
            raise HardwareError(f'canopen: node {node.id} ({a} {what}): reading '
                                f'{_hex(index, sub)} ({name}) refused: {e}') from None

    def _sdo_write(self, node, a: str, what: str, index: int, sub: int, value: int,
                   name: str) -> None:
        try:
            _set_raw(node, index, sub, value)
        except SdoCommunicationError:
            raise HardwareError(f'canopen: node {node.id} ({a} {what}) does not answer: no SDO '
                                f'response writing {_hex(index, sub)} ({name})') from None
        except SdoAbortedError as e:
            raise HardwareError(f'canopen: node {node.id} ({a} {what}) refused {name} '
                                f'({_hex(index, sub)} = 0x{value:X}): {e}') from None

    def _configure_drive(self, network, a: str, x: _Axis) -> None:
        what = 'drive'
        node, device = self._node(network, x.cfg.node_id, x.cfg.eds or DRIVE_EDS, a, what)
        x.node = node
        if device & 0xFFFF != c.PROFILE_DRIVE:
            raise HardwareError(f'canopen: node {node.id} ({a} drive) is no CiA 402 drive: '
                                f'1000h (device type) = 0x{device:08X}, profile '
                                f'{device & 0xFFFF}')
        od = node.object_dictionary
        if c.SUPPORTED_MODES in od:
            modes = self._sdo_read(node, a, what, c.SUPPORTED_MODES, 0, 'supported drive modes')
            if not modes & (1 << c.SUPPORTED_MODE_BIT[c.CST]):
                names = [n for m, n in c.MODES.items() if modes & (1 << c.SUPPORTED_MODE_BIT[m])]
                raise HardwareError(f'canopen: node {node.id} ({a} drive) has no cyclic '
                                    f'synchronous torque mode: 6502h (supported drive modes) = '
                                    f'0x{modes:08X} ({", ".join(names) or "none"})')
        self._sdo_write(node, a, what, c.MODES_OF_OPERATION, 0, c.CST,
                        'cyclic synchronous torque mode (6060h = 10)')
        mode = self._sdo_read(node, a, what, c.MODES_DISPLAY, 0, 'modes of operation display')
        if mode != c.CST:
            raise HardwareError(f'canopen: node {node.id} ({a} drive) runs mode {mode} '
                                f'({c.MODES.get(mode, "unknown")}), not 10 (cyclic synchronous '
                                f'torque): 6061h (modes of operation display)')
        rx, tx = drive_pdos(x.cfg.load_encoder_node_id == 0)
        self._map(node, a, what, rx, c.RPDO_COMM)
        self._map(node, a, what, tx, c.TPDO_COMM)
        self._cycle_objects(node, a, what)
        if x.cfg.quick_stop_deceleration:
            self._sdo_write(node, a, what, c.QUICK_STOP_OPTION, 0, 2,
                            'the quick stop option code (605Ah = 2: ramp, then disable)')
            self._sdo_write(node, a, what, c.QUICK_STOP_DECELERATION, 0,
                            x.cfg.quick_stop_deceleration, 'the quick stop deceleration')
        rated = self._sdo_read(node, a, what, c.RATED_TORQUE, 0, 'motor rated torque')
        self._log('info', f'{a}: node {node.id}: CiA 402 drive in CST, rated torque {rated} '
                          f'mN·m, {x.cfg.torque_per_volt:g} ‰/V; PDOs {RPDO1.name} '
                          f'[{RPDO1.objects()}], ' + ', '.join(f'{p.name} [{p.objects()}]'
                                                               for p in tx))
        network.subscribe(TPDO1.cob_id(node.id), self._receiver(x.tpdo1))
        if x.cfg.load_encoder_node_id == 0:
            network.subscribe(tx[1].cob_id(node.id), self._receiver(x.load))
        self._watch(node, x)

    def _configure_encoder(self, network, a: str, x: _Axis) -> None:
        what = 'load encoder'
        node, device = self._node(network, x.cfg.load_encoder_node_id, ENCODER_EDS, a, what)
        x.encoder = node
        if device & 0xFFFF != c.PROFILE_ENCODER:
            raise HardwareError(f'canopen: node {node.id} ({a} load encoder) is no CiA 406 '
                                f'encoder: 1000h (device type) = 0x{device:08X}, profile '
                                f'{device & 0xFFFF}')
        self._map(node, a, what, [ENCODER_TPDO1], c.TPDO_COMM)
        self._cycle_objects(node, a, what)
        network.subscribe(ENCODER_TPDO1.cob_id(node.id), self._receiver(x.load))
        self._watch(node, x)

    def _map(self, node, a: str, what: str, pdos: list[Pdo], comm0: int) -> None:
        """Write the PDOs `pdos` (and switch off the others of that direction), read back."""
        od = node.object_dictionary
        used = {p.comm for p in pdos}
        for i in range(512):
            comm = comm0 + i
            if comm not in od or comm in used:
                continue
            cob = self._sdo_read(node, a, what, comm, 1, f'the COB-ID at {_hex(comm)}')
            self._sdo_write(node, a, what, comm, 1, cob | PDO_NOT_VALID,
                            f'switching off the PDO at {_hex(comm)}')
        for p in pdos:
            cob = p.cob_id(node.id)
            self._sdo_write(node, a, what, p.comm, 1, cob | PDO_NOT_VALID,
                            f'{p.name} COB-ID (invalid while mapped)')
            self._sdo_write(node, a, what, p.comm, 2, SYNCHRONOUS,
                            f'{p.name} transmission type')
            self._sdo_write(node, a, what, p.mapping, 0, 0, f'{p.name} mapping count')
            for k, (index, sub, bits) in enumerate(p.entries, 1):
                self._sdo_write(node, a, what, p.mapping, k, mapping_entry(index, sub, bits),
                                f'the mapping of {_hex(index, sub)} into {p.name}')
            self._sdo_write(node, a, what, p.mapping, 0, len(p.entries),
                            f'{p.name} mapping count')
            self._sdo_write(node, a, what, p.comm, 1, cob, f'{p.name} COB-ID')
        for p in pdos:                                          # read back
            n = self._sdo_read(node, a, what, p.mapping, 0, f'{p.name} mapping count')
            got = [self._sdo_read(node, a, what, p.mapping, k, f'{p.name} mapping')
                   for k in range(1, n + 1)]
            want = [mapping_entry(*e) for e in p.entries]
            cob = self._sdo_read(node, a, what, p.comm, 1, f'{p.name} COB-ID')
            trans = self._sdo_read(node, a, what, p.comm, 2, f'{p.name} transmission type')
            if got != want or cob != p.cob_id(node.id) or trans != SYNCHRONOUS:
                def entries(values):
                    return '[' + ', '.join(f'0x{v:08X}' for v in values) + ']'
                raise HardwareError(
                    f'canopen: node {node.id} ({a} {what}): {p.name} reads back '
                    f'{_hex(p.mapping)} = {entries(got)}, COB-ID 0x{cob:X}, transmission type '
                    f'{trans}; written {entries(want)}, 0x{p.cob_id(node.id):X}, {SYNCHRONOUS}')

    def _cycle_objects(self, node, a: str, what: str) -> None:
        od = node.object_dictionary
        if c.CYCLE_PERIOD in od:
            self._sdo_write(node, a, what, c.CYCLE_PERIOD, 0, round(self.period * 1e6),
                            'the communication cycle period')
        self._sdo_write(node, a, what, c.PRODUCER_HEARTBEAT, 0, HEARTBEAT_MS,
                        'the producer heartbeat time')

    def _receiver(self, slot: _Slot):
        def on_frame(can_id: int, data: bytearray, timestamp: float) -> None:
            n = slot.counted(self._sent_before(timestamp), self.sync_count)
            slot.frames.append((n, bytes(data), time.monotonic()))
        return on_frame

    def _sent_before(self, timestamp: float) -> int:
        """The last SYNC sent before a frame that came at `timestamp` (time.time()'s clock, as
        the virtual, udp_multicast and socketcan interfaces stamp; a stamp on another clock,
        as some adapters' own, counts as now)."""
        sent = self._sync_wall
        if sent and sent[0][0] - 1.0 < timestamp < time.time() + 0.01:
            for wall, k in reversed(list(sent)):
                if wall <= timestamp:
                    return k
            return sent[0][1] - 1
        return self.sync_count

    def _watch(self, node, x: _Axis) -> None:
        nid = node.id
        x.heartbeat[nid] = (time.monotonic(), 127)

        def on_heartbeat(state: int) -> None:
            x.heartbeat[nid] = (time.monotonic(), state)

        def on_emcy(e) -> None:
            x.emcy.append((nid, e.code, e.register))
        node.nmt.add_heartbeat_callback(on_heartbeat)
        node.emcy.add_callback(on_emcy)

    def on_activate(self) -> None:
        now = time.monotonic()
        for x in self._ax.values():
            for node in (x.node, x.encoder):
                if node is not None:
                    node.nmt.state = 'OPERATIONAL'
                    x.heartbeat[node.id] = (now, x.heartbeat[node.id][1])
        self._started = now
        # From now on the servo thread takes the frames off the bus itself at each read (no
        # receive thread to wait on the interpreter's lock while the loop ticks on).
        notifier = self.network.notifier
        if notifier is not None:
            self.network.notifier = None
            notifier.stop()

    def _receive(self) -> None:
        """Every frame waiting on the bus, to its handlers (TPDOs, heartbeats, EMCY)."""
        bus, network = self.network.bus, self.network
        for _ in range(RECEIVE_MAX):
            msg = bus.recv(0.0)
            if msg is None:
                return
            if not (msg.is_error_frame or msg.is_remote_frame):
                network.notify(msg.arbitration_id, msg.data, msg.timestamp)

    def on_deactivate(self) -> None:
        network = self.network
        if network is None:
            return
        try:
            for _ in range(2):      # torque 0, disable voltage; applied at the SYNC after it
                for x in self._ax.values():
                    x.want = False
                    network.send_message(RPDO1.cob_id(x.cfg.node_id),
                                         RPDO1.codec.pack(c.CW_DISABLE_VOLTAGE, 0))
                network.send_message(0x80, b'')
            for x in self._ax.values():
                for node in (x.node, x.encoder):
                    if node is not None:
                        node.nmt.state = 'PRE-OPERATIONAL'
        except Exception as e:      # the bus went away: the drives' watchdogs take over
            self._log('error', f'canopen: stopping the drives failed: {e}')
        finally:
            network.disconnect()
            self.network = None

    # -- the cycle -------------------------------------------------------------------------------
    def read(self, now: float) -> None:
        self._faults_now = {}
        try:
            self._read()
        except Exception as e:      # the servo loop never dies of its I/O: a link fault
            reason = f'canopen: reading the bus failed: {e!r}'
            self._once('error', reason)
            for a in self.axes:
                self._fault(a, LINK, reason)
        for a, io in self.io.items():       # (a fault is set while it lasts)
            io.fault_kind, io.fault_reason = self._faults_now.get(a, ('', ''))

    def _fault(self, a: str, kind: str, reason: str) -> None:
        """A fault of axis `a` this read (a link fault before a drive's: what the drive says
        cannot be trusted without the link)."""
        if a not in self._faults_now or kind == LINK and self._faults_now[a][0] != LINK:
            self._faults_now[a] = (kind, reason)

    def _once(self, level: str, text: str) -> None:
        if text not in self._said:
            self._said.add(text)
            self._log(level, text)

    def _read(self) -> None:
        if self.network is not None and self.network.notifier is None:
            self._receive()
        n = self.sync_count
        self.cycles += 1
        complete = True
        mono = time.monotonic()
        last = 0.0
        for a, x in self._ax.items():
            tp = x.tpdo1.newest()
            if tp is not None:
                sample = self._sample(x, tp)
                if sample is not None:
                    k, motor, load, arrived = sample
                    x.used = k
                    self.io[a].sample(motor, load, self._sync_stamp[k])
                    if k == n:
                        last = max(last, arrived)
                    else:
                        complete = False
                else:
                    complete = False
                self._faults(a, x, tp[0])
            else:
                complete = False
            self._link(a, x, mono)
            while x.emcy:
                nid, code, register = x.emcy.popleft()
                self._log('error' if code else 'info',
                          f'{a}: node {nid}: EMCY 0x{code:04X} ({_describe(code)}), error '
                          f'register 0x{register:02X}')
        if n:
            if complete and last:
                self.response.append(last - self._sync_sent)
                self._window.append(last - self._sync_sent)
            elif n > 1:
                self.missed += 1

    def _sample(self, x: _Axis, tp) -> tuple[int, int, int, float] | None:
        """The newest SYNC, not used yet, whose TPDOs have all come: (its count, motor, load,
        when the last of them came). The statusword and error code are the newest whatever."""
        k, data, arrived = tp
        sw, motor, code = TPDO1.codec.unpack(data)
        x.statusword, x.error_code = sw, code
        for k, data, arrived in reversed(list(x.tpdo1.frames)):
            if k <= x.used:
                return None
            ld = x.load.answering(k)
            if ld is not None and k in self._sync_stamp:
                return k, TPDO1.codec.unpack(data)[1], _load(ld[1]), max(arrived, ld[2])
        return None

    def _faults(self, a: str, x: _Axis, n: int) -> None:
        state = c.state_of(x.statusword)
        if c.is_fault(x.statusword) and n > x.ignore_fault_until:
            x.fault = (f'node {x.cfg.node_id}: drive {state}, error code 603Fh = '
                       f'0x{x.error_code:04X} ({_describe(x.error_code)})')
            self._fault(a, DRIVE, x.fault)
            return
        x.fault = None
        if x.quick_stop:
            x.want_since = time.monotonic()     # (disabled on purpose: the ESTOP's quick stop)
        elif x.want and state != c.OPERATION_ENABLED and n > x.ignore_fault_until and \
                time.monotonic() - x.want_since > ENABLE_TIMEOUT:
            self._fault(a, DRIVE, f'node {x.cfg.node_id}: not OPERATION ENABLED '
                                 f'{ENABLE_TIMEOUT:g} s after enable: {state} (statusword '
                                 f'0x{x.statusword:04X})')

    def _link(self, a: str, x: _Axis, mono: float) -> None:
        for nid, (t, state) in x.heartbeat.items():
            if state == 5:
                x.operational.add(nid)
            if mono - t > HEARTBEAT_LOST * HEARTBEAT_MS / 1000:
                self._fault(a, LINK, f'node {nid}: no heartbeat for {(mono - t) * 1e3:.0f} ms')
            elif state != 5 and nid in x.operational:
                self._fault(a, LINK, f'node {nid} left OPERATIONAL (heartbeat: NMT state '
                                    f'{_NMT.get(state, state)})')
            elif state != 5 and mono - self._started > START_TIMEOUT:
                self._fault(a, LINK, f'node {nid} is not OPERATIONAL {START_TIMEOUT:g} s after '
                                    f'its NMT start (heartbeat: NMT state '
                                    f'{_NMT.get(state, state)})')

    def write(self, now: float) -> None:
        try:
            self._write(now)
        except Exception as e:      # (a full send queue, a bus gone): the next cycle tries
            self._once('error', f'canopen: sending failed (logged once): {e!r}; the drives\' '
                                f'watchdogs stop them if it lasts')

    def _write(self, now: float) -> None:
        network = self.network
        if network is None:
            return
        mono = time.monotonic()
        n_used = self.sync_count
        axes = self._axes
        for x in self._ax.values():
            io = self.io[x.name]
            if io.enabled != x.want:            # the loop closed or opened: the drive follows
                self._enable(x, io.enabled)
            x.quick_stop = bool(x.cfg.quick_stop_deceleration and x.want and x.name in axes
                                and axes[x.name].status & _ESTOPPED)
            cw = c.CW_QUICK_STOP if x.quick_stop else self._controlword(x)
            torque = 0
            if x.want and c.state_of(x.statusword) == c.OPERATION_ENABLED:
                volts = io.output if io.commanded else 0.0
                torque = max(-32767, min(32767, round(volts * x.cfg.torque_per_volt)))
            network.send_message(RPDO1.cob_id(x.cfg.node_id), RPDO1.codec.pack(cw, torque))
            x.cw = cw
        self.sync_count += 1
        self._sync_stamp[self.sync_count] = now
        self._sync_stamp.pop(self.sync_count - KEPT, None)
        if n_used and self._sync_sent:
            self.cycle_latency.append(mono - self._sync_sent)
            self._to_rpdo.append(mono - self._sync_sent)
        sent = time.monotonic()
        if self._sync_sent:
            self._intervals.append(sent - self._sync_sent)
        self._sync_sent = sent
        self._sync_wall.append((time.time(), self.sync_count))
        network.send_message(0x80, b'')

    def _controlword(self, x: _Axis) -> int:
        if x.reset_pending:
            if x.cw & c.CW_FAULT_RESET:
                return c.CW_DISABLE_VOLTAGE
            x.reset_pending = False
            x.ignore_fault_until = self.sync_count + RESET_CYCLES
            return c.CW_FAULT_RESET
        return c.master_controlword(c.state_of(x.statusword), x.want)

    def _enable(self, x: _Axis, on: bool) -> None:
        if on and not x.want:
            x.want_since = time.monotonic()
        x.want = on

    def reset(self, axis: str) -> None:
        x = self._ax[axis]
        x.reset_pending = True
        x.ignore_fault_until = self.sync_count + RESET_CYCLES + 1

    def wait_for_samples(self, timeout: float) -> bool:
        """Until every axis's TPDOs answering the last SYNC are in (a lockstep run, as tests
        drive it; the real-time cycle never waits)."""
        end = time.monotonic() + timeout
        n = self.sync_count
        slots = [s for x in self._ax.values() for s in (x.tpdo1, x.load)]
        while True:
            if self.network is not None and self.network.notifier is None:
                self._receive()
            if all(s.answering(n) is not None for s in slots):
                return True
            if time.monotonic() > end:
                return False
            time.sleep(2e-5)

    def watch(self, axes: dict) -> None:
        """The servo loop's axes (core.axis.Axis by name): an ESTOP in their status is the
        drive's quick stop where the axis has one."""
        self._axes = axes

    def configure_axis(self, axis: str, changes: dict) -> None:
        """A live change of the axis's canopen registers (torque_per_volt; the others are
        read-only), applied from the next write."""
        x = self._ax[axis]
        x.cfg = dataclasses.replace(x.cfg, **changes)

    def figures(self) -> dict[str, float]:
        """The bus's figures for /diagnostics: its load; over the window since the last call,
        SYNC -> last TPDO (the drives' answer), SYNC -> the RPDO computed from it (the loop's
        delay) and SYNC -> SYNC (how regularly they go out) [us]; the cycles so far and those
        with a sample missing; each drive's statusword and error code."""
        window, self._window = self._window, []
        intervals, self._intervals = self._intervals, []
        to_rpdo, self._to_rpdo = self._to_rpdo, []
        out = {'can_bus_load_pct': self.bus_load() * 100, 'can_missed_cycles': self.missed,
               'can_cycles': self.cycles}
        for key, values in (('can_sync_to_tpdo', window), ('can_sync_to_rpdo', to_rpdo),
                            ('can_sync_interval', intervals)):
            if values:
                values.sort()
                out[f'{key}_p50_us'] = values[len(values) // 2] * 1e6
                out[f'{key}_p99_us'] = values[min(len(values) - 1, int(len(values) * 0.99))] * 1e6
                out[f'{key}_max_us'] = values[-1] * 1e6
        for a, x in self._ax.items():
            out[f'{a}_drive_statusword'] = x.statusword
            out[f'{a}_drive_error_code'] = x.error_code
        return out

    # -- what the node shows ---------------------------------------------------------------------
    def drive_states(self) -> dict[str, tuple[str, int, int]]:
        """Per axis: the drive's state, statusword and error code (603Fh) as last sampled."""
        return {a: (c.state_of(x.statusword), x.statusword, x.error_code)
                for a, x in self._ax.items()}


_NMT = {0: 'boot-up', 4: 'STOPPED', 5: 'OPERATIONAL', 127: 'PRE-OPERATIONAL'}


def _describe(code: int) -> str:
    return EmcyError(code, 0, b'', 0.0).get_desc() or 'manufacturer specific'


def _load(data: bytes) -> int:
    return int.from_bytes(data[:4], 'little', signed=True)


def _variable(node, index: int, sub: int):
    obj = node.sdo[index]
    return obj if hasattr(obj, 'raw') else obj[sub]       # a VAR, or a RECORD / ARRAY entry


def _raw(node, index: int, sub: int) -> int:
    return _variable(node, index, sub).raw


def _set_raw(node, index: int, sub: int, value: int) -> None:
    _variable(node, index, sub).raw = value
