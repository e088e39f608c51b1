"""ament_python package weather_filter."""
from glob import glob

from setuptools import find_packages, setup

package_name = "weather_filter"

setup(
    name=package_name,
    version="0.1.0",
    packages=find_packages(exclude=["test", "test.*"]),
    data_files=[
        ("share/ament_index/resource_index/packages", [f"resource/{package_name}"]),
        (f"share/{package_name}", ["package.xml"]),
        # The CLI on PATH (colcon adds <prefix>/bin); the node lives in lib/<package> for ros2 run.
        ("bin", glob("bin/*")),
    ],
    package_data={package_name: ["models/*.joblib", "models/*.md", "models/*.yaml", "scenarios/*.yaml"]},
    include_package_data=True,
    install_requires=["setuptools"],
    zip_safe=False,
    maintainer="lidar_weather_sim developers",
    maintainer_email="dev@lidar-weather-sim.invalid",
    license="Apache-2.0",
    entry_points={
        # The filter's training and evaluation runs (weather_filter/scenarios/wf_*.yaml), runnable by name.
        "lidar_weather_sim.scenario_dirs": ["weather_filter = weather_filter.simdata:scenario_directory"],
        # `lidar-weather-sim sweep`'s `compute: [eval]`: the filter's evaluation of each run.
        "lidar_weather_sim.sweep_metrics": ["eval = weather_filter.sweep_metrics:evaluate"],
        # `lidar-weather-sim twin`: the frames' weather removed before the scene is meshed.
        "lidar_weather_sim.point_filters": ["weather = weather_filter.twin_filter:make"],
        "console_scripts": [
            "weather-filter = weather_filter.cli:main",
            "weather_filter_node = weather_filter.ros.weather_filter_node:main",
        ],
    },
)
