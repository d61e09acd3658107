"""The ROS interface beyond one axis (issue 6): three axes in one controller over DDS, and the
parameter YAML load / dump round trip through the parameter services `ros2 param` uses."""
import pathlib

import pytest
import yaml
from rcl_interfaces.msg import Parameter as ParameterMsg
from rclpy.parameter import (get_parameter_value, parameter_dict_from_yaml_file,
                             parameter_value_to_python)
from rclpy.parameter_client import AsyncParameterClient

from kit import COUNT, running_slide, spin_for
from motion_ctrl.analysis import iso230
from motion_ctrl.ros.client import SlideClient
from motion_ctrl.ros.processes import NodeProcess, params_dir

REPO = pathlib.Path(__file__).resolve().parents[2]


@pytest.fixture
def three_axes(rclpy_session, tmp_path):
    axes = "['x','y','z']"   # quoted: a bare y is YAML for true
    with running_slide(tmp_path, lambda: SlideClient(axes=('x', 'y', 'z'),
                                                     name='three_axes_client'),
                       {'axes': axes}, {'axes': axes}, exit_zero=True) as s:
        yield s.client


@pytest.mark.timeout(120)
def test_three_axes_move_to_different_targets_at_once(three_axes):
    targets = {'x': 0.0254, 'y': -0.0127, 'z': 0.0381}
    t = three_axes.move(targets, timeout=10.0)
    assert t is not None, f'not every axis reported MOTION_DONE: {three_axes.status}'
    spin_for(three_axes, 0.05)                   # the latest truth after MOTION_DONE
    for axis, target in targets.items():
        assert abs(three_axes.truth[f'{axis}_load'] - target) <= 3 * COUNT, axis
    # The registers are independent: slowing y alone leaves x and z as they were.
    params = AsyncParameterClient(three_axes, 'controller')
    assert params.wait_for_services(10.0)
    from rclpy.parameter import Parameter
    res = three_axes.answer(
        lambda: params.set_parameters([Parameter('y.max_velocity', value=0.01)]))
    assert res.results[0].successful
    got = three_axes.answer(lambda: params.get_parameters(
        ['x.max_velocity', 'y.max_velocity', 'z.max_velocity'])).values
    assert [v.double_value for v in got] == [0.1, 0.01, 0.1]


def _dump(client, node_name):
    """What `ros2 param dump` prints, as a dict: every parameter the node lists, via the
    list_parameters / get_parameters services."""
    p = AsyncParameterClient(client, node_name)
    assert p.wait_for_services(10.0)
    names = sorted(client.answer(p.list_parameters).result.names)
    values = client.answer(lambda: p.get_parameters(names)).values
    return {n: parameter_value_to_python(v) for n, v in zip(names, values)}, p


def _dump_file(client, node_name, path):
    """`ros2 param dump NODE > path` as ros2param writes it: names sorted, split at '.' into
    nested maps, `yaml.dump` in block style (a double such as 1e-06 is written `1.0e-06`, an
    empty table `[]`)."""
    values, p = _dump(client, node_name)
    tree = {}
    for name, value in values.items():
        *prefix, leaf = name.split('.')
        node = tree
        for key in prefix:
            node = node.setdefault(key, {})
        node[leaf] = value
    path.write_text(yaml.dump({node_name: {'ros__parameters': tree}}, default_flow_style=False))
    return values, p


def _load(client, params, path, atomically=False) -> dict:
    """`ros2 param load NODE path`: the file read by rclpy's `parameter_dict_from_yaml_file`
    (which re-reads each value from its text, so `1.0e-06` comes back as the string '1e-06'
    and `[]` as an empty bool array) and sent with set_parameters, one result per parameter:
    {name: SetParametersResult}. `atomically`: one set_parameters_atomically call, as
    load_parameter_file_atomically; the one result under the key None."""
    if atomically:
        return {None: client.answer(
            lambda: params.load_parameter_file_atomically(str(path))).result}
    names = parameter_dict_from_yaml_file(str(path), target_nodes=[params.remote_node_name])
    results = client.answer(lambda: params.load_parameter_file(str(path))).results
    assert len(results) == len(names)
    return dict(zip(names, results))


def test_calibration_yaml_loads_with_rclpys_parameter_file_reader(tmp_path):
    """The calibration's tables file (iso230.params_yaml) as `ros2 param load` reads it: each
    register with its type, spacings before tables."""
    from rclpy.parameter import Parameter
    from test_iso230 import result_for       # a measured error curve with noise
    targets = iso230.plan_targets(0.0, 0.05, 6)
    tab = iso230.build_tables(result_for(targets), tolerance=0.25 * COUNT)
    tab.leadscrew_table[1] = 1e-06                    # repr '1e-06': YAML 1.1 text, not a float
    path = tmp_path / 'comp.yaml'
    path.write_text(iso230.params_yaml(tab, 'x', comment='two\nlines'))
    params = parameter_dict_from_yaml_file(str(path), target_nodes=['controller'])
    names = list(params)
    assert names == ['x.backlash_distance', 'x.leadscrew_table_spacing', 'x.leadscrew_table',
                     'x.backlash_table_spacing', 'x.backlash_table']     # spacings first
    for name, value in tab.registers('x').items():
        p = Parameter.from_parameter_msg(params[name])
        if isinstance(value, list):
            assert p.type_ == Parameter.Type.DOUBLE_ARRAY
            assert list(p.value) == pytest.approx(value, rel=1e-15)
        else:
            assert p.type_ == Parameter.Type.DOUBLE
            assert p.value == pytest.approx(value, rel=1e-15)


def _refusals(results: dict) -> dict:
    return {n: r.reason for n, r in results.items() if not r.successful}


def _yaml_text(path, node, text):
    """A params file from YAML text, written as a user would type it."""
    body = ''.join(f'    {line}\n' for line in text.strip().splitlines())
    path.write_text(f'{node}:\n  ros__parameters:\n{body}')
    return path


@pytest.fixture
def param_node(request, rclpy_session, tmp_path, node_env):
    """One node started from its params file (as `ros2 run ... --params-file`) and a client:
    (node name, client, AsyncParameterClient)."""
    node, module, yaml_file = request.param
    proc = NodeProcess(module, params_dir() / yaml_file, None, tmp_path / f'{node}.log',
                       env=node_env)
    client = SlideClient(name=f'params_{node}')
    try:
        _, params = _dump(client, node)
        yield node, client, params
    finally:
        client.destroy_node()
        assert proc.stop() == 0


NODES = [('controller', 'controller_node', 'controller.yaml'),
         ('plant', 'plant_node', 'plant.yaml')]
CONTROLLER = [NODES[0]]


@pytest.mark.timeout(120)
@pytest.mark.parametrize('param_node', NODES, ids=['controller', 'plant'], indirect=True)
def test_yaml_load_and_dump_round_trip(param_node, tmp_path):
    """`ros2 param dump` then `ros2 param load` of that file: every parameter of the node
    (read-only ones, rclpy's own, empty tables, doubles written as 1.0e-06) is accepted and
    nothing changes; a file with other values is applied; an unknown name is refused naming
    it, as at start-up."""
    node, client, params = param_node
    path = params_dir() / f'{node}.yaml'
    expected = yaml.safe_load(path.read_text())[node]['ros__parameters']
    dumped, _ = _dump_file(client, node, tmp_path / 'dump.yaml')
    for name, value in expected.items():
        got = dumped[name]
        if isinstance(value, float):
            assert got == value, name            # doubles come back bit-exact
        else:
            assert list(got) == value if isinstance(value, list) else got == value, name
    text = (tmp_path / 'dump.yaml').read_text()
    if node == 'controller':           # empty tables, loaded back as empty bool arrays
        assert 'leadscrew_table: []' in text and 'backlash_table: []' in text
    else:                              # loaded back as the string '2e-05'
        assert 'motor_inertia: 2.0e-05' in text

    results = _load(client, params, tmp_path / 'dump.yaml')
    assert set(results) == set(dumped)
    assert not _refusals(results)
    again, _ = _dump(client, node)
    assert again == dumped
    assert {n: type(v) for n, v in again.items()} == {n: type(v) for n, v in dumped.items()}

    # `ros2 param load`: a file with other values is applied through the same services.
    changed = {k: v for k, v in expected.items() if k.endswith(('.kp', '.slide_mass'))}
    assert changed
    new = {k: v * 1.5 for k, v in changed.items()}
    other = tmp_path / 'other.yaml'
    other.write_text(yaml.safe_dump({node: {'ros__parameters': new}}))
    assert not _refusals(_load(client, params, other))
    again, _ = _dump(client, node)
    for k, v in new.items():
        assert again[k] == v

    # A typo is refused naming it (rclpy's own text is "... undeclared parameter(s): []").
    typo = _yaml_text(tmp_path / 'typo.yaml', node, 'x.kpp: 1.0')
    assert _refusals(_load(client, params, typo)) == {
        'x.kpp': f"x.kpp: no such parameter on {node} (axes ['x'])"}


@pytest.mark.timeout(120)
@pytest.mark.parametrize('param_node', CONTROLLER, ids=['controller'], indirect=True)
def test_tables_load_dump_and_clear(param_node, tmp_path):
    """The compensation tables through `ros2 param load` / `dump` / `set`: a table of small
    doubles survives a dump and load, `[]` clears it (from a file and as `ros2 param set`
    sends it), a table and its spacing clear together in one call; a spacing of 0 alone while
    the table is set is refused naming both."""
    node, client, params = param_node
    tables = {'x.backlash_table': [1.0e-06, -2.5e-06, 3.0e-05],
              'x.leadscrew_table': [0.001, 1.0e-06, -2.0e-06, 0.0]}
    spacing = {f'{k}_spacing': 0.005 for k in tables}
    set_file = _yaml_text(tmp_path / 'tables.yaml', node, '\n'.join(
        f'{k}: {yaml.safe_dump(v, default_flow_style=True).splitlines()[0]}'  # [1.0e-06, ...]
        for k, v in (spacing | tables).items()))   # spacings first: a file is set in order
    assert not _refusals(_load(client, params, set_file))
    dumped, _ = _dump_file(client, node, tmp_path / 'dump.yaml')
    assert {k: dumped[k] for k in tables} == tables
    assert '1.0e-06' in (tmp_path / 'dump.yaml').read_text()
    assert not _refusals(_load(client, params, tmp_path / 'dump.yaml'))
    again, _ = _dump(client, node)
    assert again == dumped

    # Spacing 0 alone while its table is set: refused, naming the spacing and the table.
    zero = _yaml_text(tmp_path / 'zero.yaml', node, 'x.backlash_table_spacing: 0.0')
    (reason,) = _refusals(_load(client, params, zero)).values()
    assert 'backlash_table_spacing' in reason and 'backlash_table is set' in reason, reason
    # Cleared from a file: `x.leadscrew_table: []` (an empty bool array on the wire).
    clear = _yaml_text(tmp_path / 'clear.yaml', node, 'x.leadscrew_table: []')
    assert not _refusals(_load(client, params, clear))
    # ... and the table with its spacing in one call (ros2 param load of both, atomically).
    both = _yaml_text(tmp_path / 'both.yaml', node,
                      'x.backlash_table: []\nx.backlash_table_spacing: 0.0')
    assert not _refusals(_load(client, params, both, atomically=True))
    now, _ = _dump(client, node)
    assert {k: now[k] for k in tables} == {k: [] for k in tables}
    assert now['x.backlash_table_spacing'] == 0.0 and now['x.leadscrew_table_spacing'] == 0.005
    # `ros2 param set /controller x.leadscrew_table "[]"` sends what get_parameter_value('[]')
    # makes of the text; a table is put back first so that the clear changes something.
    assert not _refusals(_load(client, params, set_file))
    msg = ParameterMsg(name='x.leadscrew_table', value=get_parameter_value('[]'))
    (result,) = client.answer(lambda: params.set_parameters([msg])).results
    assert result.successful, result.reason
    now, _ = _dump(client, node)
    assert now['x.leadscrew_table'] == [] and now['x.backlash_table'] == tables[
        'x.backlash_table']
