"""SWEEP.yaml: validation, expansion into runs, run identity (no simulation, no Dask)."""

from __future__ import annotations

import pytest
import yaml

from lidar_weather_sim.core.config import ConfigError
from lidar_weather_sim.sweep.run_spec import code_version
from lidar_weather_sim.sweep.spec import expand, load_sweep, points, set_dotted


def _sweep(tmp_path, **keys):
    path = tmp_path / "sweep.yaml"
    path.write_text(yaml.safe_dump({"scenario": "highway_spray", "frames": 2, **keys}))
    return path


def test_grid_times_seeds_each_with_its_validated_scenario(tmp_path):
    spec = load_sweep(_sweep(tmp_path, seeds=[3, 4], grid={"weather.fog.visual_range_m": [60, 200],
                                                          "actors.0.speed_m_s": [20.0, 25.0, 30.0]}))
    runs = expand(spec)
    assert len(runs) == 2 * 3 * 2
    assert {(r.point["weather.fog.visual_range_m"], r.point["actors.0.speed_m_s"], r.seed) for r in runs} == {
        (v, s, seed) for v in (60, 200) for s in (20.0, 25.0, 30.0) for seed in (3, 4)}
    first = runs[0]
    assert first.scenario["weather"]["fog"]["visual_range_m"] == 60
    assert first.scenario["actors"][0]["speed_m_s"] == 20.0
    assert first.scenario["actors"][0]["id"] == 100  # the rest of the scenario is kept


def test_random_draws_are_seeded_and_in_range(tmp_path):
    keys = {"weather.fog.visual_range_m": {"low": 30, "high": 500, "log": True},
            "weather.precipitation.intensity_mm_h": [1, 50],
            "weather.precipitation.type": {"choices": ["rain", "snow"]},
            "actors.0.lead_gap_m": {"low": 10, "high": 30, "integer": True}}
    spec = load_sweep(_sweep(tmp_path, random={"count": 200, "seed": 7, "keys": keys}))
    a, b = points(spec), points(spec)
    assert a == b and len(a) == 200
    fog = [p["weather.fog.visual_range_m"] for p in a]
    assert min(fog) >= 30 and max(fog) <= 500
    assert sum(f < 122.5 for f in fog) in range(70, 131)  # log-uniform: half below the geometric mean
    assert {p["weather.precipitation.type"] for p in a} == {"rain", "snow"}
    gaps = {p["actors.0.lead_gap_m"] for p in a}
    assert gaps <= set(range(10, 31)) and len(gaps) > 15
    other = load_sweep(_sweep(tmp_path, random={"count": 200, "seed": 8, "keys": keys}))
    assert points(other) != a


@pytest.mark.parametrize("keys, reason", [
    ({"grid": {}}, "'grid' is empty"),
    ({"grid": {"weather.fog.visual_range_m": []}}, "has no values"),
    ({"grid": {"weather.fog.visual_range_m": [60]}, "random": {"count": 2, "keys": {"seed": [0, 1]}}}, "not both"),
    ({"sedes": [1]}, "sedes"),
    ({"compute": ["stats", "nonsense"]}, "nonsense"),
    ({"seeds": [1, 1]}, "distinct"),
    ({"profile": "vlp16", "grid": {"sensor.profile": ["scala4", "os1_128_1024"]}}, "'profile' overrides it"),
    ({"grid": {"seed": [1, 2]}}, "'seeds' overrides it"),
    ({"random": {"count": 3, "keys": {"weather.fog.visual_range_m": {"low": 0, "high": 9, "log": True}}}}, "low > 0"),
])
def test_bad_sweep_files_name_the_problem(tmp_path, keys, reason):
    with pytest.raises(ConfigError, match=reason):
        expand(load_sweep(_sweep(tmp_path, **keys)))


@pytest.mark.parametrize("key, value, reason", [
    ("weather.fgo.visual_range_m", 60, "'weather.fgo': the scenario has no such key"),
    ("actors.5.speed_m_s", 20, "index out of range"),
    ("weather.fog.visual_range_m", -5, "weather.fog.visual_range_m"),
    ("region_params.cover.dirt", 0.5, "region_params"),  # cover is not among highway_spray's regions
])
def test_keys_and_values_the_scenario_refuses(tmp_path, key, value, reason):
    with pytest.raises(ConfigError, match=reason):
        expand(load_sweep(_sweep(tmp_path, grid={key: [value]})))


def test_weather_key_without_the_region_that_reads_it_is_refused(tmp_path):
    path = tmp_path / "s.yaml"
    path.write_text(yaml.safe_dump({"scenario": "highway_clear", "frames": 1, "grid": {"weather.fog.visual_range_m": [50]}}))
    with pytest.raises(ConfigError, match="acts only through the region.*atmosphere"):
        expand(load_sweep(path))


def test_region_parameters_may_be_set_when_absent(tmp_path):
    runs = expand(load_sweep(_sweep(tmp_path, grid={"region_params.spray.film_cv": [0.2, 0.4]})))
    assert [r.scenario["region_params"]["spray"]["film_cv"] for r in runs] == [0.2, 0.4]
    data = {"a": [{"b": 1}]}
    set_dotted(data, "a.0.b", 2)
    assert data == {"a": [{"b": 2}]}


def test_run_identity_follows_spec_and_code(tmp_path):
    runs = expand(load_sweep(_sweep(tmp_path, seeds=[1, 2], grid={"weather.fog.visual_range_m": [60, 200]})))
    version = code_version()
    ids = [r.identity(version) for r in runs]
    assert len(set(ids)) == 4
    again = expand(load_sweep(_sweep(tmp_path, seeds=[1, 2], grid={"weather.fog.visual_range_m": [60, 200]})))
    assert [r.identity(version) for r in again] == ids
    assert [r.identity("another-version") for r in runs] != ids
