"""Atmosphere region: extinction, near-field statistics, road surface, rooftop reproduction."""

import json
import subprocess
from importlib.metadata import entry_points

import numpy as np
import pytest
import yaml

from lidar_weather_sim.core.config import ConfigError
from lidar_weather_sim.core.points import Label
from lidar_weather_sim.experiments.reproduce import load_tables, simulate
from lidar_weather_sim.experiments.rooftop_states import RooftopStates, load_states
from lidar_weather_sim.regions.base import REGISTRY, RegionContext
from lidar_weather_sim.regions.extinction import fog_alpha, rain_alpha, snow_alpha
from lidar_weather_sim.regions.weather import Road, Weather
from lidar_weather_sim.sensor.profile import load_profile
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


def _region(weather: dict | None = None, profile=None, **params):
    context = RegionContext(profile or simple_profile(), Weather.model_validate(weather or {}), MATERIALS)
    return REGISTRY.create("atmosphere", params, context)


def test_fog_of_50_m_removes_the_wall_beyond_the_predicted_range():
    """The wall's echo through 50 m fog survives where the LIDAR equation with the region's extinction (its Mie
    alpha at the profile's wavelength) keeps it above the threshold, and is gone 10 % farther (the fog's own
    echoes stay)."""
    profile = simple_profile()
    region = _region({"fog": {"visual_range_m": 50.0}}, profile)
    alpha = region.alpha
    assert 0.5 * fog_alpha(50.0) < alpha < 1.5 * fog_alpha(50.0)  # Koschmieder's 550 nm alpha, Mie at 905 nm
    det = profile.detection
    level = det.noise_mean + det.threshold_sigma * det.noise_sigma
    rho = MATERIALS["concrete"].reflectivity
    r = np.linspace(1.0, 150.0, 150000)
    r_max = r[np.nonzero(det.power_constant * rho / r**2 * np.exp(-2 * alpha * r) > level)[0][-1]]
    assert 10 < r_max < 60  # clear air: 150 m
    for distance, seen in ((0.9 * r_max, True), (1.1 * r_max, False)):
        scene = scene_of(wall(distance, "concrete", 1, half_width=5.0))
        central = one_frame(LidarSimulator(profile, scene, regions=[("atmosphere", region)])).points
        central = central[(np.abs(central["azimuth"]) < 1e-6) & (central["label"] != Label.FOG)]
        assert (len(central) == 1) is seen, distance
        clear = one_frame(LidarSimulator(profile, scene)).points
        assert np.any(np.abs(clear["azimuth"]) < 1e-6)


def test_fog_with_rain_adds_the_extinctions_and_takes_the_rains_road():
    fog = {"fog": {"visual_range_m": 50.0}}
    rain = {"precipitation": {"type": "rain", "intensity_mm_h": 10.0}}
    scala4 = load_profile("scala4")
    (fog_region, rain_region, both) = (_region(w, scala4) for w in (fog, rain, {**fog, **rain}))
    assert both.alpha == pytest.approx(fog_region.alpha + rain_region.alpha)
    assert fog_region.wetness == 0.0 < rain_region.wetness == both.wetness
    batch = beams_along_x(np.full(20000, 30.0))
    effect = both.apply(batch, np.random.default_rng(5))
    assert (effect.scatterers.label == Label.RAIN).sum() > 100 and effect.volume
    np.testing.assert_allclose(effect.extinction_per_m, both.alpha)


def test_the_road_block_sets_wetness_and_snow_cover_and_the_region_parameter_overrides_the_film():
    """No film given: eq. 1's film of the rain (dry without rain); a film given, or the region's own, wins; no
    snow cover unless the road block sets one."""
    wet = MATERIALS["asphalt_wet"].reflectivity / MATERIALS["asphalt_dry"].reflectivity
    rain = {"precipitation": {"type": "rain", "intensity_mm_h": 2.0}}

    def region(road, weather=rain, **params):
        return _region({**weather, "road": road}, **params)

    eq1 = region({})
    film = Road().film_mm(2.0)
    assert 0.6 < film < 0.8  # the thesis' highway: 0.7 mm at 2 mm/h (Fig. 13)
    assert eq1.wetness == pytest.approx(1.0 - np.exp(-film / 1.5)) and eq1.snow_depth_m == 0.0
    assert region({}, weather={}).wetness == 0.0
    assert region({}, weather={"precipitation": {"type": "snow", "intensity_mm_h": 2.0}}).wetness == 0.0
    given = region({"water_film_mm": 1.2, "texture_depth_mm": 0.6})
    assert given.wetness == pytest.approx(1.0 - np.exp(-2.0)) and given._wet_scale == pytest.approx(wet ** given.wetness)
    assert region({"water_film_mm": 1.2}, road_water_film_mm=0.0).wetness == 0.0  # the gap effects' isolation
    snow = region({"snow_depth_m": 0.05})
    assert snow.snow_depth_m == 0.05 and snow._snow_refl == MATERIALS["snow"].reflectivity
    with pytest.raises(ConfigError, match=r"key 'road_texture_depth_mm' moved to weather.road.texture_depth_mm"):
        region({}, road_texture_depth_mm=2.0)


def test_the_fitted_model_and_its_keys_are_refused_with_one_line_and_physical_is_accepted():
    assert _region(model="physical").alpha == 0.0
    for params in ({"model": "fitted"}, {"fit_file": "fit.yaml"}, {"weather_class": "rain"}):
        with pytest.raises(ConfigError, match="the fitted atmosphere model was removed: the atmosphere is physical") as err:
            _region(**params)
        assert len(str(err.value).strip().splitlines()) == 1, err.value


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


def test_reproduce_rooftop_takes_another_sensor_profile_and_refuses_bad_inputs(tmp_path, cli):
    """A sunblind receiver changes only the sunlit rows. A missing profile, states that miss a class, and the
    removed fitted model's flags exit 2 with one line and write nothing."""
    from lidar_weather_sim.core.paths import config_dir

    profile = yaml.safe_load((config_dir() / "sensors" / "scala4.yaml").read_text())
    profile["detection"]["sun_noise_per_w_m2"] *= 2.0  # a receiver that sunlight blinds more
    profile_path = tmp_path / "scala4_sunblind.yaml"
    profile_path.write_text(yaml.safe_dump(profile))

    def near_field(sun, **kw):
        return _mean(simulate("clear", sun, 3, seed=5, **kw), "atmosphere", "n_total")

    night, day = near_field(False), near_field(True)
    assert near_field(False, profile=str(profile_path)) == night  # the noise model acts only in sunlight
    assert near_field(True, profile=str(profile_path)) < 0.8 * day

    out = tmp_path / "rt"
    bad = tmp_path / "states.yaml"  # states without rain, fog and snow
    bad.write_text("window_ghosts: {scale_m: 0.1, amplitude: 2, sigma_ln: 0.5}\nclasses: {clear: {window_ghosts_per_beam: 0.2}}\n")
    for args, reason in ((["--profile", "no_such_sensor"], "no_such_sensor"),
                         (["--states", str(bad)], "no state for rain, fog, snow"),
                         (["--fit-file", "fit.yaml"], "--fit-file was removed with the fitted atmosphere model"),
                         (["--atmosphere-model", "fitted"], "--atmosphere-model was removed")):  # fmt: skip
        proc = subprocess.run([*cli, "reproduce", "rooftop", "--frames", "1", "--out", str(out), *args],
                              capture_output=True, text=True, timeout=600)  # fmt: skip
        assert proc.returncode == 2 and len(proc.stderr.strip().splitlines()) == 1, proc.stderr
        assert reason in proc.stderr and not out.exists(), proc.stderr


#: matched paper means (of the 80 of Tables 3-4) of `reproduce rooftop` at 10 frames, seed 0, with
#: config/rooftop_physical.yaml and the geometry of config/rooftop.yaml; raise it when a change matches more, never
#: lower it to make a change pass.
MATCHED_AT_10_FRAMES = 51


def test_physical_rooftop_clear_nights_get_the_sensors_cover_term():
    """The atmosphere has no cover returns of its own; the rooftop runs take the window's ghosts of
    config/rooftop_physical.yaml (the cover region's): the clear night's near field then holds the paper's
    244 +- 16 detections a frame (0 without them), and fewer under the sun's raised threshold."""
    paper, sigma = load_tables()["atmosphere_region"]["n_total"]["clear"]["sun_false"]
    night = _mean(simulate("clear", False, 12, seed=3), "atmosphere", "n_total")
    day = _mean(simulate("clear", True, 12, seed=3), "atmosphere", "n_total")
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
        return simulate("rain", False, 6, seed=2, states=RooftopStates.model_validate(data))

    base, wet, heavy = rain(), rain(window_ghosts_per_beam=0.2), rain(precipitation_mm_h=20.0)
    cover = [int(np.sum(c.x["atmosphere"] < 0.5)) for c in (base, wet)]
    assert 1.7 < cover[1] / cover[0] < 2.3, cover
    assert _mean(heavy, "atmosphere", "x_sigma") > 3 * _mean(base, "atmosphere", "x_sigma")


def test_rooftop_reproduction_matches_at_least_the_recorded_number_of_paper_means(tmp_path):
    """``reproduce rooftop`` with config/rooftop_physical.yaml (benchmarks/calibration/fit_physical_rooftop.py
    --columns all) on a seed the fit did not use."""
    from lidar_weather_sim.experiments.reproduce import reproduce_rooftop, within_sigma

    rows = reproduce_rooftop(tmp_path, frames=10, seed=0, plots=False)
    regions = [within_sigma(r) for r in rows if r["region"] != "both" and within_sigma(r) is not None]
    assert len(regions) == 80
    assert sum(regions) >= MATCHED_AT_10_FRAMES, [
        (r["weather"], r["sun"], r["region"], r["parameter"], r["sim_mean"], r["paper_mean"]) for r in rows if within_sigma(r) is False
    ]
