"""ament_python package region_template: a lidar_weather_sim region plugin to copy."""
from setuptools import find_packages, setup

package_name = "region_template"

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
        # <region name used in scenarios> = <module>:<class>; the simulator finds it by this name
        "lidar_weather_sim.regions": ["template_region = region_template.region:TemplateRegion"],
    },
)
