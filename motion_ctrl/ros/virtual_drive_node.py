"""The `virtual_drive` node: emulated CiA 402 drives (motion_ctrl.canopen.virtual_drive) on a CAN
bus, one backlash slide behind each, for a controller with `hardware: canopen` to drive as it
would drive real ones.

Parameters: the controller's `can_interface`, `can_channel`, `can_bitrate` and, per axis,
`<axis>.can_node_id` and `<axis>.load_encoder_node_id` (a CiA 406 encoder node on the slide when
not 0); the plant's physics registers (`<axis>.slide_mass`, ..., `<axis>.command_timeout` is the
drive's communication watchdog); and what the drive can be made to do wrong
(`<axis>.inject_fault`, `device_type`, `supported_modes`, `refuse_mapping`). The slides step one
communication cycle per SYNC (the controller is the clock) and on their own clock when SYNCs
stop. `plant_states`, `amplifier_states` and `<axis>/amplifier_fault` (true while the
communication watchdog holds the drive in its fault) are published as the plant node publishes
them, at PUBLISH_RATE; a drive's fault and its recovery are logged with the error code.

Like the plant, it runs in a process of its own on the servo bus (ros.servo_bus), bridged to
the user's domain: a ROS tool joining the graph holds up the bridge, not the drives' thread.
"""
from __future__ import annotations

import sys

from motion_ctrl.canopen import cia402 as c
from motion_ctrl.canopen.virtual_drive import RPDO_TIMEOUT, DriveConfig, DrivesProcess
from motion_ctrl.core.hardware import HardwareError
from motion_ctrl.core.registers import (PLANT_AXIS, VIRTUAL_DRIVE_AXIS, VIRTUAL_DRIVE_GLOBALS,
                                        plant_consistency)
from motion_ctrl.ros import ros_params
from motion_ctrl.ros.node_runner import run
from motion_ctrl.ros.hardware_topics import stamp_of
from motion_ctrl.ros.plant_states import PlantStates

PUBLISH_RATE = 1000.0        # Hz of plant_states / amplifier_states


class VirtualDriveNode(ros_params.RegisterNode):
    NODE_NAME = 'virtual_drive'

    def __init__(self, **kwargs):
        super().__init__(self.NODE_NAME, **kwargs)
        self.globals_table = {r.name: r for r in VIRTUAL_DRIVE_GLOBALS}
        self.axis_table = {r.name: r for r in VIRTUAL_DRIVE_AXIS}
        self.consistency = self._plant_consistency
        g = {r.name: ros_params.declare(self, r, r.name) for r in VIRTUAL_DRIVE_GLOBALS}
        self.axis_names = list(g['axes'])
        self.values = {a: {r.name: ros_params.declare(self, r, f'{a}.{r.name}')
                           for r in VIRTUAL_DRIVE_AXIS} for a in self.axis_names}
        self.refuse_unknown_overrides()
        configs = {}
        for a, v in self.values.items():
            configs[a] = DriveConfig(
                v['can_node_id'], v['load_encoder_node_id'],
                plant={k: x for k, x in v.items() if k in PLANT_AXIS},
                device_type=v['device_type'], supported_modes=v['supported_modes'],
                refuse_mapping=v['refuse_mapping'])
        # The drives run in a process of their own (DrivesProcess): their thread answers the
        # SYNCs without waiting on this one's interpreter
        self.drives = DrivesProcess(configs, g['can_interface'], g['can_channel'],
                                    g['can_bitrate'], substep_rate=g['substep_rate'])
        try:
            self.drives.start()
        except RuntimeError as e:
            raise HardwareError(f'virtual_drive: {e}') from None
        self.add_on_set_parameters_callback(self.validate)
        self.add_post_set_parameters_callback(self._apply)
        self.states = PlantStates(self, self.axis_names, {
            a: v['command_timeout'] for a, v in self.values.items()})
        self.reported = {a: (c.SWITCH_ON_DISABLED, 0) for a in self.axis_names}
        self._published = -1.0
        self._truth: list = []
        self._states: list[tuple[str, int]] = []
        self.timer = self.create_timer(1.0 / PUBLISH_RATE, self._publish)
        ids = ', '.join(f'{a}: drive {v["can_node_id"]}' + (
            f', encoder {v["load_encoder_node_id"]}' if v['load_encoder_node_id'] else '')
            for a, v in self.values.items())
        self.get_logger().info(f'CiA 402 drives on {g["can_interface"]} {g["can_channel"]} '
                               f'({ids}): waiting for the master')

    def _plant_consistency(self, values: dict) -> list[str]:
        return plant_consistency({k: v for k, v in values.items() if k in PLANT_AXIS})

    def current(self, axis: str) -> dict:
        return self.values[axis]

    def _apply(self, params) -> None:
        for axis, changes in self.axis_changes(params).items():
            plant = {k: v for k, v in changes.items() if k in PLANT_AXIS}
            if plant:                  # (validated with the table's rules by `validate`)
                self.drives.configure_plant(axis, plant)
                self.states.command_timeout[axis] = \
                    plant.get('command_timeout', self.states.command_timeout[axis])
            code = changes.get('inject_fault', 0)
            if code and code != self.values[axis]['inject_fault']:
                self.drives.inject_fault(axis, code)
                self.get_logger().warning(f'{axis}: fault 0x{code:04X} injected')
            self.values[axis].update(changes)

    def _publish(self) -> None:
        """The slides as the last SYNC found them, stamped with the time it came (the
        controller stamps what it publishes with the time of the tick that sent it): the two
        line up in a recording whatever the scheduler does to either process."""
        when, *self._truth = self.drives.truth()
        if when != self._published:
            self._published = when
            self.states.publish(stamp_of(when), self)
        for level, text in self.drives.logs():
            (self.get_logger().error if level == 'error' else self.get_logger().info)(text)
        self._states = self.drives.states()
        for a, now in zip(self.axis_names, self._states):
            if now == self.reported[a]:
                continue
            state, code = now
            node = self.values[a]['can_node_id']
            if state == c.FAULT and code:
                self.get_logger().error(f'{a}: drive node {node}: FAULT, error code '
                                        f'0x{code:04X}: torque 0, dynamic brake on')
            elif self.reported[a][0] == c.FAULT:
                self.get_logger().info(f'{a}: drive node {node}: fault reset')
            self.reported[a] = now

    # -- what PlantStates publishes --------------------------------------------------------------
    def truth(self) -> tuple[list[float], list[float]]:
        return self._truth[0], self._truth[1]

    def applied(self) -> list[float]:
        return self._truth[2]

    def tripped(self) -> list[bool]:
        """The communication watchdog holds the drive in its fault."""
        return [state in (c.FAULT, c.FAULT_REACTION) and code == RPDO_TIMEOUT
                for state, code in self._states]

    def destroy_node(self) -> None:
        self.drives.stop()
        super().destroy_node()


def main(args=None):
    sys.exit(run(VirtualDriveNode, args))


if __name__ == '__main__':
    main()
