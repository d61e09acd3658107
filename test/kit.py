"""The test kit: units, and the slide (plant + controller as processes, with a client) that the
DDS tests run against.

Imports no ROS package itself (the core tests take their units from here); ROS comes in when a
slide starts. The ROS domain and the node environment stay the fixtures of conftest
(module_domain, own_domain, node_env).
"""
from __future__ import annotations

import contextlib
import os
import pathlib
import socket
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from typing import Any

import pytest

from motion_ctrl.core.registers import INCH, LOAD_COUNTS_PER_M, MOTOR_COUNTS_PER_M, axis_defaults

__all__ = ['INCH', 'COUNT', 'MOTOR_COUNT', 'LOAD_COUNTS_PER_M', 'MOTOR_COUNTS_PER_M', 'Slide',
           'running_slide', 'spin_for', 'DUAL_REGISTERS', 'enabled_xy']

COUNT = 1 / LOAD_COUNTS_PER_M          # one linear (slide encoder) count [m]: 2.54 um
MOTOR_COUNT = 1 / MOTOR_COUNTS_PER_M   # one motor encoder count, in slide travel [m]


# The default axis on both encoders, with the slide's Coulomb friction fed forward.
DUAL_REGISTERS = axis_defaults() | {'feedback': 'dual', 'friction_ff': 0.24}


def enabled_xy():
    """An in-process harness (no ROS) of two such axes, x and y, enabled and at rest."""
    from motion_ctrl.sim.harness import Harness
    h = Harness(DUAL_REGISTERS, axes=('x', 'y'), record=False)
    h.run(0.05)
    for a in h.axes.values():
        assert a.enable(True)[0]
    h.run(0.2)
    return h


def long_run(what: str):
    """Opt-in (MOTION_CTRL_LONG=1) for a test of minutes or one that repeats what another test
    in the default suite already shows on a shorter path: the suite stays well inside CI's 15
    minutes. `what` says how long and what covers it meanwhile."""
    return pytest.mark.skipif(os.environ.get('MOTION_CTRL_LONG') != '1',
                              reason=f'opt-in, {what}: MOTION_CTRL_LONG=1')


def spin_for(client, seconds: float) -> None:
    """`client.spin_for(seconds)` (SlideClient): the time is the point, not a condition."""
    client.spin_for(seconds)


# What the nodes log when the DDS link between plant and controller stalled: no encoder sample,
# no command (conftest.pytest_runtest_protocol reruns a failed test that saw one).
SERVO_LINK_STALLS = ('FEEDBACK_FAULT: no new encoder sample', 'amplifier fault: no command')


def stall_line(*texts: str) -> str:
    """The first line of `texts` that says the servo link stalled ('' for none)."""
    return next((line for text in texts for line in text.splitlines()
                 if any(s in line for s in SERVO_LINK_STALLS)), '')


def link_stall(item, *texts: str) -> str:
    """The first line of `texts` that says the servo link stalled ('' for none, or for a test
    marked servo_link_under_test)."""
    if item.get_closest_marker('servo_link_under_test') is not None:
        return ''
    return stall_line(*texts)


def note_link_stalls(request, *texts: str) -> None:
    """Note on the test the first line of `texts` (what the nodes logged during it) that says
    the servo link stalled."""
    request.node.servo_link_stalled = link_stall(request.node, *texts)


@dataclass
class Slide:
    """The nodes of a running slide and the client watching it. A test that replaces a node
    (a restarted controller) assigns it here, and that one is stopped at the end."""
    plant: Any                  # motion_ctrl.ros.processes.NodeProcess (None: hardware sim)
    controller: Any
    client: Any                 # a SlideClient
    log_dir: pathlib.Path

    def log(self, node: str) -> str:
        path = self.log_dir / f'{node}.log'
        return path.read_text(errors='replace') if path.exists() else ''


@contextlib.contextmanager
def running_slide(log_dir, make_client: Callable[[], Any], controller_params: dict | None = None,
                  plant_params: dict | None = None, *, client_first: bool = False,
                  ready: Callable[[Any], bool] | None = None, timeout: float = 30.0,
                  exit_zero: bool = False, plant_env: dict | None = None,
                  hardware: str = 'topics') -> Iterator[Slide]:
    """Plant and controller as processes (motion_ctrl.ros.processes.start_slide: the params
    files plus these overrides, logs in `log_dir`; `hardware` sim: the controller alone, the
    slide in its loop, the plant's parameters its own, start_sim) and the client
    `make_client()` makes (before the nodes with client_first); yields when the client sees the
    slide ready (SlideClient.wait_ready, then `ready(client)` if given), else fails with what
    was missing and the nodes' logs.

    `plant_env`: added to the plant's environment (start_slide). At the end the client goes and
    both nodes stop with SIGINT; exit_zero: both must exit 0.
    The nodes inherit this process's environment: the module's ROS domain (conftest
    module_domain), or the test's (own_domain)."""
    from motion_ctrl.ros.processes import start_sim, start_slide
    log_dir = pathlib.Path(log_dir)
    client = make_client() if client_first else None
    if hardware == 'sim':
        plant, (controller,) = None, start_sim(controller_params, plant_params, log_dir=log_dir)
    else:
        plant, controller = start_slide(controller_params, plant_params, log_dir=log_dir,
                                        plant_env=plant_env)
    slide = Slide(plant, controller, client, log_dir)
    try:
        if client is None:
            client = slide.client = make_client()
        if not (client.wait_ready(timeout) and (ready is None or ready(client))):
            import pytest
            missing = client.not_ready() or 'the ready check failed'
            pytest.fail(f'plant + controller did not come up ({missing}); logs in {log_dir}'
                        '\ncontroller log:\n'
                        f'{slide.log("controller")[-3000:]}\nplant log:\n'
                        f'{slide.log("plant")[-3000:]}')
        yield slide
    finally:
        if client is not None:
            client.destroy_node()
        codes = {'controller': slide.controller.stop()}
        if slide.plant is not None:
            codes['plant'] = slide.plant.stop()
    if exit_zero:
        assert set(codes.values()) == {0}, f'exit codes {codes}; logs in {log_dir}'


def ip_sockets(pid: int) -> list[tuple[str, str, int]]:
    """(protocol, bound address, port) of each IP socket process `pid` holds."""
    inodes = {t[len('socket:['):-1] for t in (os.readlink(f) for f in
              pathlib.Path(f'/proc/{pid}/fd').iterdir() if f.is_symlink())
              if t.startswith('socket:[')}
    out = []
    for proto, family in (('udp', socket.AF_INET), ('udp6', socket.AF_INET6),
                          ('tcp', socket.AF_INET), ('tcp6', socket.AF_INET6)):
        for line in pathlib.Path(f'/proc/{pid}/net/{proto}').read_text().splitlines()[1:]:
            fields = line.split()
            if fields[9] in inodes:
                address, port = fields[1].split(':')
                raw = bytes.fromhex(address)     # (/proc prints each 32-bit word little-endian)
                raw = b''.join(raw[i:i + 4][::-1] for i in range(0, len(raw), 4))
                out.append((proto, socket.inet_ntop(family, raw), int(port, 16)))
    return sorted(out)
