"""Refused input, said once a second: a stream of bad messages must neither flood the log nor
slow the loop (the controller's refusals of targets, trajectories and parameter loads, and the
bridge's of a target it does not copy onto the servo bus: too large, or malformed whatever the
axes).

Each kind of refusal logs its first line at once and then at most one line per PERIOD, which
counts the refusals of that kind not logged since (`... (41 more refused in the last 1.0 s)`).
"""
from __future__ import annotations

import math
import time
from collections.abc import Callable

from rclpy.serialization import deserialize_message
from sensor_msgs.msg import JointState

import msg_defs as md

PERIOD = 1.0      # s: at most one line per kind of refused input per second


def too_large(what: str, size: int) -> str:
    """The refusal of a `what` message of `size` bytes over msg_defs.MAX_TARGET_BYTES (as the
    controller says it, and the bridge that stops it before the servo bus)."""
    return f'{what} refused: a {size}-byte message (at most {md.MAX_TARGET_BYTES})'


# The field each target topic carries.
TARGET_FIELD = {md.TARGET_POSITION: 'position', md.TARGET_VELOCITY: 'velocity'}


def malformed_target(what: str, data: bytes) -> str | None:
    """Why a raw `what` message (target_position, target_velocity) is refused whichever axes
    the controller has: not a JointState, or its field refused by msg_defs.read_joint_state
    (lengths, duplicate names, NaN / inf); None when only the controller can judge it."""
    try:
        msg = deserialize_message(data, JointState)
    except Exception as e:           # (rclpy raises its own types for a bad CDR)
        return f'{what} refused: not a JointState ({e})'
    try:
        md.read_joint_state(msg, TARGET_FIELD[what])
    except md.MalformedMessage as e:
        return f'{what} refused: {e}'
    return None


class RefusalLog:
    """`warn(text)` is the logger's warning; `refused(kind, text)` is called per refusal."""

    def __init__(self, warn: Callable[[str], object]) -> None:
        self.warn = warn
        self.kinds: dict[str, list] = {}          # kind -> [time of its last line, count since]

    def refused(self, kind: str, text: str) -> None:
        now = time.monotonic()
        entry = self.kinds.setdefault(kind, [-math.inf, 0])
        if now - entry[0] < PERIOD:
            entry[1] += 1
            return
        more = f' ({entry[1]} more refused in the last {now - entry[0]:.1f} s)' \
            if entry[1] and entry[0] > -math.inf else ''
        entry[0], entry[1] = now, 0
        self.warn(text + more)
