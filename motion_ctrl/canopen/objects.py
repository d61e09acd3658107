"""The shipped EDS files and the PDO mapping the master writes at start-up (CiA 301 PDOs with
CiA 402 / CiA 406 objects), one place for the master, the emulated drive and the bus load.

Per axis, every cycle (transmission type 1: the drive samples its TPDOs at each SYNC and
applies its RPDO at the next one):

    RPDO1 (0x200 + node)  6040h controlword, 6071h target torque            4 bytes
    TPDO1 (0x180 + node)  6041h statusword, 6064h position actual value,
                          603Fh error code                                  8 bytes
    and the load encoder, either
    TPDO2 (0x280 + node)  60E4h:01 additional position actual value        4 bytes
    or, on a CiA 406 encoder node,
    TPDO1 (0x180 + encoder node)  6004h position value                      4 bytes

The error code rides in TPDO1 so that a drive fault is known with its code in the cycle that
reports it, without an SDO in the servo loop.
"""
from __future__ import annotations

import os
import struct
from dataclasses import dataclass

from motion_ctrl.canopen import cia402 as c

EDS_DIR = os.path.join(os.path.dirname(os.path.abspath(__file__)), 'eds')
DRIVE_EDS = os.path.join(EDS_DIR, 'cia402_drive.eds')
ENCODER_EDS = os.path.join(EDS_DIR, 'cia406_encoder.eds')

SYNC_COB_ID = 0x80
PDO_NOT_VALID = 0x80000000      # COB-ID bit 31: the PDO is off
SYNCHRONOUS = 1                 # transmission type: every SYNC


@dataclass(frozen=True)
class Pdo:
    """One PDO of the mapping: its objects (index, subindex, bits) and where it is configured."""
    name: str
    comm: int                   # communication parameter (1400h.. / 1800h..)
    mapping: int                # mapping parameter (1600h.. / 1A00h..)
    cob_base: int               # the pre-defined connection set: COB-ID = base + node id
    entries: tuple[tuple[int, int, int], ...]
    layout: str                 # struct format of the data (little-endian, CANopen's order)

    def cob_id(self, node_id: int) -> int:
        return self.cob_base + node_id

    @property
    def size(self) -> int:
        return sum(bits for _, _, bits in self.entries) // 8

    @property
    def codec(self) -> struct.Struct:
        return struct.Struct(self.layout)

    def objects(self) -> str:
        return ', '.join(f'{i:04X}h' + (f':{s:02X}' if s else '') for i, s, _ in self.entries)


RPDO1 = Pdo('RPDO1', c.RPDO_COMM, c.RPDO_MAP, 0x200,
            ((c.CONTROLWORD, 0, 16), (c.TARGET_TORQUE, 0, 16)), '<Hh')
TPDO1 = Pdo('TPDO1', c.TPDO_COMM, c.TPDO_MAP, 0x180,
            ((c.STATUSWORD, 0, 16), (c.POSITION_ACTUAL, 0, 32), (c.ERROR_CODE, 0, 16)), '<HiH')
TPDO2_LOAD = Pdo('TPDO2', c.TPDO_COMM + 1, c.TPDO_MAP + 1, 0x280,
                 ((c.ADDITIONAL_POSITION, 1, 32),), '<i')
# CiA 406's position value is UNSIGNED32; a linear scale counting both ways around its zero
# reads as two's complement.
ENCODER_TPDO1 = Pdo('TPDO1', c.TPDO_COMM, c.TPDO_MAP, 0x180,
                    ((c.ENCODER_POSITION, 0, 32),), '<i')


def drive_pdos(load_on_drive: bool) -> tuple[list[Pdo], list[Pdo]]:
    """(RPDOs, TPDOs) the master maps on a drive; the load encoder in TPDO2 when it is the
    drive's 60E4h."""
    return [RPDO1], [TPDO1, TPDO2_LOAD] if load_on_drive else [TPDO1]


def cycle_frames(load_encoder_node_ids: list[int]) -> list[int]:
    """Data bytes of every PDO of one cycle, for axes whose load encoders are these node ids
    (0: the drive's own 60E4h)."""
    frames: list[int] = []
    for load_id in load_encoder_node_ids:
        rx, tx = drive_pdos(load_id == 0)
        frames += [p.size for p in rx + tx]
        if load_id:
            frames.append(ENCODER_TPDO1.size)
    return frames


def mapping_entry(index: int, subindex: int, bits: int) -> int:
    """A mapping parameter's value: index << 16 | subindex << 8 | length in bits."""
    return index << 16 | subindex << 8 | bits
