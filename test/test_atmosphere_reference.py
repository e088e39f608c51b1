"""The independent atmosphere reference (references/droplets.py) and the simplified Hahner et al. fog (references/hahner.py):
drop counts, a lone hard target's echo, Beer-Lambert on every return, make-measured --reference bags, seeds."""

from __future__ import annotations

import subprocess

import numpy as np
import pytest
import yaml

from lidar_weather_sim.core.points import Label, ReturnType, empty_points
from lidar_weather_sim.scenario.effects import parse_effect
from lidar_weather_sim.references.hahner import KOSCHMIEDER, HahnerFog
from lidar_weather_sim.references.measured import make_measured
from lidar_weather_sim.references.droplets import Atmosphere, ReferenceAtmosphere, epw_of, intensity_bytes, scene_pulses
from lidar_weather_sim.io.recording import Recording
from lidar_weather_sim.physics.coefficients import medium
from lidar_weather_sim.physics.overlap import biaxial_overlap
from lidar_weather_sim.scenario.schema import load_scenario
from lidar_weather_sim.sensor.profile import load_profile
from lidar_weather_sim.sensor.radiometry import FWHM_TO_SIGMA
from lidar_weather_sim.testing.fixtures import receiver_variant


@pytest.fixture(scope="module")
def scala4():
    return load_profile("scala4")


def _points(ref: ReferenceAtmosphere, ranges, amplitudes, channel=1, column=290) -> np.ndarray:
    """Clear points on one beam (column, channel of scala4's frame 0) with the EPW of ``amplitudes``."""
    pts = empty_points(len(ranges))
    az = ref.scan.column_azimuth[column] + ref.scan.azimuth_offset[channel]
    el = ref.scan.elevation[channel]
    r = np.asarray(ranges, np.float64)
    pts["x"], pts["y"], pts["z"] = r * np.cos(el) * np.cos(az), r * np.cos(el) * np.sin(az), r * np.sin(el)
    pts["distance"], pts["azimuth"], pts["elevation"] = r, az, el
    pts["channel"] = channel
    pts["epw"] = epw_of(np.asarray(amplitudes, np.float64), ref.threshold, ref.sigma)
    pts["intensity"] = intensity_bytes(np.asarray(amplitudes, np.float64), ref.dark, ref.log_span)
    pts["label"] = Label.STATIC
    pts["object_id"] = 7
    pts["echo"] = np.arange(1, len(r) + 1)
    return pts


def test_poisson_drop_counts_match_n_times_volume(scala4):
    """Rain drops placed one by one in 0-5 m and seen by the receiver: their number matches
    N x (the beam volume weighted by the overlap O(r)) within 4 Poisson sigmas."""
    ref = ReferenceAtmosphere(scala4, Atmosphere(precipitation=("rain", 20.0)))
    beams = 2000
    parts = ref._particles(beams, np.random.default_rng(5))
    beam, r, _, _ = parts[int(Label.RAIN)]
    seen = int(np.sum(r < 5.0))
    m = medium("rain", 20.0, scala4.optics.wavelength_nm)
    rr = np.linspace(0.0, 5.0, 20001)
    o = scala4.optics
    radius = o.tx_aperture_radius_m + rr * np.tan(0.5e-3 * np.sqrt(o.divergence_h_mrad * o.divergence_v_mrad))
    overlap = biaxial_overlap(rr, o.lens_separation_m, 1e-3 * np.sqrt(o.divergence_h_mrad * o.divergence_v_mrad),
                              1e-3 * o.receiver_fov_mrad, o.tx_aperture_radius_m, o.rx_aperture_radius_m)  # fmt: skip
    expected = beams * m.number * np.trapezoid(np.pi * radius**2 * overlap, rr)
    assert expected > 500  # enough drops for the statistics to mean something
    assert abs(seen - expected) < 4.0 * np.sqrt(expected)
    assert set(np.unique(beam)) <= set(range(beams))


def test_lone_hard_target_echo_at_its_range_with_the_pulse_epw(scala4):
    """Fog of 100 km (almost no extinction): a lone target at 20 m is detected at 20 m (+-1 cm) with the EPW
    of its attenuated pulse, 2 s sqrt(2 ln(A/T)) (+-2 %), and keeps its label and object. (Single large fog
    droplets within a few m still give weak echoes on some beams: the profile's gain sees them.)"""
    ref = ReferenceAtmosphere(scala4, Atmosphere(fog_m=1e5))
    a = 16.0 * ref.threshold
    out = ref.apply(_points(ref, [20.0], [a]), 0, np.random.default_rng(1))
    assert np.all(out["distance"][out["label"] == Label.FOG] < 5.0)
    scene = out[out["label"] != Label.FOG]
    assert len(scene) == 1
    p = scene[0]
    assert p["distance"] == pytest.approx(20.0, abs=0.01)
    attenuated = a * np.exp(-2.0 * ref.alpha * 20.0)
    assert p["epw"] == pytest.approx(epw_of(np.array([attenuated]), ref.threshold, ref.sigma)[0], rel=0.02)
    assert p["epw"] == pytest.approx(2 * scala4.pulse.fwhm_m * np.sqrt(np.log(16.0) / np.log(2.0)) / 2, rel=0.03)
    assert p["label"] == Label.STATIC and p["object_id"] == 7 and p["echo"] == 1


def test_a_pulse_at_twice_the_threshold_has_the_pulse_width(scala4):
    """EPW of a pulse whose peak is twice the threshold is its FWHM."""
    ref = ReferenceAtmosphere(scala4, Atmosphere(fog_m=1e5))
    out = ref.apply(_points(ref, [30.0], [2.0 * ref.threshold / np.exp(-2 * ref.alpha * 30.0)]), 0,
                    np.random.default_rng(2))  # fmt: skip
    out = out[out["label"] == Label.STATIC]
    assert len(out) == 1 and out["epw"][0] == pytest.approx(scala4.pulse.fwhm_m, rel=0.02)


def test_dense_fog_hides_a_far_target_and_adds_near_echoes(scala4):
    ref = ReferenceAtmosphere(scala4, Atmosphere(fog_m=30.0))
    out = ref.apply(_points(ref, [60.0], [20.0 * ref.threshold]), 0, np.random.default_rng(3))
    assert not np.any(out["label"] == Label.STATIC)  # exp(-2 alpha 60) ~ 1e-7
    assert np.all(out["label"] == Label.FOG) and np.all(out["distance"] < 30.0)


@pytest.mark.validation
def test_weather_behind_a_near_target_is_hidden(scala4):
    """A wall 4 m ahead in fog of 100 m (whose volume echo alone is 16 m long) and in snow of 5 mm/h: nothing
    of the beam's echoes lies behind the wall (its own pulse aside): fog and flakes there cannot be seen."""
    s = scala4.pulse.fwhm_m
    for weather in (Atmosphere(fog_m=100.0), Atmosphere(precipitation=("snow", 5.0))):
        ref = ReferenceAtmosphere(scala4, weather)
        for seed in range(5):
            wall = _points(ref, [4.0], [50.0 * ref.threshold])
            out = ref.apply(wall, 0, np.random.default_rng(seed))
            out = out[(out["channel"] == 1) & (np.abs(out["azimuth"] - wall["azimuth"][0]) < 1e-4)]  # the wall's beam
            assert len(out) and np.all(out["distance"] <= 4.0 + s), out["distance"]
            assert np.all(out["distance"] + out["epw"] / 2 <= 4.0 + 2 * s)  # no echo reaching far behind it


def test_a_return_of_the_sensor_cover_does_not_hide_the_weather_behind_it(scala4):
    """A dirt return at 0.1 m (label COVER) is a partial reflection of the window, not a wall: in fog of 100 m
    the beam's echo reaches metres beyond it (scala4's AC-coupled receiver makes the fog's echo ~2 m long near
    1.1 m, merged with it; the dirt alone ends before 0.5 m), on every seed."""
    ref = ReferenceAtmosphere(scala4, Atmosphere(fog_m=100.0))
    for seed in range(5):
        dirt = _points(ref, [0.1], [3.0 * ref.threshold])
        dirt["label"] = Label.COVER
        out = ref.apply(dirt, 0, np.random.default_rng(seed))
        out = out[(out["channel"] == 1) & (np.abs(out["azimuth"] - dirt["azimuth"][0]) < 1e-4)]
        assert len(out) and np.max(out["distance"] + out["epw"] / 2) > 1.5, out[["distance", "epw"]]


def test_an_echo_summed_from_sub_rays_keeps_its_intensity_and_width_in_clear_air(scala4):
    """A vehicle's side: the simulator sums sub-rays at slightly different ranges into one echo 1.5x as wide as
    an isolated pulse of its peak. In air with no weather to speak of (fog of 100 km) the reference re-draws it
    with the same intensity (+-1 byte) and EPW (within 1 %); taking its peak from the EPW as an isolated
    pulse's made it ~100 bytes brighter."""
    ref = ReferenceAtmosphere(scala4, Atmosphere(fog_m=1e5))
    pts = _points(ref, [12.0, 30.0], [20.0 * ref.threshold, 300.0 * ref.threshold])
    pts["epw"] *= 1.5
    out = ref.apply(pts, 0, np.random.default_rng(0))
    out = out[out["label"] == Label.STATIC]
    assert len(out) == 2
    assert np.all(np.abs(out["intensity"].astype(int) - pts["intensity"].astype(int)) <= 1), out["intensity"]
    np.testing.assert_allclose(out["epw"], pts["epw"], rtol=0.01)


def test_unsampled_beams_keep_their_return_attenuated(scala4):
    ref = ReferenceAtmosphere(scala4, Atmosphere(fog_m=200.0), beams_per_frame=1)
    pts = np.concatenate([_points(ref, [25.0], [50.0 * ref.threshold], column=c) for c in range(100, 140)])
    out = ref.apply(pts, 0, np.random.default_rng(4))
    far = out[out["distance"] > 20.0]
    assert len(far) >= 39
    expected = 50.0 * ref.threshold * np.exp(-2 * ref.alpha * 25.0)
    a_out, _ = scene_pulses(far, ref.threshold, ref.sigma, ref.dark, ref.log_span)
    np.testing.assert_allclose(a_out, expected, rtol=0.02)  # the intensity byte's half step: 1.8 %
    np.testing.assert_allclose(far["epw"], epw_of(np.full(len(far), expected), ref.threshold, ref.sigma), rtol=0.01)


def test_hahner_attenuates_every_return_by_beer_lambert(scala4):
    """Hahner's single-return rule (a sensor reporting its strongest echo): strong returns stay, attenuated."""
    strongest = scala4.model_copy(update={"detection": scala4.detection.model_copy(update={"return_mode": "strongest"})})
    fog = HahnerFog(strongest, 300.0)
    alpha = KOSCHMIEDER / 300.0
    ref = ReferenceAtmosphere(scala4, Atmosphere(fog_m=1e5))
    ranges = np.array([2.0, 5.0, 10.0, 20.0, 40.0])
    a = np.full(len(ranges), 1e4 * fog.threshold)  # strong returns: above the soft echo
    pts = _points(ref, ranges, a)
    pts["time_stamp"] = np.arange(len(ranges))  # five beams
    out = fog.apply(pts, np.random.default_rng(0))
    assert len(out) == len(ranges) and np.all(out["label"] == Label.STATIC)
    np.testing.assert_allclose(out["epw"], epw_of(a * np.exp(-2.0 * alpha * ranges), fog.threshold, fog.sigma),
                               rtol=1e-3)  # saturated intensity: the peak from the EPW  # fmt: skip
    drop = 255.0 * 2.0 * alpha * ranges / fog.log_span
    i_in = np.rint(255.0 * np.log(a / fog.dark) / fog.log_span)
    assert np.all(np.abs(out["intensity"].astype(float) - (i_in - drop)) <= 1.0)


def test_hahner_soft_echo_replaces_weak_returns_and_grows_with_alpha(scala4):
    thin, thick = HahnerFog(scala4, 500.0), HahnerFog(scala4, 50.0)
    assert thick.soft_peak > thin.soft_peak
    assert 0.5 < thick.soft_range_m < 10.0
    ref = ReferenceAtmosphere(scala4, Atmosphere(fog_m=1e5))
    out = thick.apply(_points(ref, [30.0], [2.0 * thick.threshold]), np.random.default_rng(0))
    assert len(out) == 1 and out["label"][0] == Label.FOG and out["distance"][0] < 10.0


def test_hahner_on_a_sensor_reporting_every_echo_adds_the_soft_echo_before_the_hard_returns(scala4):
    """scala4 reports every echo (up to 3): a beam with two strong returns behind the soft echo keeps both as echoes
    2 and 3; a beam with three keeps the nearer two; a beam whose return lies before the soft echo gets none; a weak
    return lost to extinction leaves the soft echo alone (IDENTICAL). Echo numbers and return types renumbered."""
    fog = HahnerFog(scala4, 40.0)
    ref = ReferenceAtmosphere(scala4, Atmosphere(fog_m=1e5))
    strong = 1e4 * fog.threshold
    assert fog.soft_peak > fog.threshold and fog.soft_range_m < 8.0
    ranges = [10.0, 20.0, 12.0, 15.0, 18.0, 0.3, 30.0]
    amplitudes = [strong, strong, strong, strong, strong, strong, 1.5 * fog.threshold]
    pts = _points(ref, ranges, amplitudes)
    pts["time_stamp"] = [1, 1, 2, 2, 2, 3, 4]
    out = fog.apply(pts, np.random.default_rng(0))
    by_beam = {int(t): out[out["time_stamp"] == t] for t in (1, 2, 3, 4)}
    for t, hard in ((1, [10.0, 20.0]), (2, [12.0, 15.0])):
        b = by_beam[t]
        assert list(b["label"]) == [Label.FOG, Label.STATIC, Label.STATIC] and list(b["echo"]) == [1, 2, 3]
        np.testing.assert_allclose(b["distance"][1:], hard, rtol=1e-6)
        assert list(b["return_type"]) == [ReturnType.FIRST, ReturnType.SECOND, ReturnType.LAST]
    assert list(by_beam[3]["label"]) == [Label.STATIC]  # the cover-range return lies before the soft echo
    assert list(by_beam[4]["label"]) == [Label.FOG] and by_beam[4]["return_type"][0] == ReturnType.IDENTICAL


@pytest.mark.slow
def test_make_measured_reference_writes_a_readable_bag_with_weather_labels(tmp_path):
    out = tmp_path / "ref"
    subprocess.run(["lidar-weather-sim", "make-measured", "highway_clear", "--reference", "--hide",
                    "atmosphere.rain:intensity=30", "--frames", "3", "--labels", "--out", str(out)], check=True)  # fmt: skip
    rec = Recording.load(out)
    assert len(rec.frames) >= 2
    pts = np.concatenate([f.points for f in rec.frames])
    assert "label" in pts.dtype.names
    rain = pts["label"] == Label.RAIN
    assert rain.sum() > 50 and np.all(pts["distance"][rain] > 0)
    assert np.any(np.isin(pts["label"], [Label.STATIC, Label.VEHICLE]))
    assert np.all(np.isfinite(pts["epw"])) and np.all(pts["epw"] > 0)


def test_same_seed_same_output_other_seed_other_output(tmp_path):
    sc = load_scenario("highway_clear")
    fx = [parse_effect("atmosphere.snow:intensity=2")]
    paths = [tmp_path / n for n in ("a", "b", "c")]
    for path, seed in zip(paths, (11, 11, 12)):
        make_measured(sc, fx, path, frames=2, seed=seed, generator="reference")
    a, b, c = (np.concatenate([f.points for f in Recording.load(p).frames]) for p in paths)
    assert a.tobytes() == b.tobytes()
    assert a.tobytes() != c.tobytes()


def test_generators_refuse_what_they_do_not_make():
    sc = load_scenario("highway_clear")
    with pytest.raises(ValueError, match="fog only"):
        make_measured(sc, [parse_effect("atmosphere.rain:intensity=5")], "/nonexistent", frames=1, generator="hahner")
    with pytest.raises(ValueError, match="generator"):
        make_measured(sc, [], "/nonexistent", frames=1, generator="nope")


def test_pulse_sigma_is_the_profiles(scala4):
    assert ReferenceAtmosphere(scala4, Atmosphere(fog_m=100.0)).sigma == pytest.approx(scala4.pulse.fwhm_m * FWHM_TO_SIGMA)


@pytest.mark.parametrize("hidden, profile, frames", [("atmosphere.fog:visual_range=30", "scala4", 4),
                                                     ("atmosphere.rain:intensity=10", "scala4", 10),
                                                     ("atmosphere.snow:intensity=5", "scala4", 10),
                                                     ("atmosphere.fog:visual_range=500", "os1_128_2048", 4),
                                                     ("atmosphere.fog:visual_range=107;cover.dirt:transmission=0.66",
                                                      "scala4", 4),
                                                     ("atmosphere.fog:visual_range=30", "scala4:cone:0", 4),
                                                     ("atmosphere.rain:intensity=10", "scala4:cone:0", 4),
                                                     ("atmosphere.snow:intensity=5", "scala4:cone:0", 4)])
@pytest.mark.validation
def test_physical_fast_model_agrees_with_the_reference(hidden, profile, frames, tmp_path):
    """The atmosphere region against the reference, written apart from it, on the same clear
    frames and seed: detections in 0-5 m within 10 %, all detections within 12 %, the 0-5 m range histogram (5 cm
    bins, mean over frames) with Pearson >= 0.85 (the target is 0.9; measured over 6 frames: fog 30 m 0.99,
    rain 10 mm/h 0.95, snow 5 mm/h 0.92). OS1-128 with 32 columns (every beam simulated by the reference) in thin
    fog: 0.95 over 4 frames; 0.37 before the fog's near-field droplets fluctuated from beam to beam (every beam
    of a channel then peaked on the same spot of its flat-topped echo). Fog behind a dirty cover (gap draw case 7):
    the fog's light crosses the cover twice in both, and the dirt's own returns do not hide it; when the reference
    dimmed only the scene its near field held 19 % more detections than the fast model's and the frame 15 % fewer
    (its long fog echo hid the far returns). scala4 as shipped: ``overlap_model: defocus``, where each drop gives the
    share of its light the field stop takes, so its near field holds ~40 % fewer drops and the rain and snow
    histograms need 10 frames (rain 10 mm/h: 0.85 over 4 frames, 0.97 over 20); and an AC-coupled receiver
    (``detection.ac_coupling_tau_m`` 0.1 m), which the fast model applies to its volume slabs and clips at 0, the
    reference to its grid cells with the undershoot kept. ``scala4:cone:0``: its optics as the cone model, DC-coupled
    (``PROFILE:OVERLAP:TAU``)."""
    from lidar_weather_sim.references.measured import Nuisance

    base = load_scenario("highway_clear")
    fast_scenario = base.model_copy(update={"regions": [*base.regions, "atmosphere"]})
    quiet = Nuisance(extra_range_noise_m=0.0, drop_fraction=0.0)
    effect = [parse_effect(text) for text in hidden.split(";")]
    name, overlap, tau = (profile.split(":") + ["", ""])[:3]
    data = receiver_variant(name, overlap or None, float(tau) if tau else None).model_dump(mode="json")
    if data["scan"]["columns"] * len(data["beams"]) > 4096:  # the reference samples larger scans: 32 columns
        data["name"], data["scan"]["columns"] = f"{data['name']}_32_columns", 32
    (tmp_path / "profile.yaml").write_text(yaml.safe_dump(data, sort_keys=False))
    options = dict(frames=frames, seed=7, nuisance=quiet, profile=str(tmp_path / "profile.yaml"))
    make_measured(fast_scenario, effect, tmp_path / "fast", **options)
    make_measured(base, effect, tmp_path / "ref", generator="reference", **options)
    fast, ref = ([f.points for f in Recording.load(tmp_path / name).frames] for name in ("fast", "ref"))
    edges = np.arange(0.0, 5.0001, 0.05)
    hist = [np.mean([np.histogram(p["distance"], edges)[0] for p in frames], axis=0) for frames in (fast, ref)]
    near = [h.sum() for h in hist]
    total = [np.mean([len(p) for p in frames]) for frames in (fast, ref)]
    assert near[0] == pytest.approx(near[1], rel=0.10), near
    assert total[0] == pytest.approx(total[1], rel=0.12), total
    assert np.corrcoef(*hist)[0, 1] >= 0.85, np.corrcoef(*hist)[0, 1]


@pytest.mark.validation
@pytest.mark.parametrize("generator, visual_range_m", [("reference", 60.0), ("hahner", 90.0)])
def test_gap_with_the_physical_model_names_the_generators_fog_and_fits_its_visual_range(generator, visual_range_m,
                                                                                       tmp_path):  # fmt: skip
    """Fog made by the reference or by the Hahner et al. generator (both written apart from the simulator):
    `gap` names atmosphere.fog alone, its visual range within 25 %, and at least
    halves the held-out gap. The Hahner fog was named in none of the draw's 4 cases while scala4's receiver was
    DC-coupled with the cone overlap (its fog echo 12-16 m long, the generator's ~1.5 m) and the generator
    replaced hard returns as a single-return sensor does (docs/atmosphere_reference.md)."""
    from lidar_weather_sim.gap.command import run_gap

    scenario = load_scenario("highway_clear")
    make_measured(scenario, [parse_effect(f"atmosphere.fog:visual_range={visual_range_m}")], tmp_path / "measured",
                  frames=24, generator=generator)  # fmt: skip
    result = run_gap(tmp_path / "measured", scenario, tmp_path / "gap", fit_frames=8,
                     heldout_frames=8, screen_frames=2)  # fmt: skip
    (fog,) = result["effects"]
    assert fog["name"] == "atmosphere.fog" and fog["params"]["visual_range"] == pytest.approx(visual_range_m, rel=0.25)
    assert result["gap_after"] <= 0.5 * result["gap_before"]


def test_reference_fog_on_a_wide_beam_whose_near_field_is_all_bulk(tmp_path):
    """OS1-128's 3.1 mrad beam holds so many fog droplets per near-field cell that none is placed one by one:
    the reference then has no direct drops and still writes its fog (it used to fail unpacking them)."""
    make_measured(load_scenario("highway_clear"), [parse_effect("atmosphere.fog:visual_range=30")], tmp_path / "os1",
                  frames=1, profile="os1_128_2048", generator="reference", ground_truth=True, beams_per_frame=256)  # fmt: skip
    (frame,) = Recording.load(tmp_path / "os1").frames
    assert np.sum(frame.points["label"] == Label.FOG) > 100
