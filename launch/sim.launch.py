"""Launch sim_node with its parameters from a YAML file.

    ros2 launch abd_joint_sim sim.launch.py
    ros2 launch abd_joint_sim sim.launch.py params_file:=/path/to/my.yaml
"""
import os

from ament_index_python.packages import get_package_share_directory
from launch import LaunchDescription
from launch.actions import DeclareLaunchArgument
from launch.substitutions import LaunchConfiguration
from launch_ros.actions import Node


def generate_launch_description():
    default_params = os.path.join(
        get_package_share_directory('abd_joint_sim'), 'config', 'sim.yaml')
    params_file = LaunchConfiguration('params_file')
    return LaunchDescription([
        DeclareLaunchArgument(
            'params_file', default_value=default_params,
            description='YAML file with the abd_joint_sim node parameters'),
        Node(
            package='abd_joint_sim',
            executable='sim_node',
            name='abd_joint_sim',
            parameters=[params_file],
            output='screen',
            emulate_tty=True,
        ),
    ])
