"""Axis status word bits (published as std_msgs/UInt32 on ``<axis>/status``).

The bit positions are part of the wire contract (doc/interface.md, "Status word bits") and never
change.
Semantics follow RSI RMP / Delta Tau PMAC.
"""

import enum

__all__ = ['Status']


class Status(enum.IntFlag):
    """Bits of an axis status word (RMP / PMAC semantics)."""

    # loop closed, amplifier enabled
    ENABLED = 1 << 0
    # profile generator active
    MOVING = 1 << 1
    # command position equals the target position (never for velocity moves)
    AT_TARGET = 1 << 2
    # |target - actual| <= coarse_position_tolerance
    IN_COARSE_POSITION = 1 << 3
    # settled: |error| <= fine tolerance and |velocity| <= velocity tolerance, both held for
    # settling_time (RMP SETTLED)
    IN_FINE_POSITION = 1 << 4
    # position move settled, or STOP / ESTOP / ABORT finished
    MOTION_DONE = 1 << 5
    # velocity move within velocity_tolerance of its target for settling_time
    MOTION_AT_VELOCITY = 1 << 6
    # |following error| > following_error_warning
    FOLLOWING_ERROR_WARNING = 1 << 7
    # |following error| > following_error_fatal: loop opened, needs reset
    FOLLOWING_ERROR_FATAL = 1 << 8
    # output at output_limit
    OUTPUT_SATURATED = 1 << 9
    # integrator input off (integration mode, anti-hunting, saturation)
    INTEGRATOR_HELD = 1 << 10
    # backlash compensation register non-zero or ramping
    BACKLASH_ACTIVE = 1 << 11
    # encoder data stale (older than feedback_timeout) or invalid: loop opened
    FEEDBACK_FAULT = 1 << 12
    # a STOP finished
    STOPPED = 1 << 13
    # an ESTOP finished
    ESTOPPED = 1 << 14
    # ABORT done
    ABORTED = 1 << 15
    # a target outside the soft limits was refused
    LIMIT = 1 << 16
    # sampled dual-loop correction in progress
    CORRECTING = 1 << 17
    # measured velocity of the motor or the slide beyond overspeed_velocity (a drive's overspeed
    # fault): loop opened, output 0, needs reset. Added after SPEC's table (bits 0-17 unchanged).
    OVERSPEED = 1 << 18
