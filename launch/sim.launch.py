"""The virtual LiDAR (lidar_sim_node) in a full ROS 2 install (Jazzy / Kilted): ros2 launch.

    ros2 launch lidar_weather_sim sim.launch.py scenario:=highway_clear
    ros2 launch lidar_weather_sim sim.launch.py pose_source:=tf use_sim_time:=true regions:="[cover, rain]"

``profile`` empty = the scenario's sensor; ``regions`` empty = the scenario's
list, otherwise a YAML list of region plugin names.
"""

import yaml
from launch import LaunchDescription
from launch.actions import DeclareLaunchArgument, OpaqueFunction
from launch_ros.actions import Node


def _node(context):
    arg = context.launch_configurations
    parameters = {
        "scenario": arg["scenario"],
        "profile": arg["profile"],
        "pose_source": arg["pose_source"],
        "use_sim_time": arg["use_sim_time"].strip().lower() in ("true", "1", "yes"),
    }
    if arg["regions"].strip():  # only when given: the node's default is the scenario's list
        regions = yaml.safe_load(arg["regions"])
        if not isinstance(regions, list):
            raise ValueError(f"regions must be a YAML list such as [cover, rain], got {arg['regions']!r}")
        parameters["regions"] = [str(name) for name in regions]
    return [Node(package="lidar_weather_sim", executable="lidar_sim_node", parameters=[parameters], output="screen")]


def generate_launch_description() -> LaunchDescription:
    return LaunchDescription(
        [
            DeclareLaunchArgument("scenario", default_value="highway_clear", description="Scenario name or YAML path"),
            DeclareLaunchArgument("profile", default_value="", description="Sensor profile ('' = the scenario's)"),
            DeclareLaunchArgument(
                "pose_source",
                default_value="scenario",
                choices=["scenario", "tf", "odometry"],
                description="scenario (drives /clock), tf (/tf + /tf_static) or odometry",
            ),
            DeclareLaunchArgument("regions", default_value="", description="Region plugins, e.g. [cover, rain]"),
            DeclareLaunchArgument("use_sim_time", default_value="false", description="Follow /clock (bag replay)"),
            OpaqueFunction(function=_node),
        ]
    )
