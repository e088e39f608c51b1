"""Closed loop: adaptive cruise on the (filtered) cloud drives the ego (graph config/graphs/closed_loop.yaml).

    ros2 launch lidar_weather_sim closed_loop.launch.py scenario:=highway_spray_crosswind filter:=false
    ros2 launch lidar_weather_sim closed_loop.launch.py foxglove:=true   # + foxglove_bridge_node (ws://127.0.0.1:8765)

Here (no `launch`): lidar-weather-sim up closed_loop ...; lidar-weather-sim closed-loop (all variants + report)

The nodes, parameter files, remappings and arguments come from the graph
description, read by lidar_weather_sim.ros.graph: the same one `lidar-weather-sim up` runs.
"""

from lidar_weather_sim.ros.graph import launch_description

GRAPH = "closed_loop"


def generate_launch_description():
    return launch_description(GRAPH)
