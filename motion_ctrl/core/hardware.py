"""The servo loop's I/O: what the loop reads and writes for each axis every servo tick, behind one
interface with a lifecycle, as ros2_control's hardware components (`SystemInterface`:
on_configure / on_activate / on_deactivate, `read()` and `write()` around the controllers'
`update()`), LinuxCNC's HAL pins read and written by the servo thread, and PMAC's servo interrupt
(read the encoders, compute, write the DACs) keep it.

Each tick `ServoLoop.cycle` runs, on the servo thread:

1. `read(now, sink)`: per axis, the newest encoder sample (motor counts, load counts, the
   sample's stamp [s]) goes to `sink.feedback(axis, motor, load, stamp)`; a fault of the axis's
   drive or of the link to it goes to `sink.fault(axis, kind, reason)` on every read while it
   lasts;
2. the loop's tick (`ServoLoop.tick`);
3. `enable(axis, on)` for every axis whose loop opened or closed (the amplifier-enable output of
   a PMAC follows the motor's loop state: an ABORT or a fatal following error disables it);
4. `write(now, names, outputs)`: the output [V] of each axis the tick closed a loop for.

Fault kinds, and the status the loop gives them (the bits it has):

* `LINK`: the drive cannot be reached (a lost heartbeat, a dead link): FEEDBACK_FAULT at once,
  as stale encoder data would after feedback_timeout;
* `DRIVE`: the drive itself faulted (its own protection, an emergency message): the loop opens
  as on an ABORT (RMP's amplifier-fault action), ABORTED, and the axis refuses enable and motion
  with the drive's reason until `<axis>/reset`, which also resets the drive (`reset(axis)`).

The lifecycle (ros2_control's states): unconfigured --configure--> inactive --activate-->
active --deactivate--> inactive. `configure` checks what it talks to and raises HardwareError
with one line naming what is wrong (the node then exits 2); `deactivate` leaves every output at
0 V and every amplifier disabled: the controller calls it before it exits.

The backends: `topics` (motion_ctrl.ros.hardware_topics: the plant node, or any drive bridge,
over the `command` / `encoders` topics) and `sim` (motion_ctrl.sim.hardware: the slide's physics
stepped inside the loop).
"""
from __future__ import annotations

from typing import Protocol

try:
    from mypy_extensions import mypyc_attr
except ImportError:      # built without mypy (plain Python): the mark only matters to mypyc
    def mypyc_attr(*attrs: str, **kwattrs: object):  # type: ignore[misc]
        return lambda cls: cls

LINK = 'link'
DRIVE = 'drive'
FAULT_KINDS = (LINK, DRIVE)

UNCONFIGURED, INACTIVE, ACTIVE = 'unconfigured', 'inactive', 'active'


class HardwareError(Exception):
    """What a backend cannot do, in one line naming the device and the object."""


class FeedbackSink(Protocol):
    """What `read` hands its samples and faults to (ServoLoop)."""

    def feedback(self, axis: str, motor: int, load: int, stamp: float) -> None: ...

    def fault(self, axis: str, kind: str, reason: str) -> None: ...


@mypyc_attr(allow_interpreted_subclasses=True)     # (backends with ROS are not compiled)
class HardwareInterface:
    """One backend's I/O for the axes of a servo loop. Subclasses override the `on_*` steps of
    the lifecycle and `read` / `write`; the lifecycle's order is kept here."""

    #: the `hardware` parameter's value that selects the backend
    kind = ''

    def __init__(self, axes) -> None:
        self.axes: list[str] = list(axes)
        self.state = UNCONFIGURED

    # -- lifecycle ----------------------------------------------------------------------------
    def configure(self) -> None:
        """Check and set up what the backend talks to; raises HardwareError."""
        if self.state != UNCONFIGURED:
            raise HardwareError(f'{self.kind}: configure in state {self.state}')
        self.on_configure()
        self.state = INACTIVE

    def activate(self) -> None:
        """Start the cyclic exchange (the first `read` may follow)."""
        if self.state == UNCONFIGURED:
            self.configure()
        if self.state == INACTIVE:
            self.on_activate()
            self.state = ACTIVE

    def deactivate(self) -> None:
        """Every output 0 V and every amplifier disabled; safe to call in any state, twice."""
        if self.state == ACTIVE:
            self.state = INACTIVE
            self.on_deactivate()

    def on_configure(self) -> None:
        pass

    def on_activate(self) -> None:
        pass

    def on_deactivate(self) -> None:
        pass

    # -- the cycle ----------------------------------------------------------------------------
    def read(self, now: float, sink: FeedbackSink) -> None:
        """The newest samples and the faults of the axes, handed to `sink`."""
        raise NotImplementedError

    def write(self, now: float, names: list[str], outputs: list[float]) -> None:
        """The tick's outputs [V], one per name (the axes whose loops the tick ran)."""
        raise NotImplementedError

    def enable(self, axis: str, on: bool) -> None:
        """The axis's loop closed (on) or opened: the amplifier follows (a drive that has an
        enable sequence runs it here; a torque-mode amplifier on a 0 V command needs none)."""

    def reset(self, axis: str) -> None:
        """`<axis>/reset`: clear what faulted the drive (a drive with a fault state resets it)."""


class NoHardware(HardwareInterface):
    """Nothing behind the loop: samples come to it by `ServoLoop.feedback` from outside and the
    outputs go nowhere (a loop driven by hand, in tests)."""

    kind = 'none'

    def read(self, now: float, sink: FeedbackSink) -> None:
        pass

    def write(self, now: float, names: list[str], outputs: list[float]) -> None:
        pass
