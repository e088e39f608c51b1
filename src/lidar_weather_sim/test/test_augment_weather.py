"""A simulated effect on top of real frames: added weather returns, removed extinguished ones."""

from __future__ import annotations

import subprocess
import sys

import numpy as np
import pytest

from lidar_weather_sim.core.paths import cache_dir
from lidar_weather_sim.core.points import POINT_DTYPE_NO_EPW, Label, empty_points, fill_polar
from lidar_weather_sim.augment.weather import augment_frame
from lidar_weather_sim.replay import beam_keys

COLUMNS = 8


def _points(rows, dtype=None):
    """rows: (channel, azimuth rad, range m, label)."""
    p = empty_points(len(rows)) if dtype is None else np.zeros(len(rows), dtype)
    for i, (channel, az, r, label) in enumerate(rows):
        p[i]["x"], p[i]["y"], p[i]["channel"] = r * np.cos(az), r * np.sin(az), channel
        if "label" in p.dtype.names:
            p[i]["label"] = label
    fill_polar(p)
    return p


def test_beam_keys_separate_channels_and_columns():
    p = _points([(0, -3.0, 10, 1), (0, 0.1, 10, 1), (1, 0.1, 10, 1), (1, 3.0, 10, 1)])
    assert len(np.unique(beam_keys(p, COLUMNS))) == 4


def test_effect_adds_its_returns_and_removes_what_it_extinguishes():
    real = _points([(0, 0.1, 20.0, 0), (1, 0.1, 40.0, 0), (2, 0.1, 30.0, 0)], POINT_DTYPE_NO_EPW)
    base = _points([(0, 0.1, 20.1, Label.STATIC), (1, 0.1, 40.1, Label.STATIC), (2, 0.1, 30.1, Label.STATIC)])
    effect = _points([(0, 0.1, 20.1, Label.STATIC),  # still seen through the fog
                      (1, 0.1, 3.0, Label.FOG),  # the far wall is lost, a fog return appears
                      (2, 0.1, 30.1, Label.STATIC), (2, 0.1, 2.0, Label.FOG)])  # fmt: skip
    out = augment_frame(real, base, effect, COLUMNS)
    assert out.dtype == real.dtype
    assert sorted(np.round(out["distance"], 1).tolist()) == [2.0, 3.0, 20.0, 30.0]  # 40 m lost, two fog returns


@pytest.mark.slow
def test_make_measured_on_the_real_recording(tmp_path):
    bag = cache_dir() / "ouster_real" / "os1_128_street"
    if not bag.exists():
        pytest.skip(f"real recording {bag} absent (make setup imports it)")
    from lidar_weather_sim.io.recording import Recording

    out = tmp_path / "real_fog"
    done = subprocess.run([sys.executable, "-m", "lidar_weather_sim.cli", "make-measured", "ouster_street", "--on",
                           str(bag), "--hide", "atmosphere.fog:visual_range=60", "--out", str(out)],
                          capture_output=True, text=True)  # fmt: skip
    assert done.returncode == 0, done.stderr
    real, fog = Recording.load(bag), Recording.load(out)
    assert len(fog.frames) == len(real.frames) == 3
    assert fog.has_poses and fog.sensor_frame == real.sensor_frame
    for r, f in zip(real.frames, fog.frames):
        assert f.stamp_ns == r.stamp_ns and f.points.dtype.names == r.points.dtype.names
        near_real = np.count_nonzero(r.points["distance"] < 5.0)
        near_fog = np.count_nonzero(f.points["distance"] < 5.0)
        assert near_fog > near_real + 1000  # fog returns in the near field
        # far returns fade (those left are where the street mesh has holes: no simulated return to lose)
        assert np.count_nonzero(f.points["distance"] > 60.0) < 0.75 * np.count_nonzero(r.points["distance"] > 60.0)


@pytest.mark.slow
def test_the_reference_puts_fog_on_the_real_recording_by_each_returns_signal(tmp_path):
    """`make-measured --on BAG --reference`: the drop-by-drop reference's fog on the real frames (its sampled beams
    re-drawn, the others dimmed). Read as the profile's bytes, Ouster's reflectivity makes every return a barely
    detected one and a 150 m fog removes most returns beyond 20 m; with ``--intensity-scale reflectivity`` each
    keeps the signal its reflectivity and range give, and most stay."""
    bag = cache_dir() / "ouster_real" / "os1_128_street"
    if not bag.exists():
        pytest.skip(f"real recording {bag} absent (make setup imports it)")
    from lidar_weather_sim.io.recording import Recording

    far = {}
    for scale in ("profile", "reflectivity"):
        out = tmp_path / scale
        done = subprocess.run([sys.executable, "-m", "lidar_weather_sim.cli", "make-measured", "ouster_street",
                               "--on", str(bag), "--reference", "--intensity-scale", scale,
                               "--hide", "atmosphere.fog:visual_range=150", "--out", str(out)],
                              capture_output=True, text=True)  # fmt: skip
        assert done.returncode == 0, done.stderr
        assert "weather by the reference generator" in done.stdout
        frames = Recording.load(out).frames
        assert len(frames) == 3 and frames[0].points.dtype == Recording.load(bag).frames[0].points.dtype
        far[scale] = sum(np.count_nonzero(f.points["distance"] > 20.0) for f in frames)
    real = sum(np.count_nonzero(f.points["distance"] > 20.0) for f in Recording.load(bag).frames)
    assert far["reflectivity"] > 0.7 * real and far["profile"] < 0.3 * real, (far, real)


def test_actors_are_put_on_the_frame_and_hide_what_lies_behind_them():
    """With the scenario's actors (a car the recording lacks): its returns are added, the real returns behind it on
    its beams go, and nearer real returns and the real returns of other beams stay."""
    real = _points([(0, 0.1, 20.0, 0), (0, 0.1, 5.0, 0), (1, 0.1, 40.0, 0), (2, 0.1, 30.0, 0)], POINT_DTYPE_NO_EPW)
    car = [(0, 0.1, 12.0, Label.VEHICLE), (1, 0.1, 12.5, Label.VEHICLE)]
    base = _points([(0, 0.1, 20.1, Label.STATIC), *car, (2, 0.1, 30.1, Label.STATIC)])
    effect = _points([*car, (2, 0.1, 30.1, Label.STATIC), (0, 0.1, 11.0, Label.SPRAY)])
    effect["object_id"][:2] = 100
    out = augment_frame(real, base, effect, COLUMNS, actor_ids=(100,))
    assert sorted(np.round(out["distance"], 1).tolist()) == [5.0, 11.0, 12.0, 12.5, 30.0]
    without = augment_frame(real, base, effect, COLUMNS)  # the recording has the car: only the spray is added
    assert sorted(np.round(without["distance"], 1).tolist()) == [5.0, 11.0, 20.0, 30.0, 40.0]


@pytest.mark.slow
def test_spray_and_the_car_throwing_it_on_the_real_recording(tmp_path):
    """ouster_street_spray: a car overtakes the recording's sensor with its spray (the spray region's warm-up has it
    out at the first scan); `make-measured --on --with-actors` puts both on the real frames."""
    bag = cache_dir() / "ouster_real" / "os1_128_street"
    if not bag.exists():
        pytest.skip(f"real recording {bag} absent (make setup imports it)")
    from lidar_weather_sim.scenario.effects import parse_effect
    from lidar_weather_sim.replay import Resimulator
    from lidar_weather_sim.io.recording import Recording
    from lidar_weather_sim.scenario.schema import load_scenario

    real = Recording.load(bag)
    scenario = load_scenario("ouster_street_spray")
    resim = Resimulator(real, scenario)
    spray = [parse_effect("spray:water_film=2.0")]
    first = resim.frames(spray, [0])[0]
    warm = np.count_nonzero(first["label"] == Label.SPRAY)
    cold = scenario.model_copy(update={"region_params": {"spray": {"warmup_s": 0.0}}})
    cold = np.count_nonzero(Resimulator(real, cold).frames(spray, [0])[0]["label"] == Label.SPRAY)
    assert warm >= 10 and warm >= 4 * cold, (warm, cold)  # measured: 20 and 2 (the frame's own 0.1 s)
    out = tmp_path / "street_spray"
    done = subprocess.run([sys.executable, "-m", "lidar_weather_sim.cli", "make-measured", "ouster_street_spray",
                           "--on", str(bag), "--hide", "spray:water_film=2.0", "--with-actors", "--out", str(out)],
                          capture_output=True, text=True)  # fmt: skip
    assert done.returncode == 0, done.stderr
    car = first[(first["object_id"] == 100) & (first["label"] == Label.VEHICLE)]
    assert len(car) >= 100
    put = Recording.load(out).frames[0].points
    assert put.dtype.names == real.frames[0].points.dtype.names
    xyz = {tuple(v) for v in np.stack([put["x"], put["y"], put["z"]], -1).tolist()}
    assert all(tuple(v) in xyz for v in np.stack([car["x"], car["y"], car["z"]], -1).tolist())  # the car is on it
    columns = resim.world.profile.scan.columns
    shadow = np.isin(beam_keys(put, columns), beam_keys(car, columns)) & (put["distance"] > car["distance"].max())
    assert not shadow.any()  # no real return behind the car on its beams
    assert len(put) > len(real.frames[0].points)
    done = subprocess.run([sys.executable, "-m", "lidar_weather_sim.cli", "make-measured", "ouster_street_spray",
                           "--with-actors", "--hide", "spray:water_film=2.0", "--out", str(tmp_path / "no")],
                          capture_output=True, text=True)  # fmt: skip
    assert done.returncode == 2 and "--with-actors" in done.stderr and not (tmp_path / "no").exists()


def test_a_generator_dims_a_recorded_return_by_the_signal_its_reflectivity_gives():
    """``through_generator`` (make-measured --on BAG --generator G): the generator takes the recording's frame in
    the project's layout and gives it back in the recording's (no EPW here). A 10 % reflectivity at 20 m on
    os1_128_1024 (byte 99 on the profile's scale, --intensity-scale reflectivity) through fog_loss at a visual
    range of 60 m (2 alpha R = 2.61) keeps its return, 72 bytes dimmer (255 x 2.61 / ln 1e4); read as the
    profile's byte 10 it is lost."""
    from lidar_weather_sim.augment.weather import through_generator
    from lidar_weather_sim.references.measured import weather_transform
    from lidar_weather_sim.scenario.effects import parse_effect
    from lidar_weather_sim.scenario.schema import load_scenario
    from lidar_weather_sim.sensor.profile import load_profile
    from lidar_weather_sim.sensor.radiometry import reflectivity_intensity

    scenario = load_scenario("ouster_street")
    _, transform = weather_transform(scenario, [parse_effect("atmosphere.fog:visual_range=60")], "fog_loss",
                                     "os1_128_1024", 0)  # fmt: skip
    real = _points([(5, 0.1, 20.0, 0), (6, 0.2, 20.0, 0)], POINT_DTYPE_NO_EPW)
    real["intensity"] = 10
    assert len(through_generator(real, transform, 0)) == 0  # byte 10 on the profile's scale: below the loss
    real["intensity"] = reflectivity_intensity(real["intensity"], real["distance"], load_profile("os1_128_1024"))
    out = through_generator(real, transform, 0)
    assert out.dtype == real.dtype and len(out) == 2
    assert (real["intensity"] == 99).all() and (out["intensity"] == 99 - 72).all()
    np.testing.assert_array_equal(out["distance"], real["distance"])
