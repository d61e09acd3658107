"""The servo loop's I/O: what the loop reads and writes for each axis every servo tick, behind one
interface with a lifecycle, as ros2_control's hardware components (`SystemInterface`:
on_configure / on_activate / on_deactivate, `read()` and `write()` around the controllers'
`update()`), LinuxCNC's HAL pins read and written by the servo thread, and PMAC's servo interrupt
(read the encoders, compute, write the DACs) keep it.

Each axis has an `AxisIO`, shared by the backend and the loop (ros2_control's state and command
interfaces of a joint): its state, written by the backend, is the newest encoder sample (motor
counts, load counts, the sample's stamp [s]) and the drive's fault, if any; its command, written
by the loop's tick, is the output [V], whether the tick commanded the axis at all, and whether
the axis's loop is closed (the amplifier's enable, as PMAC's amplifier-enable output follows the
motor's loop: an ABORT or a fatal following error disables it). Each tick `ServoLoop.cycle`
runs, on the servo thread, `read(now)` (the backend brings the state up to date), the loop's tick,
and `write(now)` (the backend sends the commands). A backend whose samples arrive on their own
(a subscription, a fieldbus thread) may put them into the AxisIO as they come (`AxisIO.sample`).

Fault kinds, set on the AxisIO by the backend while the fault lasts, and the status the loop
gives them (the bits it has):

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

from typing import Final

import math

try:
    from mypy_extensions import mypyc_attr
except ImportError:      # built without mypy (plain Python): the mark only matters to mypyc
    def mypyc_attr(*attrs: str, **kwattrs: object):  # type: ignore[misc]
        return lambda cls: cls

LINK: Final = 'link'
DRIVE: Final = 'drive'
FAULT_KINDS: Final = (LINK, DRIVE)

UNCONFIGURED, INACTIVE, ACTIVE = 'unconfigured', 'inactive', 'active'

# s: an encoder stamp this much older than the sample in hand is a new clock, not a late copy
# (a copy through a bridge lags by milliseconds, at most its second of history).
CLOCK_RESTART: Final = 1.0


class HardwareError(Exception):
    """What a backend cannot do, in one line naming the device and the object."""


class AxisIO:
    """One axis's I/O, shared by the backend and the loop."""

    def __init__(self, name: str) -> None:
        self.name = name
        # State (the backend): the newest encoder sample (stamp nan: none yet), and the fault
        # of the drive or of the link while it lasts ('' : none).
        self.motor: int = 0
        self.load: int = 0
        self.stamp: float = math.nan
        self.fault_kind: str = ''
        self.fault_reason: str = ''
        # Command (the loop's tick): the output [V], whether this tick commanded the axis (it
        # has feedback and its loop ran), and whether its loop is closed.
        self.output: float = 0.0
        self.commanded: bool = False
        self.enabled: bool = False

    def sample(self, motor: int, load: int, stamp: float) -> None:
        """An encoder sample stamped `stamp` [s]. One not newer than the sample in hand is
        dropped: two paths to the loop (a plant's stream and a bridge's copy of it, a hop later)
        deliver a sample twice and out of order. A stamp more than CLOCK_RESTART older is a new
        clock (a restarted lockstep plant), taken.

        Parameters
        ----------
        motor, load : int
            The motor and load encoders [counts].
        stamp : float
            The time the drive sampled them [s], on the loop's clock.
        """
        held = self.stamp
        if held - CLOCK_RESTART < stamp <= held:          # (never with nothing held: nan)
            return
        self.motor = motor
        self.load = load
        self.stamp = stamp


@mypyc_attr(allow_interpreted_subclasses=True)     # (backends with ROS are not compiled)
class HardwareInterface:
    """One backend's I/O for the axes of a servo loop (`io`, one AxisIO per axis). Subclasses
    override the `on_*` steps of the lifecycle and `read` / `write`; the lifecycle's order is
    kept here.

    Parameters
    ----------
    axes : iterable of str
        The axes' names, in the servo loop's order; each gets an AxisIO in `io`.
    """

    #: the `hardware` parameter's value that selects the backend
    kind = ''

    def __init__(self, axes) -> None:
        self.axes: list[str] = list(axes)
        self.io: dict[str, AxisIO] = {a: AxisIO(a) for a in self.axes}
        self.state = UNCONFIGURED

    # -- lifecycle ----------------------------------------------------------------------------
    def configure(self) -> None:
        """Check and set up what the backend talks to (unconfigured -> inactive).

        Raises
        ------
        HardwareError
            One line naming the device and the object at fault; or not unconfigured.
        """
        if self.state != UNCONFIGURED:
            raise HardwareError(f'{self.kind}: configure in state {self.state}')
        self.on_configure()
        self.state = INACTIVE

    def activate(self) -> None:
        """Start the cyclic exchange (the first `read` may follow): configures first when
        unconfigured (its HardwareError passes), nothing when active already."""
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
        """The backend's configure step (`configure` calls it once); raise HardwareError."""
        pass

    def on_activate(self) -> None:
        """The backend's activate step: start the exchange (NMT start, subscriptions, ...)."""
        pass

    def on_deactivate(self) -> None:
        """The backend's deactivate step: every output 0 V, every amplifier disabled."""
        pass

    # -- the cycle ----------------------------------------------------------------------------
    def read(self, now: float) -> None:
        """Bring each AxisIO's state up to date: the newest sample, the faults.

        Parameters
        ----------
        now : float
            The servo cycle's time [s], on the loop's clock (ServoLoop.cycle's `now`).
        """
        raise NotImplementedError

    def write(self, now: float) -> None:
        """Send each commanded AxisIO's output; an amplifier follows `enabled` (a drive with
        an enable sequence runs it on a change; a torque-mode amplifier on 0 V needs none).

        Parameters
        ----------
        now : float
            The servo cycle's time [s], as `read`'s.
        """
        raise NotImplementedError

    def reset(self, axis: str) -> None:
        """`<axis>/reset`: clear what faulted the drive (a drive with a fault state resets it).

        Parameters
        ----------
        axis : str
            The axis whose drive is reset.
        """


class NoHardware(HardwareInterface):
    """Nothing behind the loop: samples come by `ServoLoop.feedback` from outside and the
    outputs go nowhere (a loop driven by hand, in tests)."""

    kind = 'none'

    def read(self, now: float) -> None:
        pass

    def write(self, now: float) -> None:
        pass
