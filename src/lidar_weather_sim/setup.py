"""ament_python package: the virtual LiDAR library, its ROS 2 nodes and the CLI."""
from glob import glob
from pathlib import Path

from setuptools import find_packages, setup

package_name = "lidar_weather_sim"


def tree(top: str) -> list[tuple[str, list[str]]]:
    """data_files entries installing the workspace directory ``../../<top>`` to share/<package>/<top>."""
    root = Path("../..")
    entries = {}
    for path in sorted((root / top).rglob("*")):
        if path.is_file():
            entries.setdefault(f"share/{package_name}/{path.parent.relative_to(root)}", []).append(str(path))
    return sorted(entries.items())

setup(
    name=package_name,
    version="0.1.0",
    packages=find_packages(exclude=["test", "test.*"]),
    data_files=[
        ("share/ament_index/resource_index/packages", [f"resource/{package_name}"]),
        (f"share/{package_name}", ["package.xml"]),
        # The CLI on PATH (colcon adds <prefix>/bin); nodes live in lib/<package> for ros2 run.
        ("bin", glob("bin/*")),
        *tree("config"),
        *tree("maps"),
        *tree("launch"),
    ],
    install_requires=["setuptools"],
    zip_safe=False,
    maintainer="lidar_weather_sim developers",
    maintainer_email="dev@lidar-weather-sim.invalid",
    description="Virtual automotive LiDAR in real weather",
    license="Apache-2.0",
    entry_points={
        "console_scripts": [
            "pattern_node = lidar_weather_sim.ros.pattern_node:main",
            "lidar_sim_node = lidar_weather_sim.ros.lidar_sim_node:main",
            "lidar-weather-sim = lidar_weather_sim.cli:main",
            "bag_player_node = lidar_weather_sim.ros.bag_player_node:main",
            "recorder_node = lidar_weather_sim.ros.recorder_node:main",
            "ego_controller_node = lidar_weather_sim.ros.ego_controller_node:main",
            "foxglove_bridge_node = lidar_weather_sim.ros.foxglove_bridge_node:main",
        ],
        "lidar_weather_sim.regions": [
            "cover = lidar_weather_sim.regions.cover:CoverRegion",
            "atmosphere = lidar_weather_sim.regions.atmosphere:AtmosphereRegion",
            "faults = lidar_weather_sim.regions.faults:FaultRegion",
        ],
    },
)
