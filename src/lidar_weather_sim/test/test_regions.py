"""The region protocol: regions change light transport; the echo stage alone decides detections."""

import numpy as np
import pydantic
import pytest

from lidar_weather_sim.core.config import ConfigError, ConfigModel
from lidar_weather_sim.core.points import Label
from lidar_weather_sim.regions.base import REGISTRY, RegionContext, RegionEffect, Scatterers, region_rng
from lidar_weather_sim.sensor.radiometry import FWHM_TO_SIGMA
from lidar_weather_sim.sim.simulator import LidarSimulator
from lidar_weather_sim.testing.fixtures import one_frame, scene_of, simple_profile, wall


class Haze:
    """Test region: a uniform one-way transmission, extinction, and one scatterer per beam."""

    name = "haze"

    class Params(ConfigModel):
        transmission: float = pydantic.Field(1.0, ge=0, le=1)
        extinction_per_m: float = pydantic.Field(0.0, ge=0)
        scatterer_range_m: float = pydantic.Field(0.0, ge=0)
        scatterer_reflectance: float = 0.0
        scatterer_occlusion: float = pydantic.Field(0.0, ge=0, le=1)
        reflectance_scale: float = 1.0
        range_offset_m: float = 0.0
        jitter_m: float = 0.0

    def __init__(self, params, context):
        self.p = params
        self.steps = []

    def step(self, t0_s, t1_s):
        self.steps.append((t0_s, t1_s))

    def apply(self, batch, rng):
        n, s = batch.shape
        p = self.p
        scatterers = None
        if p.scatterer_reflectance > 0:
            beams = np.arange(n)
            scatterers = Scatterers(
                beam=beams, subray=np.zeros(n, int), range_m=p.scatterer_range_m + rng.normal(0, p.jitter_m, n) if p.jitter_m else np.full(n, p.scatterer_range_m),
                reflectance=np.full(n, p.scatterer_reflectance), occlusion=np.full(n, p.scatterer_occlusion),
                label=np.full(n, Label.RAIN, np.uint8), object_id=np.zeros(n, np.uint32),
            )  # fmt: skip
        return RegionEffect(
            transmission=np.full((n, s), p.transmission),
            extinction_per_m=np.full((n, s), p.extinction_per_m),
            scatterers=scatterers,
            reflectance_scale=np.full((n, s), p.reflectance_scale),
            range_offset_m=np.full((n, s), p.range_offset_m),
        )


REGISTRY.register("haze", Haze)


def _sim(seed=0, **params):
    profile = simple_profile()
    region = REGISTRY.create("haze", params, RegionContext(profile))
    return LidarSimulator(profile, scene_of(wall(20.0, "concrete", 1)), regions=[("haze", region)], seed=seed)


def _centre(points):
    return points[np.argmin(np.abs(points["azimuth"]))]


def _epw_amplitude(epw, fwhm=0.6, threshold=4.0):
    s = fwhm * FWHM_TO_SIGMA
    return threshold * np.exp((epw / (2 * s)) ** 2 / 2)


def test_one_way_transmission_is_applied_twice():
    clear = _epw_amplitude(_centre(one_frame(_sim()).points)["epw"])
    dirty = _epw_amplitude(_centre(one_frame(_sim(transmission=0.8)).points)["epw"])
    assert dirty / clear == pytest.approx(0.8**2, rel=1e-3)


def test_extinction_is_beer_lambert_out_and_back():
    clear = _epw_amplitude(_centre(one_frame(_sim()).points)["epw"])
    foggy = _epw_amplitude(_centre(one_frame(_sim(extinction_per_m=0.01)).points)["epw"])
    assert foggy / clear == pytest.approx(np.exp(-2 * 0.01 * 20.0), rel=1e-3)


def test_scatterer_adds_an_echo_and_occludes_what_lies_behind():
    frame = one_frame(_sim(scatterer_range_m=5.0, scatterer_reflectance=0.02, scatterer_occlusion=0.5)).points
    central = frame[np.abs(frame["azimuth"]) < 1e-6]
    assert list(central["label"]) == [Label.RAIN, Label.STATIC]
    assert central["distance"][0] == pytest.approx(5.0, abs=1e-3)
    clear = _epw_amplitude(_centre(one_frame(_sim()).points)["epw"])
    assert _epw_amplitude(central["epw"][1]) / clear == pytest.approx(0.5**2, rel=1e-3)
    solid = one_frame(_sim(scatterer_range_m=5.0, scatterer_reflectance=0.02, scatterer_occlusion=1.0)).points
    assert set(solid["label"]) == {Label.RAIN}, "a fully occluding scatterer hides the wall"


def test_material_change_and_range_offset_act_on_scene_hits():
    base = _centre(one_frame(_sim()).points)
    wet = _centre(one_frame(_sim(reflectance_scale=0.25)).points)
    assert _epw_amplitude(wet["epw"]) / _epw_amplitude(base["epw"]) == pytest.approx(0.25, rel=1e-3)
    raised = _centre(one_frame(_sim(range_offset_m=-0.3)).points)
    assert raised["distance"] == pytest.approx(base["distance"] - 0.3, abs=1e-4)


def test_region_randomness_is_seeded_per_frame_and_plugin():
    a = one_frame(_sim(seed=3, scatterer_range_m=5.0, scatterer_reflectance=0.02, jitter_m=0.5)).points
    b = one_frame(_sim(seed=3, scatterer_range_m=5.0, scatterer_reflectance=0.02, jitter_m=0.5)).points
    c = one_frame(_sim(seed=4, scatterer_range_m=5.0, scatterer_reflectance=0.02, jitter_m=0.5)).points
    assert a.tobytes() == b.tobytes() and a.tobytes() != c.tobytes()
    x = region_rng(1, 2, "haze", 0).random()
    assert x == region_rng(1, 2, "haze", 0).random() != region_rng(1, 2, "cover", 0).random()


def test_registry_errors_name_the_region_and_the_parameter():
    with pytest.raises(ConfigError, match=r"unknown region 'nope' \(available: .*haze"):
        REGISTRY.create("nope", {}, RegionContext(None))
    with pytest.raises(ConfigError, match=r"region 'haze' parameters: key 'transmission': value 2"):
        REGISTRY.create("haze", {"transmission": 2}, RegionContext(None))
