"""``lidar-weather-sim augment`` end to end on a simulated spray bag, and its one-line errors."""

from __future__ import annotations

import numpy as np
import pytest

from lidar_weather_sim.cli import main
from lidar_weather_sim.core.points import Label
from lidar_weather_sim.augment.obstacles import OBJECT_ID_BASE
from lidar_weather_sim.io.bags import bag_info, read_clouds


@pytest.fixture(scope="module")
def spray_bag(tmp_path_factory):
    out = tmp_path_factory.mktemp("spray") / "bag"
    assert main(["run", "highway_spray", "--frames", "10", "--out", str(out)]) == 0
    return out


def test_the_car_ahead_comes_from_the_bag_and_no_box_overlaps_it(spray_bag):
    from lidar_weather_sim.augment.obstacles import ObstacleAugmenter, car_ahead
    from lidar_weather_sim.augment.boxes import footprints_overlap
    from lidar_weather_sim.io.recording import Recording
    from lidar_weather_sim.sensor.profile import load_profile

    recording = Recording.load(spray_bag)
    (car,) = car_ahead(recording, recording.frames[0])
    # highway_spray: the rear middle 17.5 m ahead, 3.7 m left (the lane centre 3.75 m), a 4.7 m car
    assert car.x == pytest.approx(17.5 + 4.7 / 2, abs=0.05) and car.y == pytest.approx(3.75, abs=0.05)
    augmenter = ObstacleAugmenter(load_profile("scala4"), objects=3, seed=9)
    for _ in range(100):
        assert not any(footprints_overlap(b.footprint, car) for b in augmenter.boxes(-0.5, (car,)))


def _counts(path):
    return {t.name: t.count for t in bag_info(path).topics}


def test_augment_adds_obstacles_and_keeps_every_other_message(spray_bag, tmp_path):
    out = tmp_path / "aug"
    assert main(["augment", str(spray_bag), "--objects", "2", "--seed", "4", "--out", str(out)]) == 0
    assert _counts(out) == _counts(spray_bag)
    before = {f.stamp_ns: f.points for f in read_clouds(spray_bag)}
    after = list(read_clouds(out))
    assert [f.stamp_ns for f in after] == sorted(before)
    ids = set()
    for f in after:
        obstacle = f.points[f.points["label"] == Label.OBSTACLE]
        assert len(obstacle) > 0
        ids |= set(obstacle["object_id"].tolist())
        assert len(set(obstacle["object_id"].tolist())) <= 2
        # every recorded point kept is a recorded point (none moved or invented)
        rest = f.points[f.points["label"] != Label.OBSTACLE]
        assert np.isin(rest["distance"], before[f.stamp_ns]["distance"]).all()
        assert len(rest) <= len(before[f.stamp_ns])
        assert np.all(obstacle["epw"] > 0) and np.all((obstacle["x"] > 11.0) & (obstacle["x"] < 21.0))
    assert min(ids) >= OBJECT_ID_BASE and len(ids) >= 4
    again = tmp_path / "again"
    assert main(["augment", str(spray_bag), "--objects", "2", "--seed", "4", "--out", str(again)]) == 0
    for a, b in zip(read_clouds(out), read_clouds(again)):
        np.testing.assert_array_equal(a.points, b.points)


@pytest.mark.parametrize(
    "extra, message",
    [
        (["--sizes", "0.2:6"], "do not fit the ROI"),
        (["--topic", "/no/such/topic"], "no PointCloud2 topic /no/such/topic"),
        (["--profile", "vlp16"], "profile vlp16 does not match the cloud"),
        (["--profile", "scala4", "--sizes", "2:1"], "need 0 < MIN <= MAX"),
        (["--kinds", "box,tank"], "unknown obstacle kind 'tank' (choose from box,vehicle,pedestrian,debris)"),
    ],
)
def test_bad_input_is_one_line_exit_2_and_nothing_written(spray_bag, tmp_path, capsys, extra, message):
    out = tmp_path / "aug"
    try:
        code = main(["augment", str(spray_bag), *extra, "--out", str(out)])
    except SystemExit as exc:  # argparse's own errors (bad --sizes)
        code = exc.code
    assert code == 2
    err = [line for line in capsys.readouterr().err.splitlines() if line.strip()]
    assert message in err[-1]
    assert len(err) == 1 or err[0].startswith("usage:")  # argparse adds its usage line
    assert not out.exists()


def _inserted_epw(path):
    return np.concatenate([f.points["epw"][f.points["label"] == Label.OBSTACLE] for f in read_clouds(path)])


def test_epw_of_inserted_points_matched_to_the_car_ahead_rear(spray_bag, tmp_path, capsys):
    """Fig. A4: the inserted points' EPW mean and sd become those of the recorded car rear."""
    from lidar_weather_sim.augment.obstacles import lead_rear_epw
    from lidar_weather_sim.replay import road_level
    from lidar_weather_sim.io.recording import Recording

    recording = Recording.load(spray_bag)
    rear, reason = lead_rear_epw(recording, road_level(recording))
    assert reason == "" and len(rear) > 300  # the car's rear, 17.5 m ahead, over 10 frames
    runs = {}
    for mode in ("none", "lead"):
        out = tmp_path / mode
        assert main(["augment", str(spray_bag), "--objects", "2", "--seed", "4", "--epw-match", mode,
                     "--out", str(out)]) == 0  # fmt: skip
        runs[mode] = _inserted_epw(out)
    assert "EPW matched to the car ahead's rear" in capsys.readouterr().out
    raw, matched = runs["none"], runs["lead"]
    assert len(raw) == len(matched) > 500  # the same points, only their EPW differs
    # the sensor model's boxes (reflectivity 0-1) differ from the car's paint: mean 0.1 m lower, 1.5x the spread
    assert rear.mean() - raw.mean() > 0.05 and raw.std() > 1.3 * rear.std()
    assert abs(matched.mean() - rear.mean()) < 0.02 and abs(matched.std() - rear.std()) < 0.05
    assert matched.min() >= rear.min() - 1e-6 and matched.max() <= rear.max() + 1e-6
    order = np.argsort(raw, kind="stable")
    assert np.all(np.diff(matched[order]) >= -1e-6)  # brighter boxes keep the wider echoes


def test_a_bag_without_a_car_ahead_keeps_the_sensor_models_epw_and_says_why(tmp_path, capsys):
    import math

    from lidar_weather_sim.core.points import empty_points
    from lidar_weather_sim.io.bags import BagWriter
    from lidar_weather_sim.sensor.profile import load_profile
    from lidar_weather_sim.sensor.scan import ScanPattern

    pattern = ScanPattern(load_profile("vlp16"))
    ch, col = np.meshgrid(np.arange(16), np.flatnonzero(np.abs(pattern.column_azimuth) < math.radians(40)))
    wall = empty_points(ch.size)
    az = pattern.column_azimuth[col.ravel()] + pattern.azimuth_offset[ch.ravel()]
    el = pattern.elevation[ch.ravel()]
    wall["x"], wall["y"], wall["z"] = 25 * np.cos(el) * np.cos(az), 25 * np.cos(el) * np.sin(az), 25 * np.sin(el)
    wall["azimuth"], wall["elevation"], wall["distance"], wall["channel"] = az, el, 25.0, ch.ravel()
    wall["echo"], wall["epw"], wall["label"] = 1, 1.0, Label.STATIC
    bag = tmp_path / "wall"
    with BagWriter(bag) as writer:
        for k in range(3):
            writer.write_cloud("/lidar/points", wall, stamp_ns=k * 100_000_000, frame_id="lidar")
    outs = {}
    for mode in ("lead", "none"):
        outs[mode] = tmp_path / f"aug_{mode}"
        assert main(["augment", str(bag), "--profile", "vlp16", "--epw-match", mode, "--out", str(outs[mode])]) == 0
        if mode == "lead":
            note = capsys.readouterr().err.strip()
            assert note == ("lidar-weather-sim augment: note: EPW not matched to the car ahead: the bag has no car "
                            "ahead (no actor_<id> transform in /tf)")
    np.testing.assert_array_equal(_inserted_epw(outs["lead"]), _inserted_epw(outs["none"]))
    assert len(_inserted_epw(outs["none"])) > 0
