"""The unit's response after detection (sensor.response): intensity gamma and scale, range bias and noise, ray drop."""

from __future__ import annotations

import numpy as np
import pytest

from lidar_weather_sim.core.points import empty_points
from lidar_weather_sim.scenario.schema import load_scenario
from lidar_weather_sim.sensor.response import SensorResponse, apply_response, intensity_table
from lidar_weather_sim.sim.offline import run_scenario


def _points(n=20000, seed=0):
    rng = np.random.default_rng(seed)
    p = empty_points(n)
    d = rng.uniform(2.0, 80.0, n)
    direction = rng.normal(size=(n, 3))
    direction /= np.linalg.norm(direction, axis=1, keepdims=True)
    p["x"], p["y"], p["z"] = (direction * d[:, None]).T
    p["distance"] = d
    p["intensity"] = rng.integers(0, 256, n)
    return p


def test_intensity_gamma_and_scale_follow_the_formula():
    table = intensity_table(SensorResponse(intensity_gamma=2.0))
    assert table[0] == 0 and table[255] == 255 and table[128] == round(255 * (128 / 255) ** 2) == 64
    table = intensity_table(SensorResponse(intensity_scale=2.0))
    assert table[100] == 200 and table[200] == 255  # saturates at 255
    p = _points()
    out = apply_response(p.copy(), SensorResponse(intensity_gamma=0.5), np.random.default_rng(0), 0.3)
    assert np.array_equal(out["intensity"], np.round(255 * np.sqrt(p["intensity"] / 255)).astype(np.uint8))


def test_range_bias_moves_every_return_along_its_ray():
    p = _points()
    out = apply_response(p.copy(), SensorResponse(range_bias_m=-0.25), np.random.default_rng(0), 0.3)
    assert len(out) == len(p)
    assert np.allclose(out["distance"], p["distance"] - 0.25, atol=1e-5)
    xyz, xyz0 = (np.stack([q[a] for a in "xyz"], 1).astype(np.float64) for q in (out, p))
    assert np.allclose(np.linalg.norm(xyz, axis=1), out["distance"], atol=1e-4)
    cos = (xyz * xyz0).sum(1) / np.linalg.norm(xyz, axis=1) / np.linalg.norm(xyz0, axis=1)
    assert cos.min() > 1 - 1e-9


def test_range_noise_sigma_and_returns_pushed_below_the_minimum_range_are_lost():
    p = _points()
    out = apply_response(p.copy(), SensorResponse(range_noise_m=0.05), np.random.default_rng(1), 0.3)
    assert len(out) == len(p)
    assert np.std(out["distance"] - p["distance"]) == pytest.approx(0.05, rel=0.03)
    near = p.copy()
    near["distance"] = 0.4
    out = apply_response(near, SensorResponse(range_bias_m=-0.2), np.random.default_rng(1), 0.3)
    assert len(out) == 0


def test_ray_drop_takes_dark_returns_first():
    p = _points(100000)
    out = apply_response(p.copy(), SensorResponse(drop_probability=0.6), np.random.default_rng(2), 0.3)
    dark, bright = p["intensity"] < 32, p["intensity"] >= 224
    kept_dark = np.isin(p["distance"][dark], out["distance"]).mean()
    kept_bright = np.isin(p["distance"][bright], out["distance"]).mean()
    assert kept_dark == pytest.approx(1 - 0.6 * (1 - 15.5 / 255), abs=0.02)
    assert kept_bright == pytest.approx(1 - 0.6 * (1 - 239.5 / 255), abs=0.01)
    again = apply_response(p.copy(), SensorResponse(drop_probability=0.6), np.random.default_rng(2), 0.3)
    assert np.array_equal(out, again)


def test_default_response_changes_nothing_and_a_scenario_response_reaches_the_clouds(tmp_path):
    from lidar_weather_sim.io.bags import read_clouds

    p = _points()
    assert apply_response(p, SensorResponse(), np.random.default_rng(0), 0.3) is p
    scenario = load_scenario("highway_clear")
    biased = scenario.model_copy(update={"sensor": scenario.sensor.model_copy(
        update={"response": SensorResponse(range_bias_m=0.5, intensity_gamma=2.0)})})  # fmt: skip
    run_scenario(scenario, tmp_path / "plain", frames=2, seed=3)
    run_scenario(biased, tmp_path / "biased", frames=2, seed=3)
    for a, b in zip(read_clouds(tmp_path / "plain"), read_clouds(tmp_path / "biased")):
        a, b = a.points, b.points
        assert len(b) == len(a) > 500  # a positive bias loses nothing
        assert np.allclose(b["distance"], a["distance"] + 0.5, atol=1e-4)
        assert np.array_equal(b["intensity"], intensity_table(SensorResponse(intensity_gamma=2.0))[a["intensity"]])
        assert np.array_equal(b["label"], a["label"]) and np.array_equal(b["channel"], a["channel"])
