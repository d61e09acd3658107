"""A small rclpy client of the controller and plant: command moves, watch status and truth.

Used by the demo, the DDS tests and the benchmark. It talks only through the public contract
(msg_defs topics), as any ROS user would.
"""
from __future__ import annotations

import time

from builtin_interfaces.msg import Time
from rclpy.node import Node
from sensor_msgs.msg import JointState
from std_msgs.msg import UInt32
from std_srvs.srv import SetBool, Trigger
from trajectory_msgs.msg import JointTrajectory

import msg_defs as md
from motion_ctrl.ros import ros_env
from msg_defs.status import Status


FAULTS = Status.FOLLOWING_ERROR_FATAL | Status.FEEDBACK_FAULT | Status.OVERSPEED


class SlideClient(Node):
    def __init__(self, axes=('x',), name='slide_client', context=None, services=False,
                 truth=True):
        super().__init__(name, context=context)
        # (The client shares two cores with two 1 kHz nodes: the lighter executor leaves them
        # more room.)
        self.executor_ = ros_env.executor(self.context)
        self.executor_.add_node(self)
        self.axes = list(axes)
        self.pub_target = self.create_publisher(JointState, md.TARGET_POSITION, 10)
        self.pub_velocity = self.create_publisher(JointState, md.TARGET_VELOCITY, 10)
        self.pub_trajectory = self.create_publisher(JointTrajectory, md.JOINT_TRAJECTORY, 10)
        self.truth = None          # latest plant_states {joint: position}
        self.truth_stamp = float('-inf')
        self.done_at = float('-inf')  # wall time this client last saw MOTION_DONE raised
        self.status = {a: None for a in self.axes}
        self.status_log = {a: [] for a in self.axes}     # (monotonic time, word)
        # truth=False: a tool that must work against real hardware (calibrate) neither reads
        # the simulation's ground truth nor waits for it.
        self.wants_truth = truth
        if truth:
            self.create_subscription(JointState, md.PLANT_STATES, self._on_truth,
                                     md.SERVO_READ_QOS)
        for a in self.axes:
            self.create_subscription(UInt32, md.status_topic(a),
                                     lambda m, a=a: self._on_status(a, m),
                                     md.STATUS_CHANGES_QOS)
        # The axis services' clients, made now when asked for: a client (a new reader) joining
        # later holds the controller up while Fast DDS health-checks its port (doc/design_notes.md).
        self.axis_services = {
            (a, name): self.create_client(SetBool if kind == 'SetBool' else Trigger,
                                          md.service_name(a, name))
            for a in (self.axes if services else ()) for name, kind in md.SERVICES.items()}

    def _on_truth(self, msg):
        self.truth = dict(zip(msg.name, msg.position))
        self.truth_stamp = msg.header.stamp.sec + msg.header.stamp.nanosec * 1e-9

    def truth_since(self, stamp: float, timeout: float = 2.0) -> bool:
        """Wait for a plant_states sample stamped at or after `stamp` (s, the plant's clock):
        the user's copy of a stream can lag a loaded machine (doc/design_notes.md)."""
        return self.spin_until(lambda: self.truth_stamp >= stamp, timeout)

    def _on_status(self, axis, msg):
        if msg.data != self.status[axis]:
            self.status_log[axis].append((time.monotonic(), msg.data))
            if msg.data & Status.MOTION_DONE:
                self.done_at = time.time()
        self.status[axis] = msg.data

    def spin_for(self, seconds: float) -> None:
        """Run the callbacks for `seconds` of wall time, where the time is the point (cruise a
        while, let the latest samples arrive); to wait for something, spin_until it."""
        end = time.monotonic() + seconds
        while (left := end - time.monotonic()) > 0:
            self.executor_.spin_once(timeout_sec=min(0.01, left))

    def spin_until(self, predicate, timeout: float) -> bool:
        end = time.monotonic() + timeout
        while time.monotonic() < end:
            if predicate():
                return True
            self.executor_.spin_once(timeout_sec=0.01)
        return bool(predicate())

    def answer(self, send, timeout: float = 10.0, resend_after: float = 1.0):
        """The response to a service request; `send()` sends it and returns the future.

        A request not answered within `resend_after` seconds is sent again (use it for requests
        that may be repeated: parameter services, enable, stop, reset, ...): until discovery has
        matched the server's response writer with our response reader, which can lag behind
        the request side by more than a second on a loaded machine, Fast DDS drops a response it
        cannot deliver within 100 ms (ros2/rmw_fastrtps#418). Raises TimeoutError.
        """
        futures = [send()]
        start = time.monotonic()
        while not any(f.done() for f in futures):
            elapsed = time.monotonic() - start
            if elapsed >= timeout:
                raise TimeoutError(f'no answer in {timeout:g} s to {len(futures)} request(s)')
            if elapsed >= len(futures) * resend_after:
                futures.append(send())
            self.executor_.spin_once(timeout_sec=0.01)
        return next(f for f in futures if f.done()).result()

    def call(self, service: str, data: bool | None = None, timeout: float = 5.0, axis=None):
        """Call `<axis>/<service>` (the first axis by default; SetBool with `data`, else
        Trigger) and return the response (services=True in the constructor)."""
        client = self.axis_services[(axis or self.axes[0], service)]
        if not self.spin_until(client.service_is_ready, timeout):
            raise TimeoutError(f'{service} not available')
        request = SetBool.Request(data=data) if data is not None else Trigger.Request()
        return self.answer(lambda: client.call_async(request), timeout)

    def wait_ready(self, timeout: float = 15.0) -> bool:
        """Discovery done and the loop running: subscribers matched, status and truth seen."""
        return self.spin_until(lambda: not self.not_ready(), timeout)

    def not_ready(self) -> str:
        """What wait_ready still waits for ('' when ready)."""
        if self.pub_target.get_subscription_count() == 0:
            return 'no controller subscribed to target_position yet'
        if self.wants_truth and self.truth is None:
            return 'no plant_states received yet'
        words = {a: s for a, s in self.status.items() if s is None or not s & Status.ENABLED}
        if words:
            return 'axes not enabled: ' + ', '.join(
                f'{a} ' + ('no status' if s is None else repr(Status(s))) for a, s in words.items())
        return ''

    def move_done(self, axis: str, mark: int) -> bool:
        """MOTION_DONE cleared and then raised again in the status words of `axis` since `mark`
        (an index into status_log). The RMP way to wait for a move: accepting a move clears
        MOTION_DONE. (Not MOVING: a move that ends within one servo period, a fraction of a
        count or a tick the loaded machine skipped, never shows it.)"""
        cleared = False
        for _, word in self.status_log[axis][mark:]:
            if not word & Status.MOTION_DONE:
                cleared = True
            elif cleared:
                return True
        return False

    def settle_after_profile(self, axis: str, mark: int) -> float | None:
        """Seconds from the end of the profile (AT_TARGET rises) to MOTION_DONE in the status
        words of `axis` since `mark` (an index into status_log), by their arrival here; None
        when the move has not shown both."""
        log = self.status_log[axis][mark:]
        i0 = next((i for i, (_, w) in enumerate(log) if not w & Status.MOTION_DONE), None)
        if i0 is None:
            return None
        end = next((i for i in range(i0, len(log)) if log[i][1] & Status.AT_TARGET), None)
        if end is None:
            return None
        done = next((i for i in range(end, len(log)) if log[i][1] & Status.MOTION_DONE), None)
        return None if done is None else log[done][0] - log[end][0]

    def move(self, targets: dict, timeout: float = 5.0):
        """Publish a target set; wait until every axis has cleared and raised MOTION_DONE.

        Returns seconds from publish to the last MOTION_DONE, or None on timeout or when an axis
        faulted instead (a fault opens the loop, which also raises MOTION_DONE): `status` then
        shows the fault bits.
        """
        msg = md.joint_state(self.get_clock().now().to_msg(), list(targets),
                             list(targets.values()))
        return self._send_and_wait(self.pub_target, msg, list(targets), timeout)

    def follow(self, names, times, positions, velocities=None, accelerations=None,
               timeout: float = 5.0):
        """Send a joint_trajectory (starting now) and wait as `move` does, `timeout` after its
        last point; returns as `move`."""
        self.spin_until(lambda: self.pub_trajectory.get_subscription_count() > 0, 5.0)
        msg = md.joint_trajectory(Time(), names, times, positions, velocities, accelerations)
        return self._send_and_wait(self.pub_trajectory, msg, list(names),
                                   max(times) + timeout)

    def stop_jogs(self, axes: list, timeout: float = 5.0):
        """Jog `axes` to 0 velocity and wait as `move` does (MOTION_DONE at rest)."""
        msg = md.joint_state(self.get_clock().now().to_msg(), list(axes),
                             velocity=[0.0] * len(axes))
        return self._send_and_wait(self.pub_velocity, msg, list(axes), timeout)

    def _send_and_wait(self, publisher, msg, axes: list, timeout: float):
        marks = {a: len(self.status_log[a]) for a in axes}
        t0 = time.monotonic()
        publisher.publish(msg)
        return self.wait_moves(marks, t0, timeout)

    def wait_moves(self, marks: dict, t0: float, timeout: float):
        """Wait until every axis of `marks` ({axis: index into status_log}) has cleared and
        raised MOTION_DONE since its mark; returns seconds from `t0` (time.monotonic) to the
        last MOTION_DONE, or None on timeout or on a fault in the words since the marks."""
        def faulted():
            return any(w & FAULTS for a, m in marks.items() for _, w in self.status_log[a][m:])
        if not self.spin_until(
                lambda: faulted() or all(self.move_done(a, m) for a, m in marks.items()),
                timeout) or faulted():
            return None
        last = max(next(t for t, w in reversed(self.status_log[a]) if w & Status.MOTION_DONE)
                   for a in marks)
        return last - t0

    def load_position(self, axis='x') -> float:
        """The true slide position, from a plant_states sample stamped after the last
        MOTION_DONE this client saw (waits up to 2 s for one)."""
        self.truth_since(self.done_at)
        return self.truth[md.load_joint(axis)]
