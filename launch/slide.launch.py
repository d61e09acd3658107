"""Controller + simulated backlash slide.

ros2 launch motion_ctrl slide.launch.py [controller_params:=FILE]
    [plant_params:=FILE] [use_sim_time:=true|false]

use_sim_time:=true runs the deterministic lockstep simulation: the plant (lockstep: 1) is the
/clock and the controller runs on it, ticking on each encoder sample.
"""
from launch import LaunchDescription
from launch.actions import DeclareLaunchArgument
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
        Node(
            package='motion_ctrl',
            executable='controller',
            name='controller',
            parameters=[LaunchConfiguration('controller_params'),
                        {'use_sim_time': use_sim_time}],
            output='screen',
        ),
        Node(
            package='motion_ctrl',
            executable='plant',
            name='plant',
            parameters=[LaunchConfiguration('plant_params'), {'lockstep': lockstep}],
            output='screen',
        ),
    ])
