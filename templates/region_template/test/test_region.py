"""Tests of the template region: the plugin is found by name and changes a simulated frame as its physics says.

Run after ``colcon build`` and ``source install/setup.bash``: ``colcon test --packages-select region_template``
or ``python -m pytest src/region_template/test``.
"""

import numpy as np
import pytest

from lidar_weather_sim.core.config import ConfigError
from lidar_weather_sim.regions.base import REGISTRY, RegionContext
from lidar_weather_sim.sim.simulator import LidarSimulator
from lidar_weather_sim.testing.fixtures import one_frame, scene_of, simple_profile, wall

NAME = "template_region"  # the entry-point name in setup.py


def frame(params=None, regions=True):
    """One frame of a one-beam sensor (81 columns over +-10 deg) seeing a narrow wall at 20 m in front of a
    wide one at 80 m."""
    profile = simple_profile()
    scene = scene_of(wall(20.0, "concrete", 1, half_width=1.5), wall(80.0, "concrete", 2))
    built = [(NAME, REGISTRY.create(NAME, params or {}, RegionContext(profile)))] if regions else []
    return one_frame(LidarSimulator(profile, scene, regions=built, seed=0)).points


def test_registered_under_its_entry_point_name():
    assert NAME in REGISTRY.names()


def test_alpha_from_visual_range_or_given():
    profile = simple_profile()
    assert REGISTRY.create(NAME, {"visual_range_m": 500.0}, RegionContext(profile)).alpha == pytest.approx(3.912 / 500.0)
    assert REGISTRY.create(NAME, {"extinction_per_m": 0.02}, RegionContext(profile)).alpha == 0.02
    with pytest.raises(ConfigError, match="visual_range_m"):
        REGISTRY.create(NAME, {"visual_range_m": 0.0}, RegionContext(profile))


def returns_of(points, object_id):
    return int(np.sum(points["object_id"] == object_id))


def test_haze_removes_far_returns_and_keeps_near_ones():
    clear, hazy = frame(regions=False), frame({"visual_range_m": 1000.0})
    assert returns_of(clear, 2) > 0 and returns_of(hazy, 2) == 0  # the wall at 80 m
    assert returns_of(hazy, 1) == returns_of(clear, 1) > 0  # the wall at 20 m
