"""The register table: every parameter of the controller and the plant, once.

Each row names the register, its ROS type, default, unit, range, the vendor register it mirrors
and what it does. This table alone drives parameter declaration and descriptors in the nodes,
validation (range, type, choices, cross-register rules), the YAML files in params/ and the
register tables of the documentation, doc/parameters.md and doc/canopen.md
(`python -m motion_ctrl.core.registers --markdown`).

Controller registers are per axis (`<axis>.<name>`); the defaults fit the default plant, the
Galil manual's backlash slide (1 in = 40,000 motor counts = 10,000 linear counts).
"""
from __future__ import annotations

import math
import pathlib
from dataclasses import dataclass

from motion_ctrl.core.notch import Biquad


INCH = 0.0254
MOTOR_COUNTS_PER_M = 40000 / INCH     # 8,000 counts/rev on a 5.08 mm lead
LOAD_COUNTS_PER_M = 10000 / INCH      # 2.54 um linear encoder

# Input budgets of a register value (doc/input_limits.md): a larger value is refused by its size
# before any per-entry work, and the refusal quotes the size, never the value. A table of 4096
# entries is 1 m of travel at 0.25 mm spacing (an ISO 230-2 test measures a few dozen targets);
# a string of 4096 characters holds a file path (Linux PATH_MAX). With the node's registers a
# fixed set, they bound a whole `ros2 param load` as well.
MAX_TABLE_ENTRIES = 4096
MAX_STRING_CHARS = 4096
SHOWN_CHARS = 80          # a refusal quotes a value up to this long, else its size


def shown(value) -> str:
    """`value` as a refusal quotes it: its repr when short, else what it is and its size."""
    text = repr(value) if not (hasattr(value, '__len__') and len(value) > SHOWN_CHARS) else ''
    if text and len(text) <= SHOWN_CHARS:
        return text
    if isinstance(value, (str, bytes)):
        return f'a {len(value)}-character {type(value).__name__}'
    if hasattr(value, '__len__'):
        return f'a {len(value)}-entry {type(value).__name__}'
    return f'a {type(value).__name__}'


def size_refusal(name: str, value) -> str | None:
    """Why `value` is too large for a register, by its size alone (MAX_TABLE_ENTRIES,
    MAX_STRING_CHARS), or None."""
    if isinstance(value, str):
        if len(value) > MAX_STRING_CHARS:
            return f'{name}: a {len(value)}-character string (at most {MAX_STRING_CHARS})'
        return None
    if _is_array(value):
        if len(value) > MAX_TABLE_ENTRIES:
            return f'{name}: {len(value)} entries (at most {MAX_TABLE_ENTRIES})'
        for i, v in enumerate(value):
            if isinstance(v, str) and len(v) > MAX_STRING_CHARS:
                return (f'{name}[{i}]: a {len(v)}-character string (at most '
                        f'{MAX_STRING_CHARS})')
    return None


@dataclass(frozen=True)
class Register:
    name: str
    type: str            # 'double' | 'integer' | 'string' | 'double_array' | 'string_array'
    default: object
    unit: str
    description: str
    vendor: str = ''
    min: float | None = None
    max: float | None = None
    choices: tuple = ()
    read_only: bool = False
    min_exclusive: bool = False   # range is (min, max] rather than [min, max]

    def descriptor_text(self) -> str:
        """Description shown by `ros2 param describe`: meaning, unit, vendor register, range."""
        parts = [self.description]
        if self.unit:
            parts.append(f'Unit: {self.unit}.')
        if self.vendor:
            parts.append(f'Mirrors: {self.vendor}.')
        if self.choices:
            parts.append('One of: ' + ', '.join(self.choices) + '.')
        if self.min is not None or self.max is not None:
            lo = '-inf' if self.min is None else f'{self.min:g}'
            hi = 'inf' if self.max is None else f'{self.max:g}'
            parts.append(f'Range: {"(" if self.min_exclusive else "["}{lo}, {hi}].')
        return ' '.join(parts)

    def check(self, value) -> str | None:
        """Why `value` is refused for this register, or None when it is acceptable. A value
        over the input budgets is refused by its size first (`size_refusal`); a refusal quotes
        a value only when it is short (`shown`)."""
        n = self.name
        size = size_refusal(n, value)
        if size:
            return size
        if self.type == 'double':
            if not isinstance(value, float):      # strict, as ROS is: 2 is not 2.0
                return f'{n}: expected a floating-point number, got {shown(value)}'
            return self._check_number(float(value))
        if self.type == 'integer':
            if isinstance(value, bool) or not isinstance(value, int):
                return f'{n}: expected an integer, got {shown(value)}'
            return self._check_number(value)
        if self.type == 'string':
            if not isinstance(value, str):
                return f'{n}: expected a string, got {shown(value)}'
            if self.choices and value not in self.choices:
                return (f'{n}: unknown value {shown(value)}, expected one of '
                        f'{", ".join(self.choices)}')
            return None
        if self.type == 'double_array':
            try:
                items = [float(v) for v in value]
            except (TypeError, ValueError):
                return f'{n}: expected a list of numbers, got {shown(value)}'
            for i, v in enumerate(items):
                reason = self._check_number(v)
                if reason:
                    return reason.replace(f'{n}:', f'{n}[{i}]:', 1)
            return None
        if self.type == 'string_array':
            if isinstance(value, str) or not all(isinstance(v, str) for v in value):
                return f'{n}: expected a list of strings, got {shown(value)}'
            return None
        raise AssertionError(self.type)

    def as_declared(self, value):
        """`value` as this register's type when it is a spelling that ROS tooling delivers with
        another type, else `value` unchanged (and then refused by type as usual). One rule for
        every register, by its declared type:

        * an empty array of any element type for an array register: YAML `[]` has no element
          type (rclpy types it as a bool array);
        * for a double, text spelled as a float; for a double array, items or a flow-list text
          spelled as floats: rclpy's YAML file loader (`ros2 param load`) reads `1.0e-06` back
          as the string '1e-06', so a dumped value returns as text.

        Integer spellings stay refused for doubles (`2` is not `2.0`), as ROS types are strict.
        A value over the input budgets is left as it is (refused by its size in `check`).
        """
        if size_refusal(self.name, value):
            return value
        if self.type in ('double_array', 'string_array') and _is_array(value) and not value:
            return []
        if self.type == 'double' and isinstance(value, str):
            number = _float_text(value)
            return value if number is None else number
        if self.type == 'double_array' and (isinstance(value, str) or _is_array(value)):
            items = value
            if isinstance(value, str):
                text = value.strip()
                if not (text.startswith('[') and text.endswith(']')):
                    return value
                items = text[1:-1].split(',') if text[1:-1].strip() else []
            if not all(isinstance(v, str) for v in items):
                return value
            numbers = [_float_text(v) for v in items]
            return value if None in numbers else numbers
        return value

    def _check_number(self, v) -> str | None:
        n = self.name
        if not math.isfinite(v):
            return f'{n}: {v} is not a finite number'
        if self.min is not None and (v < self.min or (self.min_exclusive and v == self.min)):
            op = '>' if self.min_exclusive else '>='
            return f'{n}: {v:g} {self.unit} is out of range, must be {op} {self.min:g}'
        if self.max is not None and v > self.max:
            return f'{n}: {v:g} {self.unit} is out of range, must be <= {self.max:g}'
        return None


def _is_array(value) -> bool:
    return not isinstance(value, (str, bytes)) and hasattr(value, '__len__')


def _float_text(text: str) -> float | None:
    """The float that `text` spells with a '.' or an exponent ('1e-06', '2.5'), else None."""
    text = text.strip()
    if not any(c in text for c in '.eE'):
        return None
    try:
        return float(text)
    except ValueError:
        return None


def _r(*args, **kw) -> Register:
    return Register(*args, **kw)


# Both nodes: the scheduling of the servo process (ros_env.realtime applies it).
REALTIME_PRIORITY = _r(
    'realtime_priority', 'integer', 0, '',
    'SCHED_FIFO priority of every thread of the node (the servo loop and its DDS threads); 0: '
    'normal scheduling. At normal priority CPU load, and ROS tools joining the graph (a Fast DDS '
    'shared-memory health check, eProsima/Fast-DDS#6535), now and then hold the servo streams '
    'for 333 ms, past feedback_timeout; 30 removed that in the measurements (doc/design_notes.md). '
    'Needs CAP_SYS_NICE or an rtprio limit (ulimit -r); without it the node warns and runs at '
    'normal priority.',
    'LinuxCNC servo-thread, PMAC real-time interrupt', min=0, max=98, read_only=True)

# Controller-wide parameters (not per axis).
CONTROLLER_GLOBALS = (
    _r('axes', 'string_array', ['x'], '', 'Names of the axes this controller runs.',
       read_only=True),
    _r('servo_rate', 'double', 1000.0, 'Hz', 'Servo loop rate.', 'PMAC servo clock, Galil TM',
       min=10.0, max=20000.0, read_only=True),
    _r('feedback_timeout', 'double', 0.02, 's',
       'Encoder data older than this opens the loop (FEEDBACK_FAULT).', min=0.0,
       min_exclusive=True, max=10.0),
    REALTIME_PRIORITY,
    _r('hardware', 'string', 'topics', '', "Where the servo loop's I/O goes (read each tick: "
       'the encoders; written: the outputs). topics: a plant node (or any drive bridge) over '
       'the command / encoders topics. sim: the backlash slide simulated inside this loop, one '
       'per axis, set by the plant registers on this node (<axis>.slide_mass, ..., and '
       'substep_rate; a params file\'s plant: section counts too); it publishes plant_states, '
       'amplifier_states and <axis>/amplifier_fault as the plant node does, and with '
       'use_sim_time it is the clock: it runs up to sim_speed times real time and publishes '
       '/clock. canopen: CiA 402 drives in cyclic synchronous torque mode on one CAN bus '
       '(can_interface, can_channel, can_bitrate; per axis can_node_id, load_encoder_node_id, '
       'eds, torque_per_volt; doc/canopen.md); this node is the SYNC producer.',
       'ros2_control hardware component, LinuxCNC HAL, PMAC servo interrupt',
       choices=('topics', 'sim', 'canopen'), read_only=True),
    _r('sim_speed', 'double', 4.0, '', 'With hardware sim and use_sim_time (this node the '
       'clock): sim seconds per wall second at most; 0: as fast as the machine allows (about '
       '20x real time for one axis here). A tool reading the streams keeps up at 4; faster, its '
       'readings of a move lag the move and its targets land at times set by its own lag.',
       'Gazebo real_time_factor', min=0.0, max=1000.0),
    # follow_joint_trajectory and controller_state (motion_ctrl.ros.follow_action)
    _r('action_monitor_rate', 'double', 20.0, 'Hz', 'Rate of the follow_joint_trajectory '
       'feedback (desired, actual and error of the running goal\'s axes).',
       'joint_trajectory_controller action_monitor_rate', min=0.0, min_exclusive=True,
       max=1000.0, read_only=True),
    _r('state_publish_rate', 'double', 50.0, 'Hz', 'Rate of <node>/controller_state '
       '(control_msgs/JointTrajectoryControllerState of every axis); 0: not published.',
       'joint_trajectory_controller state_publish_rate (Humble)', min=0.0, max=1000.0,
       read_only=True),
)

MODES = ('position_pid', 'position_ipd', 'velocity_pid', 'velocity_ipd')
FEEDBACKS = ('motor', 'load', 'dual', 'sampled')

# Per-axis servo registers. Gains are SI: the output is volts to a torque-mode amplifier.
AXIS_REGISTERS = (
    _r('mode', 'string', 'position_pid', '', 'Control mode. Velocity modes act on velocity error '
       '(kp V·s/m, ki V/m, kd V·s²/m).', 'RMC control modes', choices=MODES),
    _r('feedback', 'string', 'dual', '', 'Position feedback: motor encoder, load encoder, dual '
       '(KP/KI on load, KD on motor) or sampled (motor loop + correction moves on the load '
       'encoder at the end of each move).', 'Galil DV, PMAC Ixx03/Ixx04', choices=FEEDBACKS),
    _r('motor_counts_per_m', 'double', MOTOR_COUNTS_PER_M, 'counts/m',
       'Motor (rotary) encoder counts per metre of slide travel.', 'PMAC Ixx08 scaling',
       min=0.0, min_exclusive=True),
    _r('load_counts_per_m', 'double', LOAD_COUNTS_PER_M, 'counts/m',
       'Load (linear) encoder counts per metre.', 'Galil auxiliary encoder', min=0.0,
       min_exclusive=True),
    _r('kp', 'double', 16000.0, 'V/m', 'Proportional gain.', 'PMAC Ixx30, Galil KP', min=0.0),
    _r('ki', 'double', 181019.3, 'V/(m·s)', 'Integral gain.', 'PMAC Ixx33, Galil KI', min=0.0),
    _r('kd', 'double', 160.0, 'V·s/m', 'Derivative gain, on the actual velocity of the '
       'velocity-loop encoder (PMAC form; set kvff = kd for derivative of error).',
       'PMAC Ixx31, Galil KD', min=0.0),
    _r('kvff', 'double', 161.06, 'V·s/m', 'Velocity feedforward.', 'PMAC Ixx32', min=0.0),
    _r('kaff', 'double', 0.5966, 'V·s²/m', 'Acceleration feedforward.', 'PMAC Ixx35', min=0.0),
    _r('friction_ff', 'double', 0.0, 'V', 'Friction feedforward, added by the sign of the '
       'commanded velocity (0 at rest; see friction_ff_at_rest).', 'PMAC Ixx68', min=0.0,
       max=10.0),
    _r('friction_ff_at_rest', 'double', 0.0, 'V', 'Breakaway aid: once the command has '
       'stopped, added by the sign of the position error while that lies outside the '
       'anti-hunting window (half a count, or deadband_tolerance), so the last counts of a move '
       'are not crept out against stiction by the integrator alone. Keep it below the sliding '
       'friction (autotune: 0.75 x the Coulomb friction), so that friction still stops the '
       'slide once it breaks free. Applied only where the position loop reads the load encoder '
       '(feedback dual or load): with motor or sampled feedback a motor free inside a backlash '
       'gap, pushed by its own error, would hunt.', 'motion_ctrl (cf. PMAC Ixx68)', min=0.0,
       max=10.0),
    _r('bias', 'double', 0.0, 'V', 'Constant output offset (closed loop only).',
       'PMAC Ixx29 / Galil OF', min=-10.0, max=10.0),
    _r('integration_mode', 'string', 'always', '', 'always: integrate all the time; at_rest: '
       'integrator input off while the commanded velocity is non-zero (output held).',
       'PMAC Ixx34 = 0 / 1', choices=('always', 'at_rest')),
    _r('integration_limit', 'double', 5.0, 'V', 'Limit of the integrator output.',
       'PMAC Ixx63, Galil IL', min=0.0, max=10.0),
    _r('output_limit', 'double', 10.0, 'V', 'Limit of the command output.',
       'PMAC Ixx69, Galil TL', min=0.0, max=10.0),
    _r('output_deadband', 'double', 0.0, 'V', 'Added by the sign of the output to overcome an '
       'amplifier or valve deadband (closed loop only).', 'RMC Output Deadband', min=0.0,
       max=10.0),
    _r('deadband_tolerance', 'double', 0.0, 'm', 'Position error window for anti-hunting and '
       'deadband ratioing.', 'RMC Deadband Tolerance', min=0.0),
    _r('window_centre', 'string', 'reading', '', 'Where the at-rest windows (fine position, '
       'anti-hunting, deadband ratioing, the breakaway aid) are centred: reading (the position '
       'encoder as read; a quadrature counter reads the lower edge of its count, so a window of '
       'whole counts around a target on a count lies half a count high on the slide) or '
       'count_middle (half a count above the reading: the window lies symmetric about the '
       'target; autotune sets it where stick-slip needs a window wider than the exact count).',
       'motion_ctrl (cf. RMC Deadband Tolerance, half a raw count)',
       choices=('reading', 'count_middle')),
    _r('hunting_reversals', 'integer', 4, 'count', 'Hunting watch: the axis reports hunting '
       '(/diagnostics, the log) once its output has reversed this many times at rest without '
       'settling (no MOTION_DONE, or out of the fine window since); 0 = not watched.',
       'cf. RMC Deadband Tolerance (anti-hunting)', min=0, max=1000),
    _r('notch_n1', 'double', 0.0, '', 'Notch/low-pass numerator z^-1 coefficient.',
       'PMAC Ixx36', min=-2.0, max=2.0),
    _r('notch_n2', 'double', 0.0, '', 'Notch/low-pass numerator z^-2 coefficient.',
       'PMAC Ixx37', min=-2.0, max=2.0),
    _r('notch_d1', 'double', 0.0, '', 'Notch/low-pass denominator z^-1 coefficient.',
       'PMAC Ixx38', min=-2.0, max=2.0),
    _r('notch_d2', 'double', 0.0, '', 'Notch/low-pass denominator z^-2 coefficient.',
       'PMAC Ixx39', min=-2.0, max=2.0),
    _r('position_error_limit', 'double', 0.0, 'm', 'Clips the position error fed to the loop '
       '(0 = off).', 'PMAC Ixx67', min=0.0),
    _r('following_error_warning', 'double', 0.001, 'm', 'Following error warning threshold '
       '(0 = off).', 'PMAC Ixx12, Galil ER', min=0.0),
    _r('following_error_fatal', 'double', 0.005, 'm', 'Following error that opens the loop '
       '(0 = off); needs <axis>/reset.', 'PMAC Ixx11, Galil OE', min=0.0),
    _r('backlash_distance', 'double', 0.0, 'm', 'Backlash added to the motor command while '
       'moving negative.', 'PMAC Ixx86', min=-0.01, max=0.01),
    _r('backlash_takeup_rate', 'double', 0.01, 'm/s', 'Rate at which backlash is introduced or '
       'removed on a reversal (per second; 0 = at once).', 'PMAC Ixx85', min=0.0),
    _r('backlash_hysteresis', 'double', 2.54e-6, 'm', 'Commanded motion in the new direction '
       'needed to detect a reversal.', 'PMAC Ixx87', min=0.0),
    _r('backlash_table', 'double_array', [], 'm', 'Position-dependent backlash added to '
       'backlash_distance while moving negative; entry i at i·spacing.', 'PMAC DEFINE BLCOMP',
       min=-0.01, max=0.01),
    _r('backlash_table_spacing', 'double', 0.0, 'm', 'Spacing of backlash_table entries.',
       'PMAC DEFINE BLCOMP', min=0.0),
    _r('leadscrew_table', 'double_array', [], 'm', 'Correction added to the motor command in '
       'both directions (fill with minus the measured slide error); entry i at i·spacing.',
       'PMAC DEFINE COMP', min=-0.01, max=0.01),
    _r('leadscrew_table_spacing', 'double', 0.0, 'm', 'Spacing of leadscrew_table entries.',
       'PMAC DEFINE COMP', min=0.0),
    _r('max_velocity', 'double', 0.1, 'm/s', 'Move velocity limit.', 'Galil SP, PMAC Ixx16',
       min=0.0, min_exclusive=True),
    _r('overspeed_velocity', 'double', 0.0, 'm/s', 'Measured motor velocity (in load units) '
       'beyond which the loop opens at once, output 0 (OVERSPEED, until <axis>/reset), as a '
       "drive's overspeed fault; 0 = 1.5 × max_velocity; else above max_velocity.",
       'Kollmorgen VOSPD (fault F08), CiA 402 0x6080 max motor speed', min=0.0),
    _r('max_acceleration', 'double', 1.5, 'm/s²', 'Move acceleration limit.',
       'Galil AC/DC, PMAC Ixx17', min=0.0, min_exclusive=True),
    _r('max_jerk', 'double', 0.0, 'm/s³', 'Jerk limit of moves, jogs and STOPs (0 = trapezoid); '
       'an ESTOP ramps at estop_deceleration.', 'PMAC Ixx19..21 S-curve', min=0.0),
    _r('smoothing', 'double', 1.0, '', 'Profile smoothing, first-order filter with pole 1 − IT '
       'per servo sample (1 = off).', 'Galil IT', min=0.004, max=1.0),
    _r('stop_deceleration', 'double', 2.0, 'm/s²', 'Deceleration of <axis>/stop.',
       'RMP STOP rate', min=0.0, min_exclusive=True),
    _r('estop_deceleration', 'double', 10.0, 'm/s²', 'Deceleration of <axis>/estop, a ramp '
       '(max_jerk does not shape it).', 'RMP ESTOP rate, PMAC Ixx15', min=0.0,
       min_exclusive=True),
    _r('soft_limit_min', 'double', -0.5, 'm', 'Targets below are refused (LIMIT bit).',
       'Galil BL, PMAC Ixx14'),
    _r('soft_limit_max', 'double', 0.5, 'm', 'Targets above are refused (LIMIT bit).',
       'Galil FL, PMAC Ixx13'),
    _r('fine_position_tolerance', 'double', 1.5e-6, 'm', 'Settled window on the position '
       'error (default: the exact count on the linear encoder, or either neighbour of a target '
       'that falls between two counts).', 'RMP PositionToleranceFine', min=0.0),
    _r('coarse_position_tolerance', 'double', 2.54e-5, 'm', 'Near-target window.',
       'RMP PositionToleranceCoarse', min=0.0),
    _r('velocity_tolerance', 'double', 0.005, 'm/s', 'Settled / at-velocity window on the '
       'velocity.', 'RMP VelocityTolerance', min=0.0),
    _r('settling_time', 'double', 0.02, 's', 'Time the settling criteria must hold (time of new '
       'encoder samples: a held-up feedback stream adds none).',
       'RMP SettlingTime', min=0.0, max=60.0),
    _r('correction_tolerance', 'double', 1 / LOAD_COUNTS_PER_M, 'm', 'Sampled dual loop: '
       'corrections stop when the load encoder error V1 and V2 = V1 - TE (the motor\'s own '
       'error taken off) are both below this (1 count: only an exact reading ends them).',
       'Galil example: |V2| < 2 linear counts',
       min=0.0, min_exclusive=True),
    _r('correction_max_moves', 'integer', 200, 'count', 'Sampled dual loop: most correction '
       'moves per move (a reversal inside the gap can take one per count of backlash, twice '
       'over when the slide overshoots).', '', min=0, max=1000),
    _r('correction_acceleration', 'double', 0.1, 'm/s²', 'Sampled dual loop: acceleration and '
       'deceleration of the correction moves. Gentle, so that a motor crossing the backlash '
       'meets the slide slowly instead of throwing it across the gap (doc/headline.md).',
       'Galil AC / DC set for the #CORRECT moves', min=0.0, min_exclusive=True),
    # The defaults of a follow_joint_trajectory goal (motion_ctrl.core.follow_goal); a goal's
    # path_tolerance, goal_tolerance and goal_time_tolerance override them.
    _r('trajectory_tolerance', 'double', 0.001, 'm', 'follow_joint_trajectory: largest '
       'following error while the trajectory runs, else the goal ends with '
       'PATH_TOLERANCE_VIOLATED and its axes stop (0 = not checked).',
       'joint_trajectory_controller constraints.<joint>.trajectory', min=0.0),
    _r('goal_tolerance', 'double', 0.0, 'm', 'follow_joint_trajectory: largest distance of the '
       'actual position from the last point for success, besides MOTION_DONE (0 = only '
       'MOTION_DONE, i.e. fine_position_tolerance).',
       'joint_trajectory_controller constraints.<joint>.goal', min=0.0),
    _r('stopped_velocity_tolerance', 'double', 0.01, 'm/s', 'follow_joint_trajectory: largest '
       'actual velocity for success at the end (0 = not checked).',
       'joint_trajectory_controller constraints.stopped_velocity_tolerance', min=0.0),
    _r('goal_time', 'double', 2.0, 's', 'follow_joint_trajectory: time after the trajectory\'s '
       'end within which the axis must be settled (MOTION_DONE) and within its goal tolerance, '
       'else GOAL_TOLERANCE_VIOLATED (0 = no deadline, as joint_trajectory_controller\'s '
       'default).', 'joint_trajectory_controller constraints.goal_time', min=0.0),
    # The test signal of <axis>/excite (motion_ctrl.core.excitation, .gather): read when the
    # service starts a run; a change applies to the next run, never to one in progress.
    _r('excitation_signal', 'string', 'prbs', '', '<axis>/excite: the test signal added to '
       'the servo output: prbs (maximum-length sequence), chirp (logarithmic sine sweep) or '
       'stepped_sine (20 frequencies, whole cycles each).',
       'Kollmorgen WorkBench Bode excitation, PMAC / Galil sine sweep',
       choices=('prbs', 'chirp', 'stepped_sine')),
    _r('excitation_amplitude', 'double', 0.5, 'V', '<axis>/excite: peak of the test signal '
       '(the sum with the servo output stays within output_limit).',
       'WorkBench excitation amplitude', min=0.0, max=10.0, min_exclusive=True),
    _r('excitation_band_low', 'double', 5.0, 'Hz', '<axis>/excite: low end of the band.', '',
       min=0.0, min_exclusive=True),
    _r('excitation_band_high', 'double', 400.0, 'Hz', '<axis>/excite: high end of the band '
       '(at most half the servo rate; > excitation_band_low).', '', min=0.0,
       min_exclusive=True),
    _r('excitation_duration', 'double', 4.0, 's', '<axis>/excite: length of the test signal; '
       'every servo tick of it is recorded and published on <axis>/gather.',
       'PMAC gather buffer length', min=0.0, max=600.0, min_exclusive=True),
    _r('excitation_points', 'integer', 20, 'count', '<axis>/excite, stepped_sine: frequencies, '
       'log-spaced over the band, the duration shared among them.', '', min=1, max=1000),
    _r('excitation_budget', 'double', 0.005, 'm', '<axis>/excite: travel budget: the run ends '
       '(and a base motion brakes) before the slide gets further than this from where it '
       'started, braking distance included.', '', min=0.0, min_exclusive=True),
    _r('excitation_velocity', 'double', 0.0, 'm/s', '<axis>/excite: base motion under the '
       'test signal, a jog at this velocity (sign = direction; 0 = none): stiction and the '
       'backlash gap stay out of the measurement. The signal starts once the axis is '
       'MOTION_AT_VELOCITY; |velocity| <= max_velocity.', 'Beckhoff TwinCAT autotuning base '
       'motion', min=-10.0, max=10.0),
)

CONTROLLER_AXIS = {r.name: r for r in AXIS_REGISTERS}
CONTROLLER_GLOBAL = {r.name: r for r in CONTROLLER_GLOBALS}


def axis_defaults(table=AXIS_REGISTERS) -> dict:
    return {r.name: (list(r.default) if isinstance(r.default, list) else r.default)
            for r in table}


def _notch_rule(v: dict) -> str | None:
    # (the notch module owns what a valid filter is)
    try:
        Biquad.validate(v['notch_n1'], v['notch_n2'], v['notch_d1'], v['notch_d2'])
    except ValueError as e:
        return f'notch_n1..notch_d2: {e}'
    return None


def _table_rule(table: str):
    def rule(v: dict) -> str | None:
        if len(v[table]) and not v[f'{table}_spacing'] > 0:
            return (f'{table}_spacing must be > 0 while {table} is set (set the spacing before '
                    'the table; clear the table with [] before or with the spacing)')
        return None
    return rule


# Cross-register rules of one axis: (the registers a rule reads, rule -> reason or None).
AXIS_RULES = (
    (('fine_position_tolerance', 'coarse_position_tolerance'), lambda v: None
     if v['coarse_position_tolerance'] >= v['fine_position_tolerance'] else
     'coarse_position_tolerance must be >= fine_position_tolerance '
     f'({v["coarse_position_tolerance"]:g} < {v["fine_position_tolerance"]:g})'),
    (('soft_limit_min', 'soft_limit_max'), lambda v: None
     if v['soft_limit_min'] < v['soft_limit_max'] else
     f'soft_limit_min must be < soft_limit_max ({v["soft_limit_min"]:g} >= '
     f'{v["soft_limit_max"]:g})'),
    (('backlash_table', 'backlash_table_spacing'), _table_rule('backlash_table')),
    (('leadscrew_table', 'leadscrew_table_spacing'), _table_rule('leadscrew_table')),
    (('following_error_warning', 'following_error_fatal'), lambda v: None
     if not (0 < v['following_error_fatal'] < v['following_error_warning']) else
     'following_error_warning must be <= following_error_fatal '
     f'({v["following_error_warning"]:g} > {v["following_error_fatal"]:g})'),
    (('overspeed_velocity', 'max_velocity'), lambda v: None
     if not (0 < v['overspeed_velocity'] <= v['max_velocity']) else
     'overspeed_velocity must be above max_velocity (or 0: 1.5 × max_velocity) '
     f'({v["overspeed_velocity"]:g} <= {v["max_velocity"]:g} m/s)'),
    (('notch_n1', 'notch_n2', 'notch_d1', 'notch_d2'), _notch_rule),
    (('excitation_band_low', 'excitation_band_high'), lambda v: None
     if v['excitation_band_high'] > v['excitation_band_low'] else
     'excitation_band_high must be > excitation_band_low '
     f'({v["excitation_band_high"]:g} <= {v["excitation_band_low"]:g} Hz)'),
)


def consistency(v: dict) -> list[str]:
    """Cross-register rules on one axis' values; reasons name the registers. A rule applies
    when all the registers it reads are among `v` (a consumer's part, or the whole set)."""
    reasons = (rule(v) for names, rule in AXIS_RULES if all(n in v for n in names))
    return [r for r in reasons if r]


def refusals(values: dict, table: dict | None = None, rules=None) -> list[str]:
    """Every reason a complete set of one axis' register values is refused: each value by its
    row (type, range, choices), then the cross-register rules. The one validation path: the
    nodes' parameter callbacks and the core's configuration both come here."""
    table = CONTROLLER_AXIS if table is None else table
    rules = consistency if rules is None else rules
    reasons = [f'unknown register {name!r}' for name in values if name not in table]
    reasons += [r for r in (table[n].check(v) for n, v in values.items() if n in table) if r]
    return reasons or rules(values)


# Plant parameters (per axis `<axis>.<name>` on the plant node): the Galil backlash slide.
PLANT_PARAMETERS = (
    _r('lead', 'double', 0.2 * INCH, 'm/rev', 'Lead of the screw (5.08 mm: 5 rev per inch).',
       min=0.0, min_exclusive=True),
    _r('motor_counts_per_rev', 'double', 8000.0, 'counts/rev', 'Rotary encoder resolution.',
       min=1.0),
    _r('load_resolution', 'double', INCH / 10000, 'm/count', 'Linear encoder resolution.',
       min=0.0, min_exclusive=True),
    _r('motor_inertia', 'double', 2.0e-5, 'kg·m²', 'Rotor plus screw inertia.', min=0.0,
       min_exclusive=True),
    _r('slide_mass', 'double', 5.0, 'kg', 'Moving mass of the slide.', min=0.0,
       min_exclusive=True),
    _r('backlash', 'double', 20 * INCH / 10000, 'm', 'Gap between nut and slide flanks '
       '(20 linear counts).', min=0.0),
    _r('screw_stiffness', 'double', 1.0e7, 'N/m', 'Axial stiffness of screw, nut and coupling '
       'in contact: with the two masses it sets the mechanical resonance (~240 Hz).',
       min=0.0, min_exclusive=True),
    _r('screw_damping', 'double', 200.0, 'N·s/m', 'Damping of that compliance.', min=0.0),
    _r('torque_constant', 'double', 0.1, 'N·m/A', 'Motor torque constant.', min=0.0,
       min_exclusive=True),
    _r('amplifier_gain', 'double', 0.5, 'A/V', 'Torque-mode amplifier transconductance.',
       min=0.0, min_exclusive=True),
    _r('amplifier_limit', 'double', 10.0, 'V', 'Amplifier input saturation.', min=0.0,
       min_exclusive=True),
    _r('motor_viscous', 'double', 1.0e-5, 'N·m·s/rad', 'Motor viscous friction.', min=0.0),
    _r('motor_coulomb', 'double', 0.004, 'N·m', 'Motor Coulomb (sliding) friction.', min=0.0),
    _r('motor_stiction', 'double', 0.0045, 'N·m', 'Motor breakaway friction (>= coulomb).',
       min=0.0),
    _r('slide_viscous', 'double', 50.0, 'N·s/m', 'Slide viscous friction.', min=0.0),
    _r('slide_coulomb', 'double', 10.0, 'N', 'Slide Coulomb friction.', min=0.0),
    _r('slide_stiction', 'double', 10.5, 'N', 'Slide breakaway friction (>= coulomb).', min=0.0),
    _r('pitch_error_slope', 'double', 2.0e-4, 'm/m', 'Cumulative lead error of the screw '
       '(nut position gains this much per metre of motor travel).', min=-0.01, max=0.01),
    _r('pitch_error_amplitude', 'double', 2.54e-6, 'm', 'Periodic lead error amplitude.',
       min=0.0, max=0.001),
    _r('pitch_error_period', 'double', 1.5 * INCH, 'm', 'Period of the periodic lead error.',
       min=0.0, min_exclusive=True),
    _r('travel_min', 'double', -0.55, 'm', 'Slide end stop (negative).'),
    _r('travel_max', 'double', 0.55, 'm', 'Slide end stop (positive).'),
    _r('brake', 'integer', 0, '', '1 clamps the slide (stall test), 0 releases it.',
       min=0, max=1),
    _r('command_timeout', 'double', 0.01, 's', 'Amplifier command watchdog: with no '
       '`command` for this long (plant time, checked every plant cycle) the output goes to 0 V '
       'and the dynamic brake closes until commands come again; <axis>/amplifier_fault reports '
       'it. 10 servo periods: a slide at max_velocity (0.1 m/s) runs 1 mm on the last command '
       'and 1 mm on the dynamic brake, at rest in 31 ms (coasting free against friction alone '
       'it would run 9.3 mm more, in 0.2 s); shorter trips on every controller stall of a '
       'loaded machine.',
       'fieldbus (EtherCAT SM) watchdog, PMAC amplifier fault', min=0.0, max=10.0,
       min_exclusive=True),
    _r('dynamic_brake', 'double', 0.002, 'N·m·s/rad', 'Braking torque per motor speed while '
       'the watchdog holds the output at 0: the amplifier shorts the windings through its brake '
       'resistor (Kt²/R, here R = 5 Ω); 0 lets the motor coast.',
       'servo drive dynamic braking (DB stop)', min=0.0, max=0.1),
)
PLANT_GLOBALS = (
    _r('axes', 'string_array', ['x'], '', 'Names of the simulated axes.', read_only=True),
    _r('publish_rate', 'double', 1000.0, 'Hz', 'Rate of encoders / plant_states.', min=10.0,
       max=20000.0, read_only=True),
    _r('substep_rate', 'double', 20000.0, 'Hz', 'Integration rate of the physics.', min=1000.0,
       max=1.0e6, read_only=True),
    _r('lockstep', 'integer', 0, '', '1: advance one period per controller command and publish '
       '/clock (deterministic sim time).', min=0, max=1, read_only=True),
    REALTIME_PRIORITY,
)
PLANT_AXIS = {r.name: r for r in PLANT_PARAMETERS}
PLANT_GLOBAL = {r.name: r for r in PLANT_GLOBALS}

# `hardware: canopen` (motion_ctrl.canopen, doc/canopen.md): the bus, and each axis's nodes on
# it. The controller and the emulated drive (`virtual_drive`) share these names.
CAN_GLOBALS = (
    _r('can_interface', 'string', 'socketcan', '', "python-can's interface name: socketcan "
       '(Linux SocketCAN: PEAK, Kvaser, IXXAT, ... USB adapters with a kernel driver), pcan, '
       'kvaser, ixxat, vector, slcan, gs_usb, ...; virtual (in one process) and udp_multicast '
       '(between processes of one machine) are emulated buses.', 'python-can interface',
       read_only=True),
    _r('can_channel', 'string', 'can0', '', "python-can's channel: can0 (socketcan), "
       'PCAN_USBBUS1 (pcan), 0 (kvaser), a multicast group such as 239.74.163.2 '
       '(udp_multicast), any name (virtual).', 'python-can channel', read_only=True),
    _r('can_bitrate', 'integer', 1_000_000, 'bit/s', 'Bit rate of the bus (CiA 301: 10 k to '
       '1 M); it bounds the servo rate: the SYNC and every PDO of a cycle must fit 80 % of it '
       '(doc/canopen.md). For socketcan the interface is set up outside (ip link set can0 type '
       'can bitrate ...); the figure is still the one the rate is checked against.',
       'CiA 301 bit timing', min=10_000, max=1_000_000, read_only=True),
)
CAN_AXIS = (
    _r('can_node_id', 'integer', 1, '', "The axis's CiA 402 drive: its CANopen node id.",
       'CiA 301 node-ID', min=1, max=127, read_only=True),
    _r('load_encoder_node_id', 'integer', 0, '', 'Where the load (linear) encoder comes from: '
       "0 = the drive's additional position actual value 60E4h:01 (a second encoder input on "
       'the drive); otherwise the node id of a CiA 406 encoder (position value 6004h).',
       'CiA 402 60E4h / CiA 406 6004h', min=0, max=127, read_only=True),
)
CANOPEN_AXIS = CAN_AXIS + (
    _r('eds', 'string', '', '', "The drive's EDS file ('' = the shipped generic CiA 402 one, "
       'motion_ctrl/canopen/eds/cia402_drive.eds): the objects the start-up reads and writes.',
       'CiA 306 EDS', read_only=True),
    _r('torque_per_volt', 'double', 100.0, '‰/V', 'The servo output [V] as target torque '
       "6071h [‰ of the drive's rated torque 6076h]: 100 makes ±10 V the rated torque, as a "
       "torque-mode amplifier's input scaling does (the default slide: 0.05 N·m/V). The gains "
       'stay in volts.', 'analog amplifier input scaling; CiA 402 6071h', min=0.0,
       max=3276.7, min_exclusive=True),
    _r('estop_quick_stop', 'integer', 0, '', "1: an ESTOP is also the drive's quick stop: "
       'while the axis is ESTOPPED the controlword says quick stop (02h), and the drive brakes '
       'on its own at 6085h (written at start-up: estop_deceleration in motor counts/s²) and '
       "then disables (605Ah = 2), whatever the loop does; the next move enables it again. 0: "
       "the controller's ESTOP profile alone, through the drive in torque mode.",
       'CiA 402 quick stop, 605Ah / 6085h; RMP ESTOP', min=0, max=1, read_only=True),
)

# The registers a hardware backend adds to the controller (declared only when `hardware` chooses
# it): (controller-wide, per axis).
HARDWARE_REGISTERS: dict[str, tuple[tuple[Register, ...], tuple[Register, ...]]] = {
    'topics': ((), ()),
    'sim': ((PLANT_GLOBAL['substep_rate'],), PLANT_PARAMETERS),
    'canopen': (CAN_GLOBALS, CANOPEN_AXIS),
}

# The emulated drive (`ros2 run motion_ctrl virtual_drive`, motion_ctrl.canopen.virtual_drive):
# the bus and node ids as the controller's, the slide's physics as the plant's, and what it can
# be made to do wrong.
VIRTUAL_DRIVE_GLOBALS = (
    _r('axes', 'string_array', ['x'], '', 'Names of the emulated axes (one drive each).',
       read_only=True),
    *CAN_GLOBALS,
    PLANT_GLOBAL['substep_rate'],
    REALTIME_PRIORITY,
)
VIRTUAL_DRIVE_FAULTS = (
    _r('inject_fault', 'integer', 0, '', 'A change to a non-zero error code makes the drive '
       'fault with it at the next cycle, as its own protection would (0x2310 over-current, '
       '0x4310 drive temperature, ...): EMCY, 603Fh, statusword fault bit, 0 torque and the '
       'dynamic brake, until a fault reset.', 'CiA 402 603Fh / CiA 301 EMCY', min=0,
       max=0xFFFF),
    _r('device_type', 'integer', 0x00020192, '', "1000h as the drive reports it (the master "
       'checks the low 16 bits: 402); another value makes a drive the controller refuses.',
       'CiA 301 1000h', min=0, max=0xFFFFFFFF, read_only=True),
    _r('supported_modes', 'integer', 0x200, '', '6502h as the drive reports it: bit 9 is '
       'cyclic synchronous torque, the only mode it runs; without it the controller refuses '
       'the drive.', 'CiA 402 6502h', min=0, max=0xFFFFFFFF, read_only=True),
    _r('refuse_mapping', 'integer', 0, '', 'An object index the drive refuses to map into a '
       'PDO (SDO abort 06040041h), 0 = none: the controller refuses the drive naming it.',
       'CiA 301 SDO abort', min=0, max=0xFFFF, read_only=True),
)
VIRTUAL_DRIVE_AXIS = CAN_AXIS + PLANT_PARAMETERS + VIRTUAL_DRIVE_FAULTS


def plant_consistency(v: dict) -> list[str]:
    reasons = []
    if v['motor_stiction'] < v['motor_coulomb']:
        reasons.append('motor_stiction must be >= motor_coulomb')
    if v['slide_stiction'] < v['slide_coulomb']:
        reasons.append('slide_stiction must be >= slide_coulomb')
    if not v['travel_min'] < 0.0 < v['travel_max']:
        reasons.append('travel_min < 0 < travel_max is required (the slide starts at 0)')
    return reasons


# -- generated artefacts: params/*.yaml and the documentation's tables -----------------------------
def yaml_float(value) -> str:
    """A double that every YAML reader types as one: YAML 1.1 wants a '.' (1e-06 -> 1.0e-06)."""
    text = repr(float(value))
    if 'e' in text and '.' not in text.split('e')[0]:
        text = text.replace('e', '.0e', 1)
    return text


def _yaml_value(reg, value) -> str:
    if reg.type == 'double':
        return yaml_float(value)
    if reg.type == 'integer':
        return str(int(value))
    if reg.type == 'string':
        return value
    if reg.type == 'double_array':
        return '[' + ', '.join(yaml_float(v) for v in value) + ']'
    # Quoted: rcl's YAML reads y, n, on, off (and yes, no, true, false) as booleans, and an
    # unquoted `axes: [x, y]` is refused as a list of mixed types.
    return '[' + ', '.join(f"'{v}'" for v in value) + ']'


def params_yaml(node: str, globals_, axis_table, axes=('x',), tuning=None) -> str:
    """`ros2 param load` YAML of a node's registers at their defaults (the default slide), or
    at `tuning`'s values ({register: value}) for the registers it names, each such line saying
    so and giving the table's default.

    Empty arrays are written as comments: rcl's YAML parser cannot type an empty sequence.
    """
    tuning = tuning or {}
    lines = [f'# Generated by `python -m motion_ctrl.core.registers --yaml {node}` from the',
             '# register table in motion_ctrl/core/registers.py: edit the table, not this file.']
    if tuning:
        lines += ["# The gains are the shipped slide's tuning (SHIPPED_SLIDE_TUNING,",
                  "# doc/gains.md), not the table's defaults: each such line gives the default."]
    lines += [f'{node}:', '  ros__parameters:']

    def emit(reg, key):
        value = tuning.get(reg.name, reg.default)
        text = f'{key}: {_yaml_value(reg, value)}'
        unit = f' [{reg.unit}]' if reg.unit else ''
        vendor = f' {reg.vendor}' if reg.vendor else ''
        comment = f'  #{unit}{vendor}'.rstrip(' #') if (unit or vendor) else ''
        if reg.name in tuning:
            comment = (comment or '  #') + (f'; shipped slide tuning, table default '
                                             f'{_yaml_value(reg, reg.default)}')
        if isinstance(value, list) and not value and reg.type == 'double_array':
            lines.append(f'    # {text}{comment}')
        else:
            lines.append(f'    {text}{comment}')

    for reg in globals_:
        value = list(axes) if reg.name == 'axes' else reg.default
        lines.append(f'    {reg.name}: {_yaml_value(reg, value)}')
    for axis in axes:
        for reg in axis_table:
            emit(reg, f'{axis}.{reg.name}')
    return '\n'.join(lines) + '\n'


def _md_cell(text: str) -> str:
    """Text for a Markdown table cell: `|` would end the cell and `<axis>` read as an HTML tag."""
    return text.replace('|', '\\|').replace('<', '\\<')


def markdown_table(table) -> str:
    rows = ['| register | unit | default | range | vendor | meaning |',
            '|---|---|---|---|---|---|']
    for r in table:
        if r.choices:
            rng = ' \\| '.join(r.choices)
        elif r.min is not None or r.max is not None:
            lo = '−∞' if r.min is None else f'{r.min:g}'
            hi = '∞' if r.max is None else f'{r.max:g}'
            rng = f'{"(" if r.min_exclusive else "["}{lo}, {hi}]'
        else:
            rng = ''
        default = r.default if not isinstance(r.default, float) else f'{r.default:.6g}'
        rows.append(f'| `{r.name}` | {r.unit} | {default} | {rng} | {_md_cell(r.vendor)} | '
                    f'{_md_cell(r.description)} |')
    return '\n'.join(rows) + '\n'


# The shipped slide's tuning (doc/gains.md): params/controller.yaml, which the demo, the launch
# file and the tools' --spawn load, carries these values instead of the table's defaults. They
# are autotune's stiff proposal for the default slide (plant.yaml) with its dual loop, rounded
# (8.2 dB / 45.6° on the identified model, crossover 36.9 Hz), with the integrator held while
# the command moves (PMAC Ixx34 = 1). The breakaway aid (0.75 x the Coulomb friction) pushes the
# last counts in against stiction. Held during moves, the integrator carries no push past the
# end of the profile: over DDS, with the loop's real timing, the slide otherwise stopped a count
# past the target and came back through the backlash in 300-650 ms. The profile is an S-curve
# (max_jerk 60 m/s³, the acceleration ramps in 25 ms): the acceleration feedforward fades out
# with it at the end of the move, and the motor, braking on it a tick or two late over DDS,
# stays on the slide instead of running back off it across the backlash gap. The table's
# defaults stay the gains of Galil's tuning procedure on the slide (`tune`), integrating always,
# without the aid, on a trapezoid: the harness scenarios and the core tests are stated in them.
SHIPPED_SLIDE_TUNING: dict[str, float | str] = {
    'kp': 9200.0,
    'ki': 168000.0,
    'kd': 126.0,
    'kvff': 127.0,
    'kaff': 0.575,
    'friction_ff': 0.242,
    'friction_ff_at_rest': 0.181,
    'integration_mode': 'at_rest',
    'window_centre': 'count_middle',
    'max_jerk': 60.0,
}


def shipped_tuning(axes) -> dict[str, float | str]:
    """SHIPPED_SLIDE_TUNING as `<axis>.<register>` parameters for each of `axes`: the shipped
    params file tunes x only; start_slide and the launch file give the other axes they are
    asked for the same slide's tuning (under any file or override that names them)."""
    return {f'{a}.{k}': v for a in axes for k, v in SHIPPED_SLIDE_TUNING.items()}


def shipped_tuning_yaml(axes) -> list[str]:
    """shipped_tuning(axes) as params-file lines (`y.kp: 9200.0`), each value written as its
    register is typed (as in params/controller.yaml)."""
    return [f'{a}.{k}: {_yaml_value(CONTROLLER_AXIS[k], v)}'
            for a in axes for k, v in SHIPPED_SLIDE_TUNING.items()]

GENERATED = {
    'params/controller.yaml': lambda: params_yaml('controller', CONTROLLER_GLOBALS,
                                                  AXIS_REGISTERS, tuning=SHIPPED_SLIDE_TUNING),
    'params/plant.yaml': lambda: params_yaml('plant', PLANT_GLOBALS, PLANT_PARAMETERS),
    'params/virtual_drive.yaml': lambda: params_yaml('virtual_drive', VIRTUAL_DRIVE_GLOBALS,
                                                     VIRTUAL_DRIVE_AXIS),
}


# Generated blocks of the documentation pages (doc/<topic>.md): the text between
# `<!-- key -->` and `<!-- /key -->`.
DOC_BLOCKS = {
    'doc/parameters.md': {
        'registers:controller': lambda: markdown_table(AXIS_REGISTERS),
        'registers:controller_globals': lambda: markdown_table(CONTROLLER_GLOBALS),
        'registers:plant': lambda: markdown_table(PLANT_PARAMETERS),
        'registers:plant_globals': lambda: markdown_table(PLANT_GLOBALS),
    },
    'doc/canopen.md': {
        'registers:canopen': lambda: markdown_table(CAN_GLOBALS + CANOPEN_AXIS),
        'registers:virtual_drive': lambda: markdown_table(VIRTUAL_DRIVE_FAULTS),
    },
}


def doc_block(text: str, key: str) -> str:
    """The generated text between `<!-- key -->` and `<!-- /key -->` in a page's text."""
    start = text.index(f'<!-- {key} -->\n') + len(f'<!-- {key} -->\n')
    return text[start:text.index(f'<!-- /{key} -->')]


def stale_blocks(text: str, blocks) -> list[str]:
    """The keys of a page's generated blocks that differ from what the table generates now."""
    return [key for key, make in blocks.items() if doc_block(text, key) != make()]


def update_doc(text: str, blocks) -> str:
    """A page's text with its generated blocks made again from the table."""
    for key, make in blocks.items():
        text = text.replace(f'<!-- {key} -->\n{doc_block(text, key)}',
                            f'<!-- {key} -->\n{make()}')
    return text


def main(argv=None) -> int:
    import argparse  # (here: only this command line needs it: 2-9 ms at load, -X importtime)
    ap = argparse.ArgumentParser(description='Print or write what the register table generates.')
    ap.add_argument('--yaml', choices=('controller', 'plant', 'virtual_drive'),
                    help='print a params YAML')
    ap.add_argument('--markdown', choices=('controller', 'plant'),
                    help='print a register table (Markdown)')
    ap.add_argument('--write', metavar='REPO',
                    help='rewrite params/*.yaml and the documentation\'s tables under REPO')
    a = ap.parse_args(argv)
    if a.yaml:
        print(GENERATED[f'params/{a.yaml}.yaml'](), end='')
    if a.markdown:
        print(markdown_table(AXIS_REGISTERS if a.markdown == 'controller'
                             else PLANT_PARAMETERS), end='')
    if a.write:
        for path, make in GENERATED.items():
            (pathlib.Path(a.write) / path).write_text(make())
        for path, blocks in DOC_BLOCKS.items():
            doc = pathlib.Path(a.write) / path
            doc.write_text(update_doc(doc.read_text(), blocks))
    return 0


if __name__ == '__main__':
    raise SystemExit(main())
