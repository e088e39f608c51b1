"""The virtual LiDAR, optionally with the weather filter (graph config/graphs/sim.yaml).

    ros2 launch lidar_weather_sim sim.launch.py scenario:=highway_clear
    ros2 launch lidar_weather_sim sim.launch.py pose_source:=tf use_sim_time:=true regions:="[cover, atmosphere]" filter:=true
    ros2 launch lidar_weather_sim sim.launch.py foxglove:=true     # + foxglove_bridge_node: Foxglove at ws://127.0.0.1:8765

Here (no `launch`): lidar-weather-sim up sim scenario:=highway_clear ...

The nodes, parameter files, remappings and arguments come from the graph
description, read by lidar_weather_sim.ros.graph: the same one `lidar-weather-sim up` runs.
"""

from lidar_weather_sim.ros.graph import launch_description

GRAPH = "sim"


def generate_launch_description():
    return launch_description(GRAPH)
