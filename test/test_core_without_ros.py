"""Every library module imports with rclpy and all ROS message packages blocked."""

import pkgutil
import subprocess
import sys

import lidar_weather_sim
import spray_particles
import weather_filter

BLOCKED = ["rclpy", "sensor_msgs", "std_msgs", "geometry_msgs", "nav_msgs", "tf2_msgs", "builtin_interfaces",
           "rosgraph_msgs", "diagnostic_msgs", "visualization_msgs", "rcl_interfaces"]  # fmt: skip


def _core_modules():
    for package in (lidar_weather_sim, spray_particles, weather_filter):
        yield package.__name__
        for info in pkgutil.walk_packages(package.__path__, package.__name__ + "."):
            if ".ros" not in info.name and not info.name.endswith("_node"):
                yield info.name


def test_core_modules_import_without_ros():
    modules = sorted(_core_modules())
    assert "lidar_weather_sim.io.cloud_codec" in modules and "lidar_weather_sim.io.bags" in modules
    script = "import sys\n" + "".join(f"sys.modules[{m!r}] = None\n" for m in BLOCKED)
    script += "".join(f"import {m}\n" for m in modules)
    result = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True)
    assert result.returncode == 0, result.stderr
