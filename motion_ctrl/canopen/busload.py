"""What a servo cycle costs on a CAN bus, and the highest cycle rate a bitrate carries.

A classical CAN data frame with an 11-bit identifier and n data bytes is 47 + 8n bits (SOF,
identifier, RTR, IDE, r0, DLC, data, CRC, delimiters, ACK, EOF and the 3-bit interframe space);
bit stuffing adds at most one bit per 4 of the 34 + 8n bits it covers (SOF to CRC). The
worst-case length (Davis, Burns, Bril, Lukkien, "Controller Area Network (CAN) schedulability
analysis: refuted, revisited and revised", Real-Time Systems 35, 2007, eq. 2):

    bits(n) = 47 + 8n + floor((34 + 8n - 1) / 4)        # 55 for the SYNC, 135 for 8 bytes

A cycle is the SYNC, every RPDO and every SYNC-triggered TPDO of the mapping. MAX_LOAD leaves
the rest of the bus to what is not cyclic: heartbeats, EMCY, SDO, and the retransmission of a
frame destroyed by an error (CiA AN 802 and drive vendors' guidance: keep the cyclic load at or
below 70-80 %).
"""
from __future__ import annotations

import math

MAX_LOAD = 0.8
# The bitrates of CiA 301 / CiA 102 (bit/s).
BITRATES = (10_000, 20_000, 50_000, 125_000, 250_000, 500_000, 800_000, 1_000_000)


def frame_bits(n_bytes: int) -> int:
    """Worst-case bits of a data frame with an 11-bit identifier, interframe space included."""
    if not 0 <= n_bytes <= 8:
        raise ValueError(f'a CAN frame carries 0 to 8 data bytes, not {n_bytes}')
    return 47 + 8 * n_bytes + (34 + 8 * n_bytes - 1) // 4


def cycle_bits(frames: list[int]) -> int:
    """Bits of one cycle: the SYNC (no data) and `frames`, the data bytes of each PDO."""
    return frame_bits(0) + sum(frame_bits(n) for n in frames)


def load(rate: float, bitrate: float, frames: list[int]) -> float:
    """The share of the bus a cycle of `frames` at `rate` [Hz] takes."""
    return rate * cycle_bits(frames) / bitrate


def max_rate(bitrate: float, frames: list[int], max_load: float = MAX_LOAD) -> float:
    """The highest cycle rate [Hz] at which the cycle takes at most `max_load` of the bus,
    rounded down to a whole microsecond of period (the SYNC period 1006h is in us)."""
    period_us = math.ceil(cycle_bits(frames) / (bitrate * max_load) * 1e6 - 1e-9)
    return 1e6 / period_us


def refusal(rate: float, bitrate: float, frames: list[int],
            max_load: float = MAX_LOAD) -> str | None:
    """Why `rate` is too fast for the bus (with the figures), or None."""
    share = load(rate, bitrate, frames)
    if share <= max_load + 1e-12:
        return None
    return (f'{rate:g} Hz needs {share * 100:.0f} % of a {bitrate / 1000:g} kbit/s bus '
            f'({cycle_bits(frames)} bits a cycle: SYNC + {len(frames)} PDOs of '
            f'{"/".join(str(n) for n in frames)} bytes, worst-case stuffing); at most '
            f'{max_load * 100:.0f} % is cyclic: {max_rate(bitrate, frames, max_load):.0f} Hz '
            f'is the most')
