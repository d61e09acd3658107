"""The ROS interface beyond one axis (issue 6): three axes in one controller over DDS, and the
parameter YAML load / dump round trip through the parameter services `ros2 param` uses."""
import pathlib

import pytest
import yaml
from rclpy.parameter_client import AsyncParameterClient

from motion_ctrl.client import SlideClient
from motion_ctrl.processes import NodeProcess, params_dir

COUNT = 0.0254 / 10000
REPO = pathlib.Path(__file__).resolve().parent.parent


@pytest.fixture
def three_axes(rclpy_session, tmp_path, node_env, slow_watchdog):
    axes = "['x','y','z']"   # quoted: a bare y is YAML for true
    d = params_dir()
    plant = NodeProcess('plant_node', d / 'plant.yaml', {'axes': axes},
                        tmp_path / 'plant.log', env=node_env)
    controller = NodeProcess('controller_node', d / 'controller.yaml',
                             {'axes': axes} | slow_watchdog,
                             tmp_path / 'controller.log', env=node_env)
    client = SlideClient(axes=('x', 'y', 'z'), name='three_axes_client')
    try:
        assert client.wait_ready(30.0), f'plant + controller with three axes did not come up: {client.not_ready()}'
        yield client
    finally:
        client.destroy_node()
        assert controller.stop() == 0 and plant.stop() == 0


@pytest.mark.timeout(120)
def test_three_axes_move_to_different_targets_at_once(three_axes):
    targets = {'x': 0.0254, 'y': -0.0127, 'z': 0.0381}
    t = three_axes.move(targets, timeout=10.0)
    assert t is not None, f'not every axis reported MOTION_DONE: {three_axes.status}'
    three_axes.spin_until(lambda: False, 0.05)
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
    from rclpy.parameter import parameter_value_to_python
    p = AsyncParameterClient(client, node_name)
    assert p.wait_for_services(10.0)
    names = client.answer(p.list_parameters).result.names
    values = client.answer(lambda: p.get_parameters(names)).values
    return {n: parameter_value_to_python(v) for n, v in zip(names, values)}, p


@pytest.mark.timeout(120)
@pytest.mark.parametrize('node,module,yaml_file', [
    ('controller', 'controller_node', 'controller.yaml'),
    ('plant', 'plant_node', 'plant.yaml'),
])
def test_yaml_load_and_dump_round_trip(rclpy_session, tmp_path, node_env, node, module,
                                       yaml_file):
    path = params_dir() / yaml_file
    expected = yaml.safe_load(path.read_text())[node]['ros__parameters']
    proc = NodeProcess(module, path, None, tmp_path / f'{node}.log', env=node_env)
    client = SlideClient(name=f'dump_{node}')
    try:
        dumped, params = _dump(client, node)
        for name, value in expected.items():
            got = dumped[name]
            if isinstance(value, float):
                assert got == value, name            # doubles come back bit-exact
            else:
                assert list(got) == value if isinstance(value, list) else got == value, name
        # `ros2 param load`: a file with other values is applied through the same services.
        changed = {k: v for k, v in expected.items() if k.endswith(
            ('.kp', '.slide_mass'))}
        assert changed
        new = {k: v * 1.5 for k, v in changed.items()}
        other = tmp_path / 'other.yaml'
        other.write_text(yaml.safe_dump({node: {'ros__parameters': new}}))
        results = client.answer(lambda: params.load_parameter_file(str(other)))
        assert all(r.successful for r in results.results)
        again, _ = _dump(client, node)
        for k, v in new.items():
            assert again[k] == v
    finally:
        client.destroy_node()
        assert proc.stop() == 0
