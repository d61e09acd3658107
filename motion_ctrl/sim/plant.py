"""Physics of the Galil manual's "backlash slide" (DMC-40x0 manual, sampled dual loop example).

A rotary servo motor in a torque-mode amplifier drives a lead screw; the nut drives a slide
through a backlash gap with finite contact stiffness. A rotary encoder is on the motor, a linear
encoder on the slide. Modelled:

* amplifier: input clipped at ±amplifier_limit V, current = amplifier_gain·V, torque = Kt·i;
  a command watchdog (`command` / `advance`) puts the output to 0 V and closes the dynamic
  brake when no command came for `command_timeout`;
* motor side: rotor + screw inertia, viscous + Coulomb friction with stiction (Karnopp);
* lead screw: lead, and a pitch error e(x) (cumulative slope + periodic term) that displaces the
  nut from the ideal screw position, so a leadscrew table has something real to correct;
* backlash: gap `backlash` between the nut and the slide flanks; in contact the coupling is a
  spring-damper (`screw_stiffness`, `screw_damping`) — with the two masses this is the
  mechanical resonance (~240 Hz by default); out of contact no force passes;
* slide: mass, viscous + Coulomb friction with stiction, end stops (stiff walls), a brake;
* encoders quantised to counts (floor, as a quadrature counter reads between edges).

Everything is in load-equivalent linear coordinates internally: the motor position x_m is the
screw's rotation times lead/2π, its equivalent mass J·(2π/lead)². At start-up both encoders read
0 and the nut bears on the flank that drives the slide positive (doc/interface.md), so a
positive move shows no backlash error and a negative move after it shows the whole gap.

Integration: semi-implicit (symplectic) Euler at `substep_rate` (20 kHz by default, ωT ≈ 0.06 at
the resonance), which is stable for the contact spring and conserves energy well. The substeps
of one step are `_substeps`, a function of floats: it stops early once both masses are stuck and
held (the rest would change nothing), and its floats are those of running every substep
(test_plant_kernel.py).
"""
from __future__ import annotations

import math
from typing import Final

from motion_ctrl.core.registers import (PLANT_AXIS, PLANT_PARAMETERS, axis_defaults,
                                        plant_consistency)

TWO_PI: Final = 2.0 * math.pi
# Sticking window of the Karnopp friction model: below this speed a mass may stick.
_STICK_SPEED: Final = 1e-7
# End stops: a stiff, well damped wall.
_WALL_STIFFNESS: Final = 1e8
_WALL_DAMPING: Final = 2e4


def _substeps(n: int, h: float, x_m: float, v_m: float, x_l: float, v_l: float, pitch: float,
              drive: float, m_visc: float, mm: float, m_coul: float, m_stic: float, ml: float,
              l_visc: float, l_coul: float, l_stic: float, k: float, c: float, b: float,
              travel_min: float, travel_max: float,
              brake: bool) -> tuple[float, float, float, float]:
    """n semi-implicit Euler substeps of h: the new (x_m, v_m, x_l, v_l).

    Each mass gets one Karnopp friction step (written out twice below, for speed: this loop is
    most of what a simulated servo tick costs): with force F (all but friction) on a mass at
    rest, it stays stuck while |F| <= stiction, else breaks away against Coulomb friction;
    moving, viscous + Coulomb friction act, and a step that would reverse the velocity (or
    leave it below _STICK_SPEED with |F| <= stiction) stops it. `±coulomb by the sign of v` is
    math.copysign(coulomb, v) for every v that reaches it (v, F ≠ 0 there).

    A substep that starts and ends with both masses stuck (the slide stuck or braked) changes
    nothing, so every later substep of the step would repeat it exactly: the loop stops there.
    The result is the same, bit for bit, as running all n.
    """
    for _ in range(n):
        # Contact force nut -> slide (positive pushes the slide positive).
        d = x_m + pitch - x_l
        dv = v_m - v_l        # pitch-error slope is tiny: its velocity term is neglected
        if d > 0.0:
            fc = k * d + c * dv
            if not fc > 0.0:
                fc = 0.0      # the spring-damper only pushes
        elif d < -b:
            fc = k * (d + b) + c * dv
            if not fc < 0.0:
                fc = 0.0
        else:
            fc = 0.0          # in the gap
        # Motor: Karnopp friction step with force F = drive - fc.
        f_m = drive - fc
        if v_m == 0.0:
            if -m_stic <= f_m <= m_stic:
                vm_new = 0.0  # stays stuck: static friction balances the force
            else:
                vm_new = (f_m - (m_coul if f_m > 0.0 else -m_coul)) / mm * h
        else:
            vm_new = v_m + (f_m - m_visc * v_m - (m_coul if v_m > 0.0 else -m_coul)) / mm * h
            if vm_new * v_m < 0.0 or -_STICK_SPEED < vm_new < _STICK_SPEED \
                    and -m_stic <= f_m <= m_stic:
                vm_new = 0.0  # friction would reverse it: it stops (and may stick)
        # Slide: braked, or a Karnopp step with F = contact + end stop (a stiff damped wall).
        if brake:
            f_l = fc
            vl_new = 0.0
        else:
            if x_l > travel_max:
                f_l = fc + (-_WALL_STIFFNESS * (x_l - travel_max) - _WALL_DAMPING * v_l)
            elif x_l < travel_min:
                f_l = fc + (-_WALL_STIFFNESS * (x_l - travel_min) - _WALL_DAMPING * v_l)
            else:
                f_l = fc
            if v_l == 0.0:
                if -l_stic <= f_l <= l_stic:
                    vl_new = 0.0
                else:
                    vl_new = (f_l - (l_coul if f_l > 0.0 else -l_coul)) / ml * h
            else:
                vl_new = v_l + (f_l - l_visc * v_l - (l_coul if v_l > 0.0 else -l_coul)) / ml * h
                if vl_new * v_l < 0.0 or -_STICK_SPEED < vl_new < _STICK_SPEED \
                        and -l_stic <= f_l <= l_stic:
                    vl_new = 0.0
        if v_m == 0.0 and v_l == 0.0 and vm_new == 0.0 and vl_new == 0.0 \
                and -m_stic <= f_m <= m_stic and (brake or -l_stic <= f_l <= l_stic):
            # Both stuck from start to end: this substep only turns a -0.0 position into 0.0
            # (x + 0.0), and every later one would find the same forces and do nothing.
            return x_m + 0.0, 0.0, x_l + 0.0, 0.0
        v_m, v_l = vm_new, vl_new
        x_m = x_m + v_m * h
        x_l = x_l + v_l * h
    return x_m, v_m, x_l, v_l


class SlidePlant:
    """One axis of the backlash slide. `step(volts, dt)` advances the physics by dt seconds.

    Parameters
    ----------
    substep_rate : float
        The integration rate [Hz]: a step of dt is ceil(dt · substep_rate) Euler substeps.
    **params
        Plant registers over the table's defaults (core.registers PLANT_PARAMETERS, SI units);
        validated as `configure` does (ValueError).
    """

    # (substep_rate unannotated: mypyc 2.4 fails on an annotated default before **params)
    def __init__(self, substep_rate=20000.0, **params) -> None:
        self.substep_rate: float = substep_rate
        self._step_dt = self._step_rate = math.nan   # dt and substep_rate of the last step,
        self._sub_n = 1                              # and its substeps: count and length
        self._sub_h = 0.0
        self.params = axis_defaults(PLANT_PARAMETERS)
        self.configure(**params)
        self.x_m = self.v_m = 0.0     # motor side, load-equivalent [m, m/s]
        self.x_l = self.v_l = 0.0     # slide [m, m/s]
        self.time = 0.0
        self.volts = 0.0              # last applied (clipped) amplifier input
        # The amplifier's command watchdog: no command yet counts as one that timed out.
        self.commanded = 0.0          # last command received [V]
        self.command_age = math.inf   # plant time since it came [s]
        self.tripped = True           # output held at 0 V by the watchdog in the last cycle

    def configure(self, **changes) -> None:
        """Change parameters (validated together; nothing changes if one is refused).

        Parameters
        ----------
        **changes
            {plant register: value}, SI units (PLANT_PARAMETERS).

        Raises
        ------
        ValueError
            An unknown register, a value its row refuses, or the rules among them.
        """
        new = dict(self.params)
        for name, value in changes.items():
            if name not in PLANT_AXIS:
                raise ValueError(f'unknown plant parameter {name!r}')
            reason = PLANT_AXIS[name].check(value)
            if reason:
                raise ValueError(reason)
            new[name] = value
        reasons = plant_consistency(new)
        if reasons:
            raise ValueError('; '.join(reasons))
        self.params = new
        p = new
        self._rad_per_m: float = TWO_PI / p['lead']
        self.motor_mass: float = p['motor_inertia'] * self._rad_per_m ** 2
        self._force_per_volt: float = (p['amplifier_gain'] * p['torque_constant']
                                       * self._rad_per_m)
        # Rotary friction reflected to the linear coordinate.
        self._m_visc: float = p['motor_viscous'] * self._rad_per_m ** 2
        self._m_visc_braked: float = self._m_visc + p['dynamic_brake'] * self._rad_per_m ** 2
        self._m_coul: float = p['motor_coulomb'] * self._rad_per_m
        self._m_stic: float = p['motor_stiction'] * self._rad_per_m
        self._command_timeout: float = p['command_timeout']
        self.motor_counts_per_m: float = p['motor_counts_per_rev'] / p['lead']
        self.load_counts_per_m: float = 1.0 / p['load_resolution']
        # What a step reads, looked up once here (params change only through configure), as
        # typed floats: compiled (setup.py), step passes them to _substeps as native doubles.
        self._pitch_slope: float = p['pitch_error_slope']
        self._pitch_amplitude: float = p['pitch_error_amplitude']
        self._pitch_period: float = p['pitch_error_period']
        self._limit: float = p['amplifier_limit']
        self._slide_mass: float = p['slide_mass']
        self._l_visc: float = p['slide_viscous']
        self._l_coul: float = p['slide_coulomb']
        self._l_stic: float = p['slide_stiction']
        self._k: float = p['screw_stiffness']
        self._c: float = p['screw_damping']
        self._backlash: float = p['backlash']
        self._travel_min: float = p['travel_min']
        self._travel_max: float = p['travel_max']
        self._brake: bool = p['brake'] == 1

    # -- derived quantities -------------------------------------------------------------------
    def pitch_error(self, x_m: float) -> float:
        """Displacement of the nut from the ideal screw position at motor position x_m [m]."""
        return self._pitch_slope * x_m + self._pitch_amplitude * math.sin(
            TWO_PI * x_m / self._pitch_period)

    @property
    def resonance_hz(self) -> float:
        """Two-mass resonance in contact: sqrt(k (1/Mm + 1/Ml)) / 2π."""
        p = self.params
        return math.sqrt(p['screw_stiffness'] * (1 / self.motor_mass + 1 / p['slide_mass'])) \
            / TWO_PI

    def gap(self) -> float:
        """Nut position relative to the slide's positive-drive flank: 0 in positive contact,
        −backlash in negative contact."""
        return self.x_m + self.pitch_error(self.x_m) - self.x_l

    def encoder_counts(self):
        """(motor counts, load counts), floored as a quadrature counter reads them.

        Returns
        -------
        tuple[int, int]
            The motor and linear encoders [counts].
        """
        return self.motor_count(), self.load_count()

    def motor_count(self) -> int:
        return math.floor(self.x_m * self.motor_counts_per_m + 1e-9)

    def load_count(self) -> int:
        return math.floor(self.x_l * self.load_counts_per_m + 1e-9)

    # -- the amplifier's command watchdog ------------------------------------------------------
    def command(self, volts: float) -> None:
        """A command arrived: held (zero-order) until the next one, and the watchdog re-armed.

        Parameters
        ----------
        volts : float
            The amplifier input [V] (clipped at ±amplifier_limit when applied; a non-finite
            one applies 0 V).
        """
        self.commanded = volts
        self.command_age = 0.0

    def disable(self) -> None:
        """The amplifier disabled by its controller (it stops): from the next cycle the output
        is 0 V and the dynamic brake closed, as after a watchdog trip, until a command comes."""
        self.commanded = 0.0
        self.command_age = math.inf

    def advance(self, dt: float, cycle: float | None = None) -> None:
        """One plant cycle of dt on the held command, through the amplifier's watchdog.

        The fieldbus / amplifier-fault rule of a servo drive (EtherCAT SyncManager watchdog,
        PMAC amplifier fault on a lost command): a drive whose command stream stopped must not
        go on driving the last value. Once `command_timeout` of plant time has passed without a
        command, the output is 0 V and the windings are shorted through the brake resistor
        (dynamic braking, as servo drives do when they disable) until a command comes again.
        Checked once per cycle, like a drive per fieldbus cycle, and a cycle that came late
        (longer than `cycle`, the nominal period, when given) counts as at most two: a plant
        held up by its machine must not cut the output of a live controller whose commands
        wait in its queue (the controller's feedback_timeout is counted the same way). Counted
        in plant time, so a lockstep run (a command every cycle) stays deterministic.

        Parameters
        ----------
        dt : float
            The cycle's length [s].
        cycle : float, optional
            The nominal cycle [s]: the watchdog counts at most two of them for a late one;
            None: dt as it is.
        """
        # (1 ns slack: five 1 ms cycles add up to 5 ms, not to a hair less)
        self.tripped = self.command_age >= self._command_timeout - 1e-9
        if self.tripped:
            self.step(0.0, dt, braking=True)
        else:
            self.step(self.commanded, dt)
        self.command_age += dt if cycle is None else min(dt, 2 * cycle)

    # -- integration --------------------------------------------------------------------------
    def step(self, volts: float, dt: float, braking: bool = False) -> None:
        """Advance the physics by dt with `volts` on the amplifier input (no watchdog);
        `braking`: the dynamic brake is closed.

        Parameters
        ----------
        volts : float
            The amplifier input [V], clipped at ±amplifier_limit; a non-finite one is 0 V.
        dt : float
            [s]; integrated in ceil(dt · substep_rate) substeps.
        braking : bool
            The windings shorted through the brake resistor (dynamic_brake).
        """
        lim = self._limit
        if not -lim <= volts <= lim:  # (a nan fails this test too)
            volts = 0.0 if not math.isfinite(volts) else lim if volts > 0.0 else -lim
        self.volts = volts            # a broken command never reaches the motor; others clipped
        if dt != self._step_dt or self.substep_rate != self._step_rate:
            n = max(1, math.ceil(dt * self.substep_rate - 1e-9))
            self._step_dt, self._step_rate = dt, self.substep_rate
            self._sub_n, self._sub_h = n, dt / n
        n, h = self._sub_n, self._sub_h
        x_m = self.x_m
        # The pitch error changes by nanometres within one step: evaluated once per step.
        pitch = self.pitch_error(x_m)
        self.x_m, self.v_m, self.x_l, self.v_l = _substeps(
            n, h, x_m, self.v_m, self.x_l, self.v_l, pitch, self._force_per_volt * volts,
            self._m_visc_braked if braking else self._m_visc, self.motor_mass, self._m_coul,
            self._m_stic, self._slide_mass, self._l_visc, self._l_coul, self._l_stic, self._k,
            self._c, self._backlash, self._travel_min, self._travel_max, self._brake)
        self.time += dt
