"""A node's process from start to exit, for every node of the package (controller, plant,
virtual drive): `run` starts it (on the servo bus through its bridge, ros.servo_bus, unless
this is the bus's own process), refuses a bad start-up value with one line and exit code 2, and
`spin`s it until SIGINT or SIGTERM with the process watchdog armed (PMAC's watchdog timer: a
loop that stands still WATCHDOG s ends the process) and the stop deadline behind the signals
(STOP_DEADLINE: a stopped node leaves whatever ROS's teardown is doing). Before it leaves, a
node's `shutdown_outputs()` makes its outputs safe (the controller: loops open, 0 V). Why each
rule: doc/design_notes.md, "Stopping a node: the deadline and the watchdog".
"""
from __future__ import annotations

import faulthandler
import gc
import os
import signal
import sys
import threading
import time

import rclpy
from rclpy.exceptions import (InvalidParameterTypeException, InvalidParameterValueException,
                              ParameterException)
from rclpy.signals import SignalHandlerOptions

from motion_ctrl.core.hardware import HardwareError
from motion_ctrl.ros import ros_env, ros_params, servo_bus

STOP_DEADLINE = 3.0      # s from SIGINT/SIGTERM to exit, whatever ROS's teardown is doing
WATCHDOG = 5.0           # s the spin loop may stand still before the process ends (exit 1)


def spin(node) -> None:
    """Spin on ros_env.executor() until SIGINT or SIGTERM.

    The signals only raise a flag: the context is shut down after the last callback returned,
    so no callback publishes on a dead context. Before that a node's `shutdown_outputs()`, if
    it has one, leaves its outputs safe (the controller: loops open, 0 V).
    """
    executor = ros_env.executor()
    executor.add_node(node)
    # What start-up made (imports, the node) stays: the cyclic collector's full passes would
    # walk it all, ~20 ms with the servo thread held, enough for a FEEDBACK_FAULT or an
    # amplifier-watchdog trip; frozen, they walk only what the loop makes (doc/design_notes.md,
    # "Python's own pauses in the servo thread").
    gc.collect()
    gc.freeze()
    stop_on_signals(node.get_name())
    pet = 0.0
    step = getattr(node, 'spin_step', None)
    try:
        while _RUNNING and rclpy.ok():
            if step is None:
                executor.spin_once(timeout_sec=0.05)
            else:
                step(executor)
            now = time.monotonic()
            if now >= pet:
                # The process watchdog (PMAC's watchdog timer): a loop stuck WATCHDOG s ends the
                # process from faulthandler's own thread, which needs no GIL. rclpy keeps the GIL
                # through publish(), which can block on a SIGKILLed peer's shared-memory port:
                # then no SIGTERM is handled and the stop deadline (a Python thread) never runs.
                # The amplifiers' command watchdog keeps the axes safe meanwhile.
                faulthandler.dump_traceback_later(WATCHDOG, exit=True, file=sys.stderr)
                pet = now + WATCHDOG / 10
    finally:
        safe = getattr(node, 'shutdown_outputs', None)
        if safe is not None and rclpy.ok():
            try:
                safe()
            except Exception as e:          # (still shut down; say why the outputs may not be)
                print(f'{node.get_name()}: shutdown_outputs failed: {e!r}', file=sys.stderr)
        executor.shutdown()
        node.destroy_node()
        rclpy.try_shutdown()
        faulthandler.cancel_dump_traceback_later()     # (armed until the teardown is done)


# Emptied by the first SIGINT / SIGTERM once stop_on_signals ran. Not a threading.Event: a signal
# handler must take no lock, since a second signal can run the handler again inside the first,
# which would then wait for the lock the outer call holds (doc/design_notes.md, "Stopping a node:
# the deadline and the watchdog").
_RUNNING = ['running']


def stop_on_signals(name: str) -> None:
    """From now on SIGINT and SIGTERM only raise the stop flag that `spin` watches (and start
    the stop deadline): a signal while the node is still being made ends it as cleanly as one
    while it spins, without a KeyboardInterrupt traceback.

    The deadline (ros_env.leave_if_stuck, STOP_DEADLINE): the outputs are made safe first
    (`shutdown_outputs`, and the plant's command watchdog behind it); what is left, ROS's
    teardown of the node and its DDS participant, can hang and must not keep a stopped node
    alive (doc/design_notes.md, "Stopping a node: the deadline and the watchdog")."""
    def on_signal(*_):
        try:
            _RUNNING.pop()           # (one C call: of handlers run inside each other, one goes on)
        except IndexError:
            return
        ros_env.leave_if_stuck(name, STOP_DEADLINE)
    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, on_signal)


def run(node_class, args=None) -> int:
    """Start a node; a bad parameter (from a YAML or the command line) exits 2 with one line."""
    ros_env.local_discovery()
    # The loop runs on the servo bus in a process of its own; this one bridges it (issue 11).
    bridged = servo_bus.supervise(f'motion_ctrl.ros.{node_class.NODE_NAME}_node',
                                  node_class.NODE_NAME, list(args or sys.argv))
    if bridged is not None:
        return bridged
    stop_on_signals(node_class.NODE_NAME)
    try:
        rclpy.init(args=args, signal_handler_options=SignalHandlerOptions.NO)
    except RuntimeError as e:          # rclpy's RCLError: e.g. a malformed -p override
        print(f'{node_class.__name__}: bad arguments: {str(e).splitlines()[0]}'
              f'{ros_params.yaml_bool_hint(str(e))}', file=sys.stderr)
        return 2
    argv = list(args or sys.argv)
    refusal = ros_params.params_files_refusal(node_class.NODE_NAME, argv,
                                              getattr(node_class, 'ALSO_SECTIONS', ()))
    if refusal:
        print(f'{node_class.__name__}: {refusal}', file=sys.stderr)
        rclpy.try_shutdown()
        return 2
    try:
        node = node_class(**({'params_files': ros_params.params_files(argv)}
                             if getattr(node_class, 'ALSO_SECTIONS', ()) else {}))
    except (InvalidParameterValueException, InvalidParameterTypeException,
            ParameterException, ValueError, HardwareError) as e:
        # rclpy's range refusal reads "Invalid parameter value (v) for parameter. Reason: <why>:
        # <name>"; the reason names the parameter too.
        msg = str(e).split('Reason: ', 1)[-1].splitlines()[0] if str(e) else type(e).__name__
        hardware = isinstance(e, HardwareError)
        where = None if hardware else ros_params.where_from(msg, argv)
        what = 'hardware' if hardware else 'bad parameter'
        print(f'{node_class.__name__}: {what}{f" (from {where})" if where else ""}: '
              f'{msg}', file=sys.stderr, flush=True)
        # The context's shutdown destroys the half-built node, and rclpy's wait for its handle
        # to be free can hang (doc/design_notes.md, "Stopping a node: the deadline and the
        # watchdog"): it gets 2 s, then the process leaves.
        closing = threading.Thread(target=rclpy.try_shutdown, daemon=True)
        closing.start()
        closing.join(2.0)
        if closing.is_alive():
            os._exit(2)
        return 2
    problem = ros_env.realtime(node.get_parameter('realtime_priority').value)
    if problem:
        node.get_logger().warning(problem)
    spin(node)
    # What spin froze is collected now, the node with it (its worker threads have ended):
    # alive at the interpreter's exit, it would outlive the extension modules, and nanobind
    # would report ruckig's objects as leaked (~30 lines on every stop).
    del node
    gc.unfreeze()
    gc.collect()
    return 0
