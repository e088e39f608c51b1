"""Play a bag's poses into the virtual LiDAR and record its clouds (graph config/graphs/replay_compare.yaml).

    ros2 launch lidar_weather_sim replay_compare.launch.py bag:=/tmp/highway out:=/tmp/replayed

Here (no `launch`): lidar-weather-sim up replay_compare bag:=/tmp/highway out:=/tmp/replayed

`bag` and `out` are required. When every node has exited cleanly, `lidar-weather-sim compare`
writes its report to /tmp/replayed_compare; a failed node or compare makes ros2 launch exit with status 1.

The nodes, parameter files, remappings and arguments come from the graph
description, read by lidar_weather_sim.ros.graph: the same one `lidar-weather-sim up` runs.
"""

from lidar_weather_sim.ros.graph import launch_description

GRAPH = "replay_compare"


def generate_launch_description():
    return launch_description(GRAPH)
