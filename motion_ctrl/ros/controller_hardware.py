"""The controller's choice of hardware interface (the read-only parameter `hardware`,
motion_ctrl.core.hardware) and the registers each backend brings: `topics`
(ros.hardware_topics: the plant node over the `command` / `encoders` topics), `sim`
(sim.hardware: the slide's physics stepped inside the loop, configured by the plant's registers
declared on the controller, published as the plant node does by ros.plant_states) or `canopen`
(canopen.master: CiA 402 drives on a CAN bus, the controller their SYNC producer; real time
only).
"""
from __future__ import annotations

from motion_ctrl.ros import ros_params
from motion_ctrl.ros.hardware_topics import TopicsHardware
from motion_ctrl.ros.plant_states import PlantStates
from motion_ctrl.core.registers import (CONTROLLER_AXIS, CONTROLLER_GLOBAL, HARDWARE_REGISTERS,
                                        PLANT_AXIS, consistency, plant_consistency)
from motion_ctrl.sim.hardware import SimHardware
from motion_ctrl.canopen.master import AxisNodes, CanopenHardware


def declare_hardware(node, params_files) -> dict:
    """The chosen backend's own registers (registers.HARDWARE_REGISTERS), declared on `node`
    now: {None: controller-wide values, axis: that axis's values}. With `hardware: sim` the
    `plant:` sections of the params files give the plant registers' start values (the node's own
    section and -p win); with another backend such a section is refused."""
    kind = node.hardware_kind
    plant_section = ros_params.section_values(params_files, 'plant')
    if plant_section and kind != 'sim':
        raise ValueError(f'hardware: {kind}: a plant: section in the params files '
                         f'configures the controller only with hardware: sim')
    globals_, per_axis = HARDWARE_REGISTERS[kind]
    node.globals_table = CONTROLLER_GLOBAL | {r.name: r for r in globals_}
    node.axis_table = CONTROLLER_AXIS | {r.name: r for r in per_axis}
    values: dict = {None: {r.name: ros_params.declare(node, r, r.name, plant_section.get(r.name))
                           for r in globals_}}
    for a in node.axis_names:
        values[a] = {r.name: ros_params.declare(node, r, f'{a}.{r.name}',
                                                plant_section.get(f'{a}.{r.name}'))
                     for r in per_axis}
    return values


def make_hardware(node, values: dict, readers_refresh: float):
    """The backend for `node`'s axes with the registers `declare_hardware` gave."""
    if node.hardware_kind == 'sim':
        node.consistency = sim_consistency
        hardware = SimHardware(node.axis_names, node.period,
                               {a: values[a] for a in node.axis_names},
                               substep_rate=values[None]['substep_rate'])
        node.plant_states = PlantStates(node, node.axis_names, {
            a: values[a]['command_timeout'] for a in node.axis_names}, readers_refresh)
        return hardware
    if node.hardware_kind == 'canopen':
        return _canopen(node, values)
    return TopicsHardware(node, node.axis_names, on_sample=node._on_sample)


def _canopen(node, values: dict):
    if node.sim_time:
        raise ValueError('hardware: canopen runs in real time: the drives step on its SYNC; '
                         'use_sim_time is for topics or sim')
    g = values[None]
    r = node.values
    return CanopenHardware(
        {a: AxisNodes(values[a]['can_node_id'], values[a]['load_encoder_node_id'],
                      values[a]['eds'], values[a]['torque_per_volt'],
                      round(r[a]['estop_deceleration'] * r[a]['motor_counts_per_m'])
                      if values[a]['estop_quick_stop'] else 0)
         for a in node.axis_names}, node.period, g['can_interface'], g['can_channel'],
        g['can_bitrate'], log=lambda level, text: node._log([(level, text)]))


def sim_consistency(values: dict) -> list[str]:
    """The controller's cross-register rules and the plant's, each on its own registers."""
    plant = {k: v for k, v in values.items() if k in PLANT_AXIS}
    own = {k: v for k, v in values.items() if k not in PLANT_AXIS}
    return consistency(own) + (plant_consistency(plant) if plant else [])
