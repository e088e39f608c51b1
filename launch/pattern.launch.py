"""Synthetic wiring-check sweep on /lidar/points (full ROS 2 install: ros2 launch)."""

from launch import LaunchDescription
from launch.actions import DeclareLaunchArgument
from launch.substitutions import LaunchConfiguration
from launch_ros.actions import Node


def generate_launch_description() -> LaunchDescription:
    rate = LaunchConfiguration("rate_hz")
    use_sim_time = LaunchConfiguration("use_sim_time")
    return LaunchDescription(
        [
            DeclareLaunchArgument("rate_hz", default_value="10.0", description="Frames per second (Hz)"),
            DeclareLaunchArgument("use_sim_time", default_value="false", description="Follow /clock"),
            Node(
                package="lidar_weather_sim",
                executable="pattern_node",
                parameters=[{"rate_hz": rate, "use_sim_time": use_sim_time}],
                output="screen",
            ),
        ]
    )
