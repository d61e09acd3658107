"""Typed configuration: what each core object reads of the register table, made once per
register set and validated by the table's one path (`registers.refusals`).

Field names are register names; no field has a default (the table's is the only one), and
derived fields are computed once here, so that a servo tick compares no strings and looks up no
keys. Compiled by mypyc with the servo tick's modules (setup.py): the tick reads these fields as
native floats.
"""
from __future__ import annotations

from dataclasses import dataclass, field, fields
from typing import Final, TypeVar

from motion_ctrl.core.registers import AXIS_REGISTERS, axis_defaults, refusals

_C = TypeVar('_C', bound='Config')
# A field computed from the registers (Config.derive), not one of them. (Not __post_init__ with
# object.__setattr__: compiled by mypyc 2.4, that failed on LawConfig's bool fields.)
DERIVED = {'derived': True}


def register_fields(cls) -> list[str]:
    """The fields of configuration `cls` that are registers (the others are DERIVED)."""
    return [f.name for f in fields(cls) if not f.metadata]


def _of(cls, values: dict, checked: bool = False):
    """`cls` from the registers among `values` that it reads, refused (ValueError naming them)
    by the table's one validation: each value by its row, then the rules among them. `checked`:
    the whole set was validated already (Axis.configure), so it is not done again."""
    picked = {name: values[name] for name in register_fields(cls)}
    reasons = [] if checked else refusals(picked)
    if reasons:
        raise ValueError('; '.join(reasons))
    picked = {k: tuple(v) if isinstance(v, list) else v for k, v in picked.items()}
    return cls(**picked, **cls.derive(picked))


class Config:
    """A consumer's registers, read-only. `of(values)` makes one from a dict of register values
    (extra keys ignored), refused with the table's reasons (ValueError) when one is bad."""
    __slots__ = ()

    @classmethod
    def of(cls: type[_C], values: dict) -> _C:
        """This configuration from a register set, validated by the table (`refusals`).

        Parameters
        ----------
        values : dict
            {register: value}, SI units as in core.registers; every register this class reads
            must be there (KeyError otherwise), others are ignored.

        Returns
        -------
        Config
            An instance of the class it is called on, derived fields computed.

        Raises
        ------
        ValueError
            The table's refusals of those registers, joined by '; '.
        """
        return _of(cls, values)

    @staticmethod
    def derive(values: dict) -> dict:
        """The derived fields (marked DERIVED) from the registers'."""
        return {}

    @classmethod
    def of_checked(cls: type[_C], values: dict) -> _C:
        """`of` for a set that `refusals` has accepted already (no validation again).

        Parameters
        ----------
        values : dict
            {register: value}, accepted by `refusals` as a whole.

        Returns
        -------
        Config
            An instance of the class it is called on.
        """
        return _of(cls, values, checked=True)


@dataclass(frozen=True, slots=True)
class LawConfig(Config):
    """The servo law's registers (PMAC Ixx29..39, 63, 67..69; RMC deadband), and the feedback
    (Galil DV), which says whose position error the law sees."""
    mode: str
    feedback: str
    kp: float
    ki: float
    kd: float
    kvff: float
    kaff: float
    friction_ff: float
    friction_ff_at_rest: float
    bias: float
    integration_mode: str
    integration_limit: float
    output_limit: float
    output_deadband: float
    deadband_tolerance: float
    position_error_limit: float
    notch_n1: float
    notch_n2: float
    notch_d1: float
    notch_d2: float
    position_mode: bool = field(metadata=DERIVED)       # mode position_* (else velocity_*)
    pid: bool = field(metadata=DERIVED)                 # mode *_pid (else *_ipd)
    integrate_at_rest: bool = field(metadata=DERIVED)   # integration_mode at_rest (Ixx34 = 1)
    # friction_ff_at_rest where the position loop reads the slide's (load) encoder, else 0: the
    # motor's error says nothing of a slide that stiction holds, and a motor free inside the
    # backlash gap, pushed by it, hunts.
    breakaway: float = field(metadata=DERIVED)

    @staticmethod
    def derive(values: dict) -> dict:
        # (here: circular, core.dual_loop imports core.config for CorrectionConfig, defaults)
        from motion_ctrl.core.dual_loop import feedback_encoders
        mode = values['mode']
        on_load = feedback_encoders(values['feedback'])[0] == 'load'
        return {'position_mode': mode.startswith('position'), 'pid': mode.endswith('pid'),
                'integrate_at_rest': values['integration_mode'] == 'at_rest',
                'breakaway': values['friction_ff_at_rest'] if on_load else 0.0}

    @property
    def notch(self) -> tuple[float, float, float, float]:
        return (self.notch_n1, self.notch_n2, self.notch_d1, self.notch_d2)


@dataclass(frozen=True, slots=True)
class SettlingConfig(Config):
    """The settling criteria (RMP PositionToleranceFine/Coarse, VelocityTolerance,
    SettlingTime)."""
    fine_position_tolerance: float
    coarse_position_tolerance: float
    velocity_tolerance: float
    settling_time: float


@dataclass(frozen=True, slots=True)
class CorrectionConfig(Config):
    """Galil's sampled dual loop: when the correction moves end."""
    correction_tolerance: float
    correction_max_moves: int
    correction_acceleration: float
    load_counts_per_m: float
    settling_time: float
    coarse_position_tolerance: float
    window_centre: str


@dataclass(frozen=True, slots=True)
class ProfileConfig(Config):
    """The move generator's limits and smoothing (Galil SP / AC / DC / IT, PMAC Ixx16..21)."""
    max_velocity: float
    max_acceleration: float
    max_jerk: float
    smoothing: float


@dataclass(frozen=True, slots=True)
class BacklashConfig(Config):
    """Backlash and leadscrew compensation (PMAC Ixx85..87, DEFINE BLCOMP, DEFINE COMP)."""
    backlash_distance: float
    backlash_takeup_rate: float
    backlash_hysteresis: float
    backlash_table: tuple
    backlash_table_spacing: float
    leadscrew_table: tuple
    leadscrew_table_spacing: float


#: overspeed_velocity 0: the trip is this many times max_velocity.
OVERSPEED_RATIO: Final = 1.5


@dataclass(frozen=True, slots=True)
class AxisConfig(Config):
    """The axis's own registers, read by its servo tick and its commands (core.axis,
    core.commands): the encoders and the feedback the loop closes on (Galil DV, PMAC Ixx03 /
    Ixx04), the following-error limits (PMAC Ixx11 / Ixx12), the soft limits, the limits a
    command is checked and braked with (Galil SP / AC, RMP stop and e-stop decelerations), the
    overspeed trip (a drive's VOSPD), the at-rest windows' centre and the hunting watch. The
    profile, settling, compensation, correction and law read theirs (the configurations
    above)."""
    feedback: str
    motor_counts_per_m: float
    load_counts_per_m: float
    window_centre: str
    following_error_fatal: float
    following_error_warning: float
    soft_limit_min: float
    soft_limit_max: float
    max_velocity: float
    max_acceleration: float
    max_jerk: float
    stop_deceleration: float
    estop_deceleration: float
    overspeed_velocity: float
    hunting_reversals: int
    # the position loop on the motor encoder (feedback motor, sampled): compensation there
    motor_side: bool = field(metadata=DERIVED)
    velocity_on_load: bool = field(metadata=DERIVED)      # feedback load: kd on the slide
    sampled: bool = field(metadata=DERIVED)               # Galil's sampled dual loop
    loop_counts_per_m: float = field(metadata=DERIVED)    # of the position loop's encoder
    # RMC: anti-hunting below half a raw count. Inclusive (by a hair): a target halfway between
    # two counts can be held from either, so the integrator must stop there too.
    half_count: float = field(metadata=DERIVED)
    # window_centre count_middle: the at-rest windows judge the position as the middle of the
    # count the encoder reads (a quadrature counter reads its lower edge).
    window_shift: float = field(metadata=DERIVED)
    overspeed: float = field(metadata=DERIVED)            # the trip, m/s (0: the ratio's)

    @staticmethod
    def derive(values: dict) -> dict:
        # (here: circular, core.dual_loop imports core.config for CorrectionConfig, defaults)
        from motion_ctrl.core.dual_loop import feedback_encoders
        feedback = values['feedback']
        motor_side = feedback_encoders(feedback)[0] == 'motor'
        cpm = values['motor_counts_per_m' if motor_side else 'load_counts_per_m']
        return {'motor_side': motor_side, 'velocity_on_load': feedback == 'load',
                'sampled': feedback == 'sampled', 'loop_counts_per_m': cpm,
                'half_count': 0.5 * (1 + 1e-6) / cpm,
                'window_shift': 0.5 / cpm if values['window_centre'] == 'count_middle' else 0.0,
                'overspeed': values['overspeed_velocity']
                or OVERSPEED_RATIO * values['max_velocity']}


def defaults(cls: type[_C]) -> _C:
    """`cls` (a configuration above) with the table's defaults."""
    return cls.of(axis_defaults(AXIS_REGISTERS))
