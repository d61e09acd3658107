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
quoted: ROS's YAML parser reads y, n, on, off as booleans.
"""
import tempfile

from launch import LaunchDescription
from launch.actions import DeclareLaunchArgument, OpaqueFunction
from launch.substitutions import LaunchConfiguration, PathJoinSubstitution, PythonExpression
from launch_ros.actions import Node
from launch_ros.parameter_descriptions import ParameterValue
from launch_ros.substitutions import FindPackageShare


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


def axes_file(context) -> list:
    """A params file setting `axes` for every node, names quoted; [] when not asked for."""
    text = LaunchConfiguration('axes').perform(context).strip().strip('[]')
    names = [n.strip().strip('\'"') for n in text.split(',') if n.strip()]
    if not names:
        return []
    with tempfile.NamedTemporaryFile('w', prefix='motion_ctrl_axes_', suffix='.yaml',
                                     delete=False) as f:
        f.write('/**:\n  ros__parameters:\n    axes: [%s]\n'
                % ', '.join(f"'{n}'" for n in names))
    return [f.name]


def nodes(context, use_sim_time, lockstep):
    axes = axes_file(context)
    if LaunchConfiguration('hardware').perform(context) == 'sim':
        return [Node(
            package='motion_ctrl',
            executable='controller',
            name='controller',
            parameters=[LaunchConfiguration('controller_params'),
                        LaunchConfiguration('plant_params'), *axes,
                        {'use_sim_time': use_sim_time, 'hardware': 'sim'}],
            output='screen',
        )]
    return [
        Node(
            package='motion_ctrl',
            executable='controller',
            name='controller',
            parameters=[LaunchConfiguration('controller_params'), *axes,
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
