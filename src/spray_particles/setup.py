"""ament_python package spray_particles."""
from setuptools import find_packages, setup

package_name = "spray_particles"

setup(
    name=package_name,
    version="0.1.0",
    packages=find_packages(exclude=["test", "test.*"]),
    data_files=[
        ("share/ament_index/resource_index/packages", [f"resource/{package_name}"]),
        (f"share/{package_name}", ["package.xml"]),
    ],
    install_requires=["setuptools"],
    zip_safe=False,
    maintainer="lidar_weather_sim developers",
    maintainer_email="dev@lidar-weather-sim.invalid",
    license="Apache-2.0",
    entry_points={
        "lidar_weather_sim.regions": ["spray = spray_particles.region:SprayRegion"],
        "console_scripts": ["spray_node = spray_particles.ros.node:main"],
    },
)
