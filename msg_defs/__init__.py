"""The wire contract of motion_ctrl, in one place: topic names, QoS profiles, status bits and the
helpers that build and read the standard messages both nodes use (no custom .msg types).

Everything here is the outside of the product as doc/interface.md fixes it. Topic names are
relative so a namespace works. Encoder counts travel as float64 in JointState.position
(integers carried exactly up to 2**53).
"""
from msg_defs.status import Status
from msg_defs.topics import (
    COMMAND, ENCODERS, JOINT_STATES, MOTOR_STATES, PLANT_STATES, REFERENCE_STATES,
    AMPLIFIER_STATES, TARGET_POSITION, TARGET_VELOCITY, MAX_TARGET_BYTES, JOINT_TRAJECTORY,
    DIAGNOSTICS, CLOCK, FOLLOW_JOINT_TRAJECTORY, CONTROLLER_STATE, QUERY_STATE,
    status_topic,
    amplifier_fault_topic, service_name,
    SERVICES, motor_joint, load_joint, split_joint, gather_topic,
)

# The ROS half (QoS profiles need rclpy, message helpers sensor_msgs) is imported when first
# used (PEP 562), so that `msg_defs.status` and `msg_defs.topics`, which the servo core uses,
# import on a machine without ROS.
_LAZY = {
    'SERVO_QOS': 'msg_defs.qos', 'SERVO_READ_QOS': 'msg_defs.qos', 'STATUS_QOS': 'msg_defs.qos',
    'STATUS_CHANGES_QOS': 'msg_defs.qos', 'LATCHED_QOS': 'msg_defs.qos',
    'STATUS_DEPTH': 'msg_defs.qos',
    'joint_state': 'msg_defs.joint_state', 'read_joint_state': 'msg_defs.joint_state',
    'MalformedMessage': 'msg_defs.joint_state', 'JointStateStream': 'msg_defs.joint_state',
    'Stream': 'msg_defs.joint_state',
    'joint_trajectory': 'msg_defs.trajectory', 'read_joint_trajectory': 'msg_defs.trajectory',
    'trajectory_counts': 'msg_defs.trajectory',
    'GATHER_QOS': 'msg_defs.qos', 'gather_message': 'msg_defs.gather',
    'read_gather': 'msg_defs.gather',
}


def __getattr__(name: str):
    module = _LAZY.get(name)
    if module is None:
        raise AttributeError(f'module {__name__!r} has no attribute {name!r}')
    import importlib
    loaded = importlib.import_module(module)
    # Every name of that module at once: importing `msg_defs.joint_state` binds the package's
    # `joint_state` to the module, which would hide the function of that name from here on.
    for lazy, where in _LAZY.items():
        if where == module:
            globals()[lazy] = getattr(loaded, lazy)
    return globals()[name]


__all__ = [
    'Status', 'COMMAND', 'ENCODERS', 'JOINT_STATES', 'MOTOR_STATES', 'PLANT_STATES',
    'REFERENCE_STATES', 'AMPLIFIER_STATES', 'TARGET_POSITION', 'TARGET_VELOCITY',
    'MAX_TARGET_BYTES',
    'JOINT_TRAJECTORY', 'DIAGNOSTICS', 'FOLLOW_JOINT_TRAJECTORY', 'CONTROLLER_STATE', 'QUERY_STATE',
    'CLOCK', 'status_topic', 'amplifier_fault_topic', 'service_name', 'SERVICES', 'motor_joint',
    'load_joint', 'split_joint',
    'SERVO_QOS', 'SERVO_READ_QOS', 'STATUS_QOS', 'STATUS_CHANGES_QOS', 'LATCHED_QOS',
    'STATUS_DEPTH', 'joint_state', 'read_joint_state',
    'MalformedMessage', 'JointStateStream', 'Stream', 'joint_trajectory',
    'read_joint_trajectory', 'trajectory_counts', 'gather_topic', 'GATHER_QOS',
    'gather_message', 'read_gather',
]
