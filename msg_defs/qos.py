"""QoS profiles of the servo topics.

Servo data (encoders, command, states) is a stream where only the newest sample matters: best
effort, keep last 1 would lose nothing a servo loop needs, but rosbag and `ros2 topic echo`
default to reliable subscriptions, and a reliable subscriber cannot match a best-effort publisher.
So the stream is published reliable with depth 1..10 (a reliable publisher matches both kinds of
subscriber); the loop itself never waits on it. Depth 100 keeps 0.1 s of samples for a
reliable reader that falls behind (a recorder starved for a few ms on a loaded machine) before
the writer drops them. Status words are reliable + transient local so a
late subscriber sees the current word at once.
"""
from rclpy.qos import QoSProfile, ReliabilityPolicy, HistoryPolicy, DurabilityPolicy

SERVO_QOS = QoSProfile(depth=100, reliability=ReliabilityPolicy.RELIABLE,
                       history=HistoryPolicy.KEEP_LAST, durability=DurabilityPolicy.VOLATILE)
COMMAND_QOS = SERVO_QOS
STATUS_QOS = QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE,
                        history=HistoryPolicy.KEEP_LAST,
                        durability=DurabilityPolicy.TRANSIENT_LOCAL)
