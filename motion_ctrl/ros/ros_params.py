"""Registers as ROS parameters: declaration with descriptors, and values back from rclpy.

The only place that turns a `registers.Register` into a ParameterDescriptor, so both nodes
describe their parameters the same way (`ros2 param describe` shows unit, vendor register and
range).
"""
from __future__ import annotations

import math
import re
from collections.abc import Callable

import yaml
from rcl_interfaces.msg import (FloatingPointRange, IntegerRange, ParameterDescriptor,
                                ParameterType, SetParametersResult)
from rclpy.node import Node
from rclpy.parameter import Parameter
from sensor_msgs.msg import JointState

import msg_defs as md
from motion_ctrl.core.registers import shown, size_refusal

_TYPES = {
    'double': (ParameterType.PARAMETER_DOUBLE, Parameter.Type.DOUBLE),
    'integer': (ParameterType.PARAMETER_INTEGER, Parameter.Type.INTEGER),
    'string': (ParameterType.PARAMETER_STRING, Parameter.Type.STRING),
    'double_array': (ParameterType.PARAMETER_DOUBLE_ARRAY, Parameter.Type.DOUBLE_ARRAY),
    'string_array': (ParameterType.PARAMETER_STRING_ARRAY, Parameter.Type.STRING_ARRAY),
}


def descriptor(reg, full_name: str) -> ParameterDescriptor:
    d = ParameterDescriptor(name=full_name, type=_TYPES[reg.type][0],
                            description=reg.descriptor_text(), read_only=reg.read_only)
    if reg.min is not None or reg.max is not None:
        # Exclusive lower bounds are enforced by validation; the range shows the closed hull.
        lo = -math.inf if reg.min is None else reg.min
        hi = math.inf if reg.max is None else reg.max
        if reg.type == 'double':
            d.floating_point_range = [FloatingPointRange(from_value=float(lo),
                                                         to_value=float(hi))]
        elif reg.type == 'integer':
            d.integer_range = [IntegerRange(from_value=int(lo), to_value=int(hi))]
    if reg.choices:
        d.additional_constraints = 'one of: ' + ', '.join(reg.choices)
    return d


def declare(node, reg, full_name: str, default=None):
    """Declare one register; returns its value (overrides from YAML / command line applied).
    `default`: the value without an override, when not the register's own default.

    Empty arrays are declared statically typed (an empty list would otherwise become a byte
    array in rclpy and refuse doubles later).
    """
    desc = descriptor(reg, full_name)
    value = reg.default if default is None else default
    if isinstance(value, list) and not value:
        p = node.declare_parameter(full_name, _TYPES[reg.type][1], desc)
        if p.type_ == Parameter.Type.NOT_SET:
            node.set_parameters([Parameter(full_name, _TYPES[reg.type][1], [])])
        return plain(node.get_parameter(full_name).value)
    value = plain(node.declare_parameter(full_name, value, desc).value)
    # The register's own rule too (rclpy checks the closed range only: feedback_timeout 0 passes)
    reason = reg.check(value)
    if reason:
        raise ValueError(f'{full_name.rsplit(".", 1)[0] + "." if "." in full_name else ""}'
                         f'{reason}')
    return value


def plain(value):
    """rclpy values as plain Python (arrays come as array.array)."""
    if value is not None and not isinstance(value, (str, bool, int, float)):
        return list(value)
    return value


def name_type_refusal(node, params, result):
    """rclpy refuses a value of the wrong type before any on-set callback runs, with a reason
    that names neither the parameter nor the types ("Wrong parameter type, expected '3' got
    '2'"), and a refusal must name the parameter: this rewrites that one reason; every other
    result is returned unchanged."""
    if result.successful or not result.reason.startswith('Wrong parameter type'):
        return result
    for p in params:
        if not node.has_parameter(p.name):
            continue
        want = Parameter.Type(node.describe_parameter(p.name).type)
        if p.type_ not in (want, Parameter.Type.NOT_SET):
            hint = ' (write 2.0, not 2)' if want == Parameter.Type.DOUBLE else ''
            return SetParametersResult(
                successful=False,
                reason=f'{p.name}: wrong type {p.type_.name.lower()}, expected '
                       f'{want.name.lower()}{hint}')
    return result


def params_files(args: list[str]) -> list[str]:
    """The files of `--params-file` in a command line."""
    return _params_files(args)


def section_values(files, node_name: str) -> dict:
    """{parameter: value} of the `ros__parameters` of the sections that name node `node_name`
    itself (`plant:`, `/plant:`, `/**/plant:`; not the wildcards, which rcl applies to every node
    anyway) in the params files `files`, a later file winning. A file rcl or YAML cannot read is
    left to rcl, which refuses it."""
    values: dict = {}
    for f in files:
        try:
            with open(f) as fh:
                data = yaml.safe_load(fh)
        except (OSError, yaml.YAMLError):
            continue
        if not isinstance(data, dict):
            continue
        for key, section in data.items():
            if (str(key).rstrip('/').split('/')[-1] == node_name and isinstance(section, dict)
                    and isinstance(section.get('ros__parameters'), dict)):
                values |= section['ros__parameters']
    return values


def _params_files(args: list[str]) -> list[str]:
    return [b for a, b in zip(args, args[1:]) if a == '--params-file']


def _applies(key: str, node_name: str) -> bool:
    """Whether a params-file section key selects the node (rcl: `name`, `/ns/name`, `/**`,
    `/**/name`, `*`)."""
    last = str(key).rstrip('/').split('/')[-1]
    return last in (node_name, '*', '**')


def params_files_refusal(node_name: str, args: list[str], also=()):
    """Why the params files given with --params-file cannot configure this node, or None: an
    empty file, or one with no section for it (`ctrl:` for `controller:`), would run the node
    on its defaults without a word. (A file rcl cannot parse is refused by rcl first.) `also`:
    other nodes whose sections this node reads too (the controller: `plant`, for `hardware:
    sim`)."""
    for a, b in zip(args, args[1:]):            # launch_ros names nodes with -r __node:=...
        if a in ('-r', '--remap') and b.split(':=', 1)[0] in ('__node', '__name'):
            node_name = b.split(':=', 1)[1]
    for f in _params_files(args):
        try:
            with open(f) as fh:
                data = yaml.safe_load(fh)
        except (OSError, yaml.YAMLError):
            continue
        if not data:
            return f'{f} is empty: it configures nothing'
        if not isinstance(data, dict):
            return f'{f} is not a params file (node name: ros__parameters: ...)'
        if not any((_applies(k, node_name) or str(k).rstrip('/').split('/')[-1] in also)
                   and isinstance(v, dict) and 'ros__parameters' in v for k, v in data.items()):
            return (f'{f} configures nothing for node {node_name!r} (its sections: '
                    f'{", ".join(map(str, data))}); expected {node_name}: ros__parameters: ...')
    return None


def where_from(refusal: str, args: list[str]) -> str:
    """Where the start-up value a `refusal` (which names its parameter) is about came from:
    a `-p name:=value` whose name it names (the command line wins over the files), else the
    params files."""
    for a, b in zip(args, args[1:]):
        if a in ('-p', '--param') and re.search(rf'(?<![\w.]){re.escape(b.split(":=", 1)[0])}'
                                                rf'(?![\w.])', refusal):
            return f'-p {b}'
    return ', '.join(_params_files(args))


class RegisterNode(Node):
    """A node whose parameters are rows of a register table: node-wide ones by name and per-axis
    ones as `<axis>.<register>`. One validation for both nodes: every value checked against its
    row, then the table's cross-register rules on the axis' values as they would become; a
    refusal names the parameter and nothing changes.

    Subclasses set `self.globals_table` ({name: Register}), `self.axis_table`, `self.axis_names`,
    `self.consistency` (values -> reasons) and implement `current(axis)` (that axis' values
    including anything accepted but not applied yet).
    """
    axis_names: list[str]
    globals_table: dict
    axis_table: dict
    consistency: Callable[[dict], list]

    def current(self, axis: str) -> dict:
        raise NotImplementedError

    def stream(self, msg_type, topic: str, qos=None, refresh: float = 0.0):
        """A publisher (servo QoS unless given) whose refused publishes are counted and logged,
        not raised (msg_defs.Stream; JointStateStream for JointState); `refresh`: Stream's."""
        pub = self.create_publisher(msg_type, topic, md.SERVO_QOS if qos is None else qos)
        return (md.JointStateStream if msg_type is JointState else md.Stream)(
            pub, self._publish_refused, refresh)

    def _publish_refused(self, topic: str, error: Exception) -> None:
        self.get_logger().warning(f'{topic}: publish refused ({error}); the node runs on',
                                  throttle_duration_sec=1.0)

    def set_parameters_atomically(self, parameter_list):
        """The parameter services (`ros2 param set`, `ros2 param load`, set_parameters,
        set_parameters_atomically) all land here, one parameter at a time for set_parameters.
        Before rclpy's own checks: an unknown name is refused naming it (rclpy's text,
        "Invalid access to undeclared parameter(s): []", loses the names); a value over the
        input budgets is refused by its size (registers.size_refusal); values are typed as
        their registers are declared (`Register.as_declared`: YAML `[]`, floats read back as
        text); a read-only parameter set to the value it has is accepted unchanged, so a
        `ros2 param dump` loads back without a refusal. After: rclpy's wrong-type refusal
        names the parameter."""
        unknown = [p.name for p in parameter_list if not self.has_parameter(p.name)]
        if unknown:
            return SetParametersResult(successful=False, reason=self.unknown_reason(unknown))
        for p in parameter_list:      # oversized: refused by its size, before any per-entry work
            reason = size_refusal(p.name, p.value)
            if reason:
                return SetParametersResult(successful=False, reason=reason)
        params = [self.as_declared(p) for p in parameter_list]
        kept = [p for p in params if not self.unchanged_read_only(p)]
        if not kept:
            return SetParametersResult(
                successful=True, reason=', '.join(p.name for p in params)
                + ': read-only, value unchanged')
        return name_type_refusal(self, kept, super().set_parameters_atomically(kept))

    def register(self, name):
        """(axis, Register) of a parameter name: (None, row) for a node-wide one, (None, None)
        for one that is not a register (use_sim_time, ...)."""
        reg = self.globals_table.get(name)
        axis, row = self.split(name)
        if reg is None and axis is not None:
            return axis, self.axis_table[row]
        return None, reg

    def as_declared(self, p: Parameter) -> Parameter:
        """`p` with its value typed as its register is declared, where the register table's one
        rule (`Register.as_declared`) allows; otherwise `p` as it came."""
        _, reg = self.register(p.name)
        if reg is None or p.type_ == Parameter.Type.NOT_SET:
            return p
        want = _TYPES[reg.type][1]
        if p.type_ == want:
            return p
        value = reg.as_declared(plain(p.value))
        return Parameter(p.name, want, value) if want.check(value) else p

    def unchanged_read_only(self, p: Parameter) -> bool:
        if not self.describe_parameter(p.name).read_only:
            return False
        now = self.get_parameter(p.name)
        return p.type_ == now.type_ and plain(p.value) == plain(now.value)

    def unknown_reason(self, names) -> str:
        """The one refusal of a parameter this node does not have (start-up and set alike)."""
        return (f'{", ".join(shown(n) if len(n) > 80 else n for n in names)}: no such '
                f'parameter on {self.get_name()} '
                f'(axes {self.axis_names})')

    def refuse_unknown_overrides(self) -> None:
        """A start-up value (params file, `-p`) for a parameter the node does not have is a typo
        or a file written for other axes; rclpy would ignore it without a word. Raises
        ValueError naming it (the node then exits with that line). Call after declaring."""
        # rclpy keeps the start-up values in Node._parameter_overrides (no public accessor).
        unknown = sorted(set(self._parameter_overrides) - set(self._parameters))
        if unknown:
            raise ValueError(self.unknown_reason(unknown))

    def split(self, name):
        """'x.kp' -> ('x', 'kp') for a register of a known axis, else (None, None)."""
        axis, _, reg = name.partition('.')
        if axis in self.axis_names and reg in self.axis_table:
            return axis, reg
        return None, None

    def axis_changes(self, params) -> dict:
        """{axis: {register: value}} of the per-axis parameters among `params`."""
        changes: dict[str, dict] = {}
        for p in params:
            axis, reg = self.split(p.name)
            if axis is not None:
                changes.setdefault(axis, {})[reg] = plain(p.value)
        return changes

    def validate(self, params) -> SetParametersResult:
        for p in params:
            axis, reg = self.register(p.name)
            if reg is None:
                continue            # not ours (use_sim_time, ...): rclpy's own rules apply
            reason = reg.check(plain(p.value))
            if reason:
                return SetParametersResult(
                    successful=False, reason=f'{axis}.{reason}' if axis else reason)
        for axis, changes in self.axis_changes(params).items():
            reasons = self.consistency(self.current(axis) | changes)
            if reasons:
                return SetParametersResult(successful=False,
                                           reason='; '.join(f'{axis}.{r}' for r in reasons))
            reason = self.live_refusal(axis, changes)
            if reason:
                return SetParametersResult(successful=False, reason=reason)
        return SetParametersResult(successful=True)

    def live_refusal(self, axis: str, changes: dict):
        """Why `changes` cannot apply to what the axis is doing now, or None (a node whose
        registers bear on motion in progress says so)."""
        return None


def yaml_bool_hint(rcl_error: str) -> str:
    """What to do about rcl's refusal of a list that YAML reads as mixed types: axis names such
    as y, n, on, off are YAML booleans to rcl's parser (`axes: [x, y]` is a string and a bool)."""
    if 'Sequence should be of same type' not in rcl_error:
        return ''
    return ("; names such as y, n, on, off are booleans to ROS's YAML parser: quote them, "
            """-p 'axes:=["x", "y"]' or axes: ['x', 'y'] in a params file""")
