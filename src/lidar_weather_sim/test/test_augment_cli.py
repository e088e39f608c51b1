"""``lidar-weather-sim augment`` end to end on a simulated spray bag, and its one-line errors."""

from __future__ import annotations

import numpy as np
import pytest

from lidar_weather_sim.cli import main
from lidar_weather_sim.core.points import Label
from lidar_weather_sim.gap.augment_obstacles import OBJECT_ID_BASE
from lidar_weather_sim.io.bags import bag_info, read_clouds


@pytest.fixture(scope="module")
def spray_bag(tmp_path_factory):
    out = tmp_path_factory.mktemp("spray") / "bag"
    assert main(["run", "highway_spray", "--frames", "10", "--out", str(out)]) == 0
    return out


def test_the_car_ahead_comes_from_the_bag_and_no_box_overlaps_it(spray_bag):
    from lidar_weather_sim.gap.augment_obstacles import ObstacleAugmenter, car_ahead
    from lidar_weather_sim.gap.obstacle_boxes import footprints_overlap
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
