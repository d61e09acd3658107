"""Controller + simulated backlash slide.

ros2 launch motion_ctrl slide.launch.py [controller_params:=FILE]
    [plant_params:=FILE] [use_sim_time:=true|false] [axes:=x,y] [hardware:=topics|sim]

hardware:=topics (the default): the plant node and the controller, exchanging `encoders` and
`command`. hardware:=sim: the controller alone, the slide simulated inside its loop (configured
by plant_params' plant: section).

use_sim_time:=true runs the deterministic lockstep simulation: with topics the plant
(lockstep: 1) is the /clock and the controller runs on it, ticking on each encoder sample; with
sim the controller is the clock, ticking as fast as the machine allows.

axes:=x,y (or "[x, y]") sets both nodes' `axes` over the params files. The names go to the nodes
quoted: ROS's YAML parser reads y, n, on, off as booleans. The axes other than x get the shipped
slide's tuning (the controller's params file tunes x; a file that names them wins).
"""
import tempfile

from launch import LaunchDescription
from launch.actions import DeclareLaunchArgument, OpaqueFunction
from launch.substitutions import LaunchConfiguration, PathJoinSubstitution, PythonExpression
from launch_ros.actions import Node
from launch_ros.parameter_descriptions import ParameterValue
from launch_ros.substitutions import FindPackageShare

from motion_ctrl.core.registers import shipped_tuning_yaml
from motion_ctrl.ros.processes import axis_names


def generate_launch_description():
    params_dir = PathJoinSubstitution([FindPackageShare('motion_ctrl'), 'params'])
    use_sim_time = ParameterValue(LaunchConfiguration('use_sim_time'), value_type=bool)
    # The plant never runs on sim time: with use_sim_time it *is* the clock (lockstep).
    lockstep = ParameterValue(PythonExpression(
        ["1 if '", LaunchConfiguration('use_sim_time'), "'.lower() == 'true' else 0"]),
        value_type=int)

    return LaunchDescription([
        DeclareLaunchArgument(
            'controller_params',
            default_value=PathJoinSubstitution([params_dir, 'controller.yaml']),
            description='Parameter file of the controller node (ros2 param load format)'),
        DeclareLaunchArgument(
            'plant_params',
            default_value=PathJoinSubstitution([params_dir, 'plant.yaml']),
            description='Parameter file of the plant node (ros2 param load format)'),
        DeclareLaunchArgument(
            'use_sim_time', default_value='false',
            description='Lockstep simulation: the plant publishes /clock, the controller '
                        'runs on it (true/false)'),
        DeclareLaunchArgument(
            'axes', default_value='',
            description='Axis names for both nodes, comma-separated (x,y); empty: as the '
                        'params files say'),
        DeclareLaunchArgument(
            'hardware', default_value='topics', choices=['topics', 'sim'],
            description='topics: plant node + controller; sim: the controller alone, the '
                        'slide simulated in its loop'),
        OpaqueFunction(function=nodes, args=[use_sim_time, lockstep]),
    ])


def _params_file(prefix: str, node: str, lines: list[str]) -> str:
    """A params file giving node `node` (`/**`: every node) the parameters of `lines`
    (`name: value`)."""
    with tempfile.NamedTemporaryFile('w', prefix=prefix, suffix='.yaml', delete=False) as f:
        f.write(f'{node}:\n  ros__parameters:\n' + ''.join(f'    {line}\n' for line in lines))
    return f.name


def axes_files(context) -> tuple[list, list]:
    """Params files for axes:=: ([the shipped slide's tuning for the named axes other than x],
    [`axes` for every node, the names quoted]); ([], []) when not asked for."""
    names = axis_names(LaunchConfiguration('axes').perform(context))
    if not names:
        return [], []
    tuning = shipped_tuning_yaml([n for n in names if n != 'x'])
    axes = "axes: [" + ', '.join(f"'{n}'" for n in names) + ']'
    # rcl applies a node's sections in the order the files first name them: the tuning under
    # the controller's own name, first, so that controller_params overrides it; `axes` under
    # /**, after controller_params, so that it overrides that file's.
    return ([_params_file('motion_ctrl_tuning_', 'controller', tuning)] if tuning else [],
            [_params_file('motion_ctrl_axes_', '/**', [axes])])


def nodes(context, use_sim_time, lockstep):
    tuning, axes = axes_files(context)
    if LaunchConfiguration('hardware').perform(context) == 'sim':
        return [Node(
            package='motion_ctrl',
            executable='controller',
            name='controller',
            parameters=[*tuning, LaunchConfiguration('controller_params'),
                        LaunchConfiguration('plant_params'), *axes,
                        {'use_sim_time': use_sim_time, 'hardware': 'sim'}],
            output='screen',
        )]
    return [
        Node(
            package='motion_ctrl',
            executable='controller',
            name='controller',
            parameters=[*tuning, LaunchConfiguration('controller_params'), *axes,
                        {'use_sim_time': use_sim_time}],
            output='screen',
        ),
        Node(
            package='motion_ctrl',
            executable='plant',
            name='plant',
            parameters=[LaunchConfiguration('plant_params'), *axes, {'lockstep': lockstep}],
            output='screen',
        ),
    ]
