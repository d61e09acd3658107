"""QoS profiles of the servo topics.

Servo data (encoders, command, states) is a stream where only the newest sample matters to the
loop, but rosbag and `ros2 topic echo` default to reliable subscriptions, and a reliable
subscriber cannot match a best-effort publisher. So the streams are published reliable, KEEP_LAST
with a history of one second at 1 kHz (SERVO_QOS): a reliable reader that falls behind for a
moment (a recorder whose process the machine held up for 150 ms was seen losing a burst with a
history of 100) gets every sample, and the publisher never waits. The nodes themselves read the
streams best effort with a short queue (SERVO_READ_QOS): a servo loop wants the newest sample,
not a backlog, and not the repair of a lost one: a reliable reader holds every later sample back
until a lost one is resent, which waits for the writer's next heartbeat (up to seconds, measured
here as feedback faults and targets seen late on a loaded machine). A best-effort reader matches
a reliable writer; a lost sample is replaced by the next one a period later.
Status words are reliable + transient local so a late subscriber sees the current word at once,
with a history of STATUS_DEPTH words: a client that waits for MOTION_DONE to clear and rise
again must get every change, and a controller that is its own clock (hardware sim, sim time)
makes a move's changes within a millisecond of wall time; a reliable writer keeping only the
last few would drop the older ones before a busy reader took them. A late joiner gets that
history, oldest first (the bridge's copy on the user's domain keeps the last
ros.servo_bus.bridge.STATUS_WORDS_DEPTH words, and the word is republished at 10 Hz: a second
after a change they are all the current word). A client that waits for a move's MOTION_DONE
reads the words published from its start on (STATUS_CHANGES_QOS, volatile): a history arriving
after it sent its target would show an earlier move's MOTION_DONE cleared and raised; its first
word comes with the next change or refresh. The record of an excitation run is reliable and
transient local too (GATHER_QOS, the last run only): a reader that joins or loses a sample
late still gets the whole record, repaired by the reliable protocol; an amplifier's fault flag
(LATCHED_QOS) keeps only its current value.
"""
from rclpy.qos import QoSProfile, ReliabilityPolicy, HistoryPolicy, DurabilityPolicy

SERVO_QOS = QoSProfile(depth=1000, reliability=ReliabilityPolicy.RELIABLE,
                       history=HistoryPolicy.KEEP_LAST, durability=DurabilityPolicy.VOLATILE)
SERVO_READ_QOS = QoSProfile(depth=10, reliability=ReliabilityPolicy.BEST_EFFORT,
                            history=HistoryPolicy.KEEP_LAST, durability=DurabilityPolicy.VOLATILE)
STATUS_DEPTH = 100
STATUS_QOS = QoSProfile(depth=STATUS_DEPTH, reliability=ReliabilityPolicy.RELIABLE,
                        history=HistoryPolicy.KEEP_LAST,
                        durability=DurabilityPolicy.TRANSIENT_LOCAL)
STATUS_CHANGES_QOS = QoSProfile(depth=STATUS_DEPTH, reliability=ReliabilityPolicy.RELIABLE,
                                history=HistoryPolicy.KEEP_LAST,
                                durability=DurabilityPolicy.VOLATILE)
# A latched value (an amplifier's fault flag): a late joiner gets the current one only.
LATCHED_QOS = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE,
                         history=HistoryPolicy.KEEP_LAST,
                         durability=DurabilityPolicy.TRANSIENT_LOCAL)
GATHER_QOS = LATCHED_QOS
