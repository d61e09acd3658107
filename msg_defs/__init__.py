"""The wire contract of motion_ctrl, in one place: topic names, QoS profiles, status bits and the
helpers that build and read the standard messages both nodes use (no custom .msg types).

Everything here is the outside of the product as SPEC.md fixes it. Topic names are relative so a
namespace works. Encoder counts travel as float64 in JointState.position (integers carried
exactly up to 2**53).
"""
from msg_defs.status import Status
from msg_defs.topics import (
    COMMAND, ENCODERS, JOINT_STATES, MOTOR_STATES, PLANT_STATES, REFERENCE_STATES,
    AMPLIFIER_STATES, TARGET_POSITION, TARGET_VELOCITY, DIAGNOSTICS, CLOCK, status_topic,
    amplifier_fault_topic, service_name,
    SERVICES, motor_joint, load_joint, split_joint,
)
from msg_defs.qos import SERVO_QOS, SERVO_READ_QOS, STATUS_QOS
from msg_defs.joint_state import (joint_state, read_joint_state, MalformedMessage,
                                 JointStateStream, Stream)

__all__ = [
    'Status', 'COMMAND', 'ENCODERS', 'JOINT_STATES', 'MOTOR_STATES', 'PLANT_STATES',
    'REFERENCE_STATES', 'AMPLIFIER_STATES', 'TARGET_POSITION', 'TARGET_VELOCITY', 'DIAGNOSTICS',
    'CLOCK', 'status_topic', 'amplifier_fault_topic', 'service_name', 'SERVICES', 'motor_joint', 'load_joint', 'split_joint',
    'SERVO_QOS', 'SERVO_READ_QOS', 'STATUS_QOS', 'joint_state', 'read_joint_state',
    'MalformedMessage', 'JointStateStream', 'Stream',
]
