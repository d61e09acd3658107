"""Topic and service names (doc/interface.md, "Topics", "Services"). Relative names: a namespace
works."""

TARGET_POSITION = 'target_position'    # sensor_msgs/JointState -> controller, position [m]
TARGET_VELOCITY = 'target_velocity'    # sensor_msgs/JointState -> controller, velocity [m/s]
# A target message larger than this is refused by its size before it is decoded (rclpy would
# build a Python string per name first: a flood of 10,000-name messages at 100 Hz took the loop
# from 995 to ~500 Hz); the servo bus's bridge refuses it before the bus. 64 KiB holds hundreds
# of axes.
MAX_TARGET_BYTES = 65536
JOINT_TRAJECTORY = 'joint_trajectory'  # trajectory_msgs/JointTrajectory -> controller (PVT) [m]
JOINT_STATES = 'joint_states'          # controller ->: load position/velocity, effort = output [V]
REFERENCE_STATES = 'reference_states'  # controller ->: commanded (profile) position/velocity
MOTOR_STATES = 'motor_states'          # controller ->: motor side in load units [m, m/s]
COMMAND = 'command'                    # controller -> plant: effort = amplifier command [V]
ENCODERS = 'encoders'                  # plant -> controller: raw counts in position
PLANT_STATES = 'plant_states'          # plant ->: ground truth [m, m/s]
AMPLIFIER_STATES = 'amplifier_states'  # plant ->: effort = amplifier output applied [V]
DIAGNOSTICS = '/diagnostics'           # diagnostic_msgs/DiagnosticArray (absolute by convention)
CLOCK = '/clock'                       # rosgraph_msgs/Clock in lockstep simulation
# The trajectory action and state, in the controller node's own namespace (~ = <node>), as
# joint_trajectory_controller names them (control_msgs; msg_defs.follow)
FOLLOW_JOINT_TRAJECTORY = '~/follow_joint_trajectory'   # action FollowJointTrajectory
CONTROLLER_STATE = '~/controller_state'  # controller ->: JointTrajectoryControllerState
QUERY_STATE = '~/query_state'          # service QueryTrajectoryState: desired state at a time

# Per-axis services: name -> std_srvs type name ('SetBool' or 'Trigger').
SERVICES = {
    'enable': 'SetBool',
    'stop': 'Trigger',
    'estop': 'Trigger',
    'abort': 'Trigger',
    'reset': 'Trigger',
    'correct': 'Trigger',
    'excite': 'Trigger',      # start the test signal of the excitation_* registers (gather)
}


def status_topic(axis: str) -> str:
    """`<axis>/status`, std_msgs/UInt32 status word."""
    return f'{axis}/status'


def amplifier_fault_topic(axis: str) -> str:
    """`<axis>/amplifier_fault`, std_msgs/Bool from the plant: true while its command watchdog
    holds the output at 0 V."""
    return f'{axis}/amplifier_fault'


def service_name(axis: str, service: str) -> str:
    return f'{axis}/{service}'


def motor_joint(axis: str) -> str:
    """Joint name of the motor (rotary) encoder of an axis in `encoders` / `plant_states`."""
    return f'{axis}_motor'


def load_joint(axis: str) -> str:
    """Joint name of the load (linear) encoder of an axis in `encoders` / `plant_states`."""
    return f'{axis}_load'


def split_joint(name: str):
    """'x_motor' -> ('x', 'motor'); anything else -> (None, None)."""
    axis, sep, side = name.rpartition('_')
    if sep and axis and side in ('motor', 'load'):
        return axis, side
    return None, None


def gather_topic(axis: str) -> str:
    """`<axis>/gather`, std_msgs/Float64MultiArray from the controller: the per-tick record of
    the last excitation run (msg_defs.gather), latched (GATHER_QOS)."""
    return f'{axis}/gather'
