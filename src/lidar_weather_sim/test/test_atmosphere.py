"""Atmosphere region: extinction, near-field statistics, road surface, rooftop reproduction."""

import json
import subprocess
from importlib.metadata import entry_points
from pathlib import Path

import numpy as np
import pytest
import yaml

from lidar_weather_sim.core.config import ConfigError
from lidar_weather_sim.core.points import Label
from lidar_weather_sim.experiments.reproduce import load_tables, simulate
from lidar_weather_sim.experiments.rooftop_states import RooftopStates, load_states
from lidar_weather_sim.regions.atmosphere import fit_path
from lidar_weather_sim.regions.base import REGISTRY, RegionContext
from lidar_weather_sim.regions.extinction import fog_alpha, rain_alpha, snow_alpha
from lidar_weather_sim.regions.weather import Weather
from lidar_weather_sim.sim.simulator import LidarSimulator
from lidar_weather_sim.testing.fixtures import MATERIALS, beams_along_x, one_frame, scene_of, simple_profile, wall


def test_plugins_are_registered_by_entry_point():
    names = {ep.name for ep in entry_points(group="lidar_weather_sim.regions")}
    assert {"cover", "atmosphere"} <= names


def test_extinction_relations():
    assert fog_alpha(50.0) == pytest.approx(3.912 / 50.0)
    assert 0 < rain_alpha(1.0) < rain_alpha(10.0) < fog_alpha(1000.0)
    assert rain_alpha(10.0) == pytest.approx(1.076 * 10**0.67 * np.log(10) / 1e4)
    assert 0 < snow_alpha(1.0) < snow_alpha(5.0)


def _quiet_fit(tmp_path, **changes):
    """The shipped fit with the near field and path scatterers switched off (extinction/road only)."""
    data = yaml.safe_load(fit_path().read_text())
    for c in data["classes"].values():
        c.update({"rate_per_beam": 0.0, "path_rate_per_beam": 0.0, **changes})
    path = tmp_path / "fit.yaml"
    path.write_text(yaml.safe_dump(data))
    return str(path)


def test_fog_of_50_m_removes_returns_beyond_the_predicted_range(tmp_path):
    profile = simple_profile()
    fit = _quiet_fit(tmp_path)
    alpha = fog_alpha(50.0)
    det = profile.detection
    level = det.noise_mean + det.threshold_sigma * det.noise_sigma
    rho = MATERIALS["concrete"].reflectivity
    r = np.linspace(1.0, 150.0, 150000)
    r_max = r[np.nonzero(det.power_constant * rho / r**2 * np.exp(-2 * alpha * r) > level)[0][-1]]
    assert 10 < r_max < 60  # clear air: 150 m
    weather = Weather.model_validate({"fog": {"visual_range_m": 50.0}})
    for distance, seen in ((0.9 * r_max, True), (1.1 * r_max, False)):
        region = REGISTRY.create("atmosphere", {"fit_file": fit}, RegionContext(profile, weather, MATERIALS))
        assert region.weather_class == "fog" and region.alpha == pytest.approx(alpha)
        sim = LidarSimulator(profile, scene_of(wall(distance, "concrete", 1, half_width=5.0)), regions=[("atmosphere", region)])
        central = one_frame(sim).points
        central = central[np.abs(central["azimuth"]) < 1e-6]
        assert (len(central) == 1) is seen, distance
        clear = one_frame(LidarSimulator(profile, scene_of(wall(distance, "concrete", 1, half_width=5.0)))).points
        assert np.any(np.abs(clear["azimuth"]) < 1e-6)


def test_fog_with_rain_draws_each_weather_at_its_own_extinction():
    """Fog 50 m + rain 10 mm/h: the fog's and the rain's scatterers as each draws them alone (before, the rain
    class at the total extinction: ~20x its scatterers, all labelled rain), the total extinction, the rain's road."""
    profile = simple_profile()
    fog = {"fog": {"visual_range_m": 50.0}}
    rain = {"precipitation": {"type": "rain", "intensity_mm_h": 10.0}}
    batch = beams_along_x(np.full(20000, 30.0))

    def drawn(weather: dict):
        region = REGISTRY.create("atmosphere", {}, RegionContext(profile, Weather.model_validate(weather), MATERIALS))
        return region, region.apply(batch, np.random.default_rng(5))

    (fog_region, fog_alone), (rain_region, rain_alone), (both_region, both) = map(drawn, (fog, rain, {**fog, **rain}))
    for label in (Label.COVER, Label.FOG, Label.RAIN):
        expected = sum(int((e.scatterers.label == label).sum()) for e in (fog_alone, rain_alone))
        got = int((both.scatterers.label == label).sum())
        assert abs(got - expected) <= 5 * np.sqrt(expected) + 5, (label, got, expected)
    assert (both.scatterers.label == Label.FOG).sum() > 20 and (both.scatterers.label == Label.RAIN).sum() > 1000
    np.testing.assert_allclose(both.extinction_per_m, fog_alpha(50.0) + rain_alpha(10.0))
    assert both_region._wet_scale == rain_region._wet_scale != fog_region._wet_scale


def test_wet_and_snow_covered_road():
    profile = simple_profile()
    batch_region = lambda cls: REGISTRY.create("atmosphere", {"weather_class": cls}, RegionContext(profile, None, MATERIALS))  # noqa: E731
    rain, snow = batch_region("rain"), batch_region("snow")
    wet = MATERIALS["asphalt_wet"].reflectivity / MATERIALS["asphalt_dry"].reflectivity
    assert rain._wet_scale == pytest.approx(wet ** rain.c.wetness)
    assert snow.c.snow_depth_m > 0 and snow._snow_refl == MATERIALS["snow"].reflectivity


def test_the_road_block_sets_wetness_and_snow_cover_and_the_region_parameter_overrides_the_film():
    profile = simple_profile()
    wet = MATERIALS["asphalt_wet"].reflectivity / MATERIALS["asphalt_dry"].reflectivity

    def region(road, **params):
        weather = Weather.model_validate({"road": road})
        return REGISTRY.create("atmosphere", {"weather_class": "rain", **params}, RegionContext(profile, weather, MATERIALS))

    fitted = region({})
    assert fitted.wetness == fitted.c.wetness and fitted.snow_depth_m == fitted.c.snow_depth_m == 0.0
    film = region({"water_film_mm": 1.2, "texture_depth_mm": 0.6})
    assert film.wetness == pytest.approx(1.0 - np.exp(-2.0)) and film._wet_scale == pytest.approx(wet ** film.wetness)
    assert region({"water_film_mm": 1.2}, road_water_film_mm=0.0).wetness == 0.0  # the gap effects' isolation
    assert region({"snow_depth_m": 0.05}).snow_depth_m == 0.05
    with pytest.raises(ConfigError, match=r"key 'road_texture_depth_mm' moved to weather.road.texture_depth_mm"):
        region({}, road_texture_depth_mm=2.0)


@pytest.fixture(scope="module")
def rooftop():
    return {(w, False): simulate(w, False, 6, seed=3) for w in ("clear", "rain", "snow")}


def _mean(cond, region, key):
    return float(np.nanmean([f[region][key] for f in cond.frames]))


def test_snow_gives_a_wider_near_field_than_rain(rooftop):
    snow, rain = _mean(rooftop["snow", False], "atmosphere", "x_sigma"), _mean(rooftop["rain", False], "atmosphere", "x_sigma")
    assert snow > 2 * rain, (snow, rain)


def test_rain_raises_street_second_echoes(rooftop):
    rain, clear = _mean(rooftop["rain", False], "street", "n_e2"), _mean(rooftop["clear", False], "street", "n_e2")
    assert rain > 1.3 * clear, (rain, clear)


def test_reproduce_rooftop_writes_a_valid_json(tmp_path, cli):
    out = tmp_path / "rt"
    proc = subprocess.run([*cli, "reproduce", "rooftop", "--frames", "2", "--out", str(out)], capture_output=True, text=True,
                          timeout=600)  # fmt: skip
    assert proc.returncode == 0, proc.stderr
    rows = json.loads((out / "rooftop.json").read_text())
    keys = {"weather", "sun", "region", "parameter", "unit", "sim_mean", "sim_std", "paper_mean", "paper_std"}
    assert all(set(r) == keys for r in rows)
    assert {(r["weather"], r["sun"]) for r in rows} == {(w, s) for w in ("clear", "rain", "fog", "snow") for s in (True, False)}
    assert {r["region"] for r in rows} == {"atmosphere", "street", "both"}
    atm = [r for r in rows if r["region"] == "atmosphere"]
    assert len({r["parameter"] for r in atm}) == 12
    assert sum(r["paper_mean"] is not None for r in rows) == 8 * 10 + 2 * 3  # Tables 3, 4 and Table 2 (clear)
    assert (out / "rooftop.md").exists() and (out / "rooftop_atmosphere.png").stat().st_size > 1000


@pytest.mark.slow
def test_reproduce_rooftop_takes_another_sensor_profile_and_fit_file(tmp_path, cli):
    from lidar_weather_sim.core.paths import config_dir

    profile = yaml.safe_load((config_dir() / "sensors" / "scala4.yaml").read_text())
    profile["detection"]["sun_noise_per_w_m2"] *= 2.0  # a receiver that sunlight blinds more
    profile_path = tmp_path / "scala4_sunblind.yaml"
    profile_path.write_text(yaml.safe_dump(profile))
    fit = yaml.safe_load(fit_path().read_text())
    fit["classes"]["clear"]["rate_per_beam"] *= 2.0  # twice the near-field detections per beam
    fit_file = tmp_path / "fit.yaml"
    fit_file.write_text(yaml.safe_dump(fit))

    def near_field(sun, **kw):
        return _mean(simulate("clear", sun, 3, seed=5, **kw), "atmosphere", "n_total")

    night, day = near_field(False), near_field(True)
    assert near_field(False, profile=str(profile_path)) == night  # the noise model acts only in sunlight
    assert near_field(True, profile=str(profile_path)) < 0.8 * day
    assert near_field(False, fit_file=str(fit_file)) > 1.6 * night

    out = tmp_path / "rt"
    for bad, name in (("--profile", "no_such_sensor"), ("--fit-file", str(tmp_path / "missing_fit.yaml"))):
        proc = subprocess.run([*cli, "reproduce", "rooftop", "--frames", "1", "--out", str(out), bad, name],
                              capture_output=True, text=True, timeout=600)  # fmt: skip
        assert proc.returncode == 2 and len(proc.stderr.strip().splitlines()) == 1, proc.stderr
        assert Path(name).name in proc.stderr and not out.exists()


#: matched paper means (Tables 2-4, 86 in all) of `reproduce rooftop` at 10 frames, seed 0, with the
#: fitted config/atmosphere_fit.yaml and the geometry of config/rooftop.yaml; raise it when a change
#: matches more, never lower it to make a change pass. (Lowered once, 69 -> 64, by a physics decision,
#: not to pass: clear air lost its fitted "dust" path scatterers, which matched the clear-night street
#: but put ~1000 noise points into every clear scala4 driving frame.)
MATCHED_AT_10_FRAMES = 64
#: the same for the physical atmosphere with config/rooftop_physical.yaml, of the 80 means of Tables 3-4
PHYSICAL_MATCHED_AT_10_FRAMES = 51


@pytest.mark.slow
def test_reproduce_rooftop_runs_the_physical_atmosphere_without_the_fitted_near_field(tmp_path, cli):
    """``--atmosphere-model physical``: the states' fog from its drop-size distribution; the class's fitted
    near-field rate no longer acts (it does on the fitted model). States that miss a class, or states given to the
    fitted model, exit 2 with a one-line reason naming the file, and write nothing."""
    fit = yaml.safe_load(fit_path().read_text())
    fit["classes"]["fog"]["rate_per_beam"] *= 3.0
    fit_file = tmp_path / "fit.yaml"
    fit_file.write_text(yaml.safe_dump(fit))

    def near_field(model, **kw):
        return _mean(simulate("fog", False, 2, seed=5, atmosphere_model=model, **kw), "atmosphere", "n_total")

    assert near_field("physical", fit_file=str(fit_file)) == near_field("physical") > 0
    assert near_field("fitted", fit_file=str(fit_file)) > 1.5 * near_field("fitted")
    out = tmp_path / "rt"
    proc = subprocess.run([*cli, "reproduce", "rooftop", "--frames", "1", "--out", str(out), "--atmosphere-model",
                           "physical"], capture_output=True, text=True, timeout=600)  # fmt: skip
    assert proc.returncode == 0 and len(json.loads((out / "rooftop.json").read_text())) > 0, proc.stderr
    bad = tmp_path / "states.yaml"  # states without rain, fog and snow; then good states on the fitted model
    bad.write_text("window_ghosts: {scale_m: 0.1, amplitude: 2, sigma_ln: 0.5}\nclasses: {clear: {window_ghosts_per_beam: 0.2}}\n")
    for extra, reason in ((["--atmosphere-model", "physical"], "no state for rain, fog, snow"),
                          ([], "add --atmosphere-model physical")):  # fmt: skip
        proc = subprocess.run([*cli, "reproduce", "rooftop", "--frames", "1", "--out", str(tmp_path / "bad"), "--states",
                               str(bad), *extra], capture_output=True, text=True, timeout=600)  # fmt: skip
        assert proc.returncode == 2 and str(bad) in proc.stderr and reason in proc.stderr, proc.stderr
        assert len(proc.stderr.strip().splitlines()) == 1 and not (tmp_path / "bad").exists()


def test_physical_rooftop_clear_nights_get_the_sensors_cover_term():
    """The physical atmosphere has no cover returns of its own; its rooftop runs take the window's ghosts of
    config/rooftop_physical.yaml (the cover region's): the clear night's near field then holds the paper's
    244 +- 16 detections a frame (0 without them), and fewer under the sun's raised threshold."""
    paper, sigma = load_tables()["atmosphere_region"]["n_total"]["clear"]["sun_false"]
    night = _mean(simulate("clear", False, 12, seed=3, atmosphere_model="physical"), "atmosphere", "n_total")
    day = _mean(simulate("clear", True, 12, seed=3, atmosphere_model="physical"), "atmosphere", "n_total")
    assert abs(night - paper) <= sigma, night
    assert day < 0.7 * night


def test_physical_rooftop_takes_the_weather_and_the_window_from_its_states():
    """The rain class's rate and wet window come from the states: doubling the window's ghosts (0.1 -> 0.2 a beam)
    doubles the near field's cover peak (0-0.5 m), and 20 mm/h of rain instead of a drizzle puts drops over
    0.5-5 m, widening the near field."""
    states = load_states()

    def rain(**changes):
        data = states.model_dump()
        data["classes"]["rain"].update({"precipitation_mm_h": 0.1, "window_ghosts_per_beam": 0.1, **changes})
        return simulate("rain", False, 6, seed=2, atmosphere_model="physical", states=RooftopStates.model_validate(data))

    base, wet, heavy = rain(), rain(window_ghosts_per_beam=0.2), rain(precipitation_mm_h=20.0)
    cover = [int(np.sum(c.x["atmosphere"] < 0.5)) for c in (base, wet)]
    assert 1.7 < cover[1] / cover[0] < 2.3, cover
    assert _mean(heavy, "atmosphere", "x_sigma") > 3 * _mean(base, "atmosphere", "x_sigma")


def test_physical_rooftop_reproduction_matches_at_least_the_recorded_number_of_paper_means(tmp_path):
    """``reproduce rooftop --atmosphere-model physical`` with config/rooftop_physical.yaml
    (benchmarks/calibration/fit_physical_rooftop.py --columns all) on a seed the fit did not use."""
    from lidar_weather_sim.experiments.reproduce import reproduce_rooftop, within_sigma

    rows = reproduce_rooftop(tmp_path, frames=10, seed=0, plots=False, atmosphere_model="physical")
    regions = [within_sigma(r) for r in rows if r["region"] != "both" and within_sigma(r) is not None]
    assert len(regions) == 80
    assert sum(regions) >= PHYSICAL_MATCHED_AT_10_FRAMES, [
        (r["weather"], r["sun"], r["region"], r["parameter"], r["sim_mean"], r["paper_mean"]) for r in rows if within_sigma(r) is False
    ]


def test_rooftop_reproduction_matches_at_least_the_recorded_number_of_paper_means(tmp_path):
    from lidar_weather_sim.experiments.reproduce import reproduce_rooftop, within_sigma

    rows = reproduce_rooftop(tmp_path, frames=10, seed=0, plots=False)
    compared = [within_sigma(r) for r in rows if within_sigma(r) is not None]
    assert len(compared) == 86
    assert sum(compared) >= MATCHED_AT_10_FRAMES, [
        (r["weather"], r["sun"], r["region"], r["parameter"], r["sim_mean"], r["paper_mean"]) for r in rows if within_sigma(r) is False
    ]
