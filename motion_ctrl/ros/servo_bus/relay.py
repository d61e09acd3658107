"""Your domain opened to other hosts, the servo bus kept on this one.

A process holds one Fast DDS profile for all its participants, and the bridge's process holds
a participant on the bus, bound to 127.0.0.1 (servo_bus.xml): its participant on your domain
can reach this host only. When your environment reaches beyond this host
(`ROS_AUTOMATIC_DISCOVERY_RANGE=SUBNET` or `SYSTEM_DEFAULT`, `ROS_STATIC_PEERS`, a
`ROS_DISCOVERY_SERVER`), the bridge's user side goes onto a *local domain* instead (LOCAL_OFFSET
from ROS_DOMAIN_ID, this host only), and a relay process of its own, started with your
environment untouched, mirrors the node from there onto your domain: the same Bridge, one hop
further. Its participant on the local domain discovers on this host only; its participant on
your domain is what the other hosts reach.

    your domain, other hosts   relay process            bridge process     loop process
    ---------------------------|--- local domain --------|--- servo bus ----|-----------
                               (your environment)         (127.0.0.1 only)

What a relay never does is copy a servo stream in: `command` or `encoders` published on your
domain reaches no loop, and the relay names the node once a second in its log and on
/diagnostics (servo_bus.commander); a plant or controller of another make runs on the
controller's host.
"""
from __future__ import annotations

import os
import signal
import subprocess
import sys
import time

from motion_ctrl.ros import ros_env
from motion_ctrl.ros.processes import child_preexec, source_env

LOCAL_OFFSET = 75            # the local domain: ROS_DOMAIN_ID + 75, wrapped in 1..101
REACHING = ('SUBNET', 'SYSTEM_DEFAULT')
PEER_VARS = ('ROS_STATIC_PEERS', 'ROS_DISCOVERY_SERVER', 'ROS_SUPER_CLIENT')
# The relay's participant on the local domain: on this host only, whatever yours reaches.
LOCAL_SIDE = {ros_env.RANGE_ENV: 'LOCALHOST'} | {k: None for k in PEER_VARS}


def reaches_other_hosts(environ=os.environ) -> bool:
    """Whether a ROS process of this environment discovers beyond this host."""
    return (environ.get(ros_env.RANGE_ENV, '').strip().upper() in REACHING
            or any(environ.get(k, '').strip() for k in PEER_VARS[:2]))


def local_domain(environ=os.environ) -> int:
    """The local domain of ROS_DOMAIN_ID: not it, not the servo bus's (50 above it)."""
    return (int(environ.get('ROS_DOMAIN_ID') or 0) + LOCAL_OFFSET) % 101 + 1


def start(name: str, namespace: str, local: int, user_env: dict) -> subprocess.Popen:
    """The relay of node `name` in `namespace` from domain `local` onto your domain, a child of
    this process (it ends with it), in `user_env`: your environment as you started the node."""
    # (a profile of ours that a tool handed down is not yours: loopback only)
    env = {k: v for k, v in user_env.items()
           if not (k in ros_env.PROFILES_ENV and ros_env.profile_is_ours(v))}
    # With a discovery server, a client learns only of the endpoints that match its own: the
    # relay must see every publisher of a servo stream on your domain to refuse it by name.
    if env.get('ROS_DISCOVERY_SERVER', '').strip():
        env.setdefault('ROS_SUPER_CLIENT', 'TRUE')
    return subprocess.Popen(
        [sys.executable, '-m', 'motion_ctrl.ros.servo_bus', 'relay', name, namespace, str(local)],
        env=source_env(env), preexec_fn=child_preexec)


def main(argv: list[str]) -> int:
    """argv: ['relay', name, namespace, local domain] (servo_bus.__main__)."""
    from motion_ctrl.ros.servo_bus import _Bus
    name, namespace, local = argv[1], argv[2], int(argv[3])
    stop: list[int] = []
    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, lambda s, _f: stop.append(s))
    bus = _Bus.open(local, name, namespace, servo_env=LOCAL_SIDE, relay=True)
    bus.bridge.log(f'relay: {namespace.rstrip("/")}/{name} mirrored from the local domain '
                   f'{local} onto domain {os.environ.get("ROS_DOMAIN_ID", "0")}, which reaches '
                   f'other hosts; the servo bus stays on this one')
    try:
        while not stop:
            time.sleep(0.1)
    finally:
        ros_env.leave_if_stuck(name, 3.0, 0, 'closing the relay')
        bus.close()
    return 0

