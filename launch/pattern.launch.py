"""Synthetic wiring-check sweep on /lidar/points (graph config/graphs/pattern.yaml).

    ros2 launch lidar_weather_sim pattern.launch.py rate_hz:=20
    ros2 launch lidar_weather_sim pattern.launch.py foxglove:=true   # + foxglove_bridge_node (ws://127.0.0.1:8765)

Here (no `launch`): lidar-weather-sim up pattern rate_hz:=20. The node and its
arguments come from the graph description, read by lidar_weather_sim.ros.graph.
"""

from lidar_weather_sim.ros.graph import launch_description

GRAPH = "pattern"


def generate_launch_description():
    return launch_description(GRAPH)
