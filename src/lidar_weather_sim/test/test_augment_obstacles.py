"""Paper 4's obstacle augmentation: boxes in the ROI, raycast with the scan pattern, occlusion per beam."""

from __future__ import annotations

import math

import numpy as np
import pytest

from lidar_weather_sim.core.points import Label, ReturnType, empty_points
from lidar_weather_sim.augment.obstacles import OBJECT_ID_BASE, ObstacleAugmenter, added_noise_sigma
from lidar_weather_sim.augment.boxes import (
    Box,
    BoxRanges,
    Footprint,
    ObstacleError,
    Roi,
    augmentation_table,
    check_fits,
    draw_box,
    footprints_overlap,
)
from lidar_weather_sim.augment.cast import ObstacleCaster
from lidar_weather_sim.augment.occlusion import beam_key, merge_obstacles
from lidar_weather_sim.sensor.profile import load_profile
from lidar_weather_sim.sensor.scan import ScanPattern

ROAD_Z = -1.5


@pytest.fixture(scope="module")
def vlp16():
    p = load_profile("vlp16")
    return p.model_copy(update={"detection": p.detection.model_copy(update={"max_echoes": 2})})


@pytest.fixture(scope="module")
def pattern(vlp16):
    return ScanPattern(vlp16)


def _box(x=15.0, y=0.0, size=(1.0, 1.0, 1.0), yaw=0.0, refl=0.5, object_id=OBJECT_ID_BASE):
    return Box(x, y, ROAD_Z, *size, yaw, refl, 1, object_id)


def _beam_point(pattern, channel, column, distance, echo=1, label=Label.STATIC):
    """A recorded point on the centre ray of (channel, column) at ``distance`` m."""
    p = empty_points(1)
    az = pattern.column_azimuth[column] + pattern.azimuth_offset[channel]
    el = pattern.elevation[channel]
    p["x"], p["y"], p["z"] = (distance * math.cos(el) * math.cos(az), distance * math.cos(el) * math.sin(az),
                              distance * math.sin(el))  # fmt: skip
    p["azimuth"], p["elevation"], p["distance"] = math.atan2(math.sin(az), math.cos(az)), el, distance
    p["channel"], p["echo"], p["label"] = channel, echo, label
    return p


def test_values_come_from_the_thesis_tables():
    table = augmentation_table()
    roi = Roi.paper()
    assert roi.x_min_m == table["roi"]["x_min_m"] and math.degrees(roi.half_angle_rad) == pytest.approx(30.0)
    assert BoxRanges.paper().size_m == tuple(table["box"]["size_m"])
    assert BoxRanges.paper().durations == (1, 2, 3)


def test_box_is_raycast_onto_its_faces_with_channel_azimuth_and_epw(vlp16, pattern):
    points = ObstacleCaster(vlp16).cast([_box()], frame_index=0, seed=1)
    assert len(points) > 10
    assert set(points["label"].tolist()) == {Label.OBSTACLE}
    assert set(points["object_id"].tolist()) == {OBJECT_ID_BASE}
    # the front face x = 14.5 m, |y| <= 0.5 m, z from -1.5 to -0.5 m (within the profile's range noise)
    assert np.all(np.abs(points["x"] - 14.5) < 0.1)
    assert np.all(np.abs(points["y"]) <= 0.5 + 0.01)
    assert np.all((points["z"] >= -1.5 - 0.02) & (points["z"] <= -0.5 + 0.02))
    # VLP-16 beams at -5 and -3 deg meet that face (-5.9 to -2.0 deg): channels 5 and 6 (0 = lowest)
    assert sorted(set(points["channel"].tolist())) == [5, 6]
    np.testing.assert_allclose(points["elevation"], pattern.elevation[points["channel"]], atol=1e-6)
    # azimuths within the face's +-atan(0.5 / 14.5), each on a column of the pattern, time stamp of that column
    assert np.all(np.abs(points["azimuth"]) <= math.atan(0.5 / 14.5) + math.radians(0.2))
    col = beam_key(pattern, points["channel"], points["azimuth"]) % pattern.n_columns
    np.testing.assert_allclose(points["time_stamp"], np.round(pattern.column_time_s[col] * 1e9), atol=1)
    assert np.all(points["epw"] > 0)


def test_brighter_box_gives_wider_echoes(vlp16):
    dark = ObstacleCaster(vlp16).cast([_box(refl=0.1)], 0, 1)
    bright = ObstacleCaster(vlp16).cast([_box(refl=0.9)], 0, 1)
    assert np.median(bright["epw"]) > np.median(dark["epw"])


def test_occlusion_keeps_returns_in_front_removes_those_behind(vlp16, pattern):
    obstacle = ObstacleCaster(vlp16).cast([_box()], 0, 1)
    key = beam_key(pattern, obstacle["channel"], obstacle["azimuth"])
    ch, col = int(key[0] // pattern.n_columns), int(key[0] % pattern.n_columns)
    free_col = (col + pattern.n_columns // 2) % pattern.n_columns  # behind the sensor: no box there
    recorded = np.concatenate([
        _beam_point(pattern, ch, col, 8.0, echo=1, label=Label.SPRAY),  # spray in front: stays
        _beam_point(pattern, ch, col, 30.0, echo=2),  # wall behind the box: removed
        _beam_point(pattern, ch, free_col, 30.0),  # another beam: stays
    ])  # fmt: skip
    out = merge_obstacles(recorded, obstacle, pattern, max_echoes=2, noise_sigma_m=0.0,
                          rng=np.random.default_rng(0))  # fmt: skip
    kept = out[out["label"] != Label.OBSTACLE]
    assert sorted(kept["distance"].tolist()) == [8.0, 30.0]
    assert beam_key(pattern, kept["channel"], kept["azimuth"]).tolist().count(int(key[0])) == 1
    added = out[out["label"] == Label.OBSTACLE]
    in_beam = added[beam_key(pattern, added["channel"], added["azimuth"]) == key[0]]
    assert len(in_beam) == 1 and in_beam["echo"][0] == 2 and in_beam["return_type"][0] == ReturnType.LAST
    assert kept["return_type"][kept["distance"] == 8.0][0] == ReturnType.FIRST
    # other obstacle beams are untouched: first echoes; every obstacle beam once
    assert len(added) == len(np.unique(key))
    # with one echo per beam the obstacle point behind the spray is lost, the wall still hidden
    one = merge_obstacles(recorded, obstacle, pattern, 1, 0.0, np.random.default_rng(0))
    assert len(one) == len(out) - 1
    assert 30.0 in one["distance"][one["label"] != Label.OBSTACLE]


def test_near_field_returns_stay_even_behind(vlp16, pattern):
    obstacle = ObstacleCaster(vlp16).cast([_box(x=3.0, size=(0.5, 0.5, 1.0))], 0, 1)
    key = beam_key(pattern, obstacle["channel"], obstacle["azimuth"])
    ch, col = int(key[0] // pattern.n_columns), int(key[0] % pattern.n_columns)
    recorded = np.concatenate([_beam_point(pattern, ch, col, 4.5), _beam_point(pattern, ch, col, 6.0)])
    out = merge_obstacles(recorded, obstacle, pattern, 2, 0.0, np.random.default_rng(0))
    assert sorted(out["distance"][out["label"] != Label.OBSTACLE].tolist()) == [4.5]


def test_range_noise_has_the_papers_sigma(vlp16, pattern):
    obstacle = ObstacleCaster(vlp16).cast([_box(size=(0.3, 2.0, 2.0))], 0, 1)
    clean = merge_obstacles(empty_points(0), obstacle, pattern, 2, 0.0, np.random.default_rng(0))
    rng = np.random.default_rng(3)
    diff = np.concatenate([merge_obstacles(empty_points(0), obstacle, pattern, 2, 0.05, rng)["distance"]
                           - clean["distance"] for _ in range(20)])  # fmt: skip
    assert len(diff) > 500
    assert np.std(diff) == pytest.approx(0.05, rel=0.1)
    total = float(augmentation_table()["noise_sigma_m"])
    assert added_noise_sigma(vlp16) == pytest.approx(math.sqrt(total**2 - vlp16.range.noise_sigma_m**2))


def test_boxes_stay_in_the_roi_and_off_the_car_ahead():
    roi, ranges = Roi.paper(), BoxRanges.paper()
    car = Footprint(16.0, 0.0, 0.0, 4.7, 1.85)
    rng = np.random.default_rng(5)
    boxes = [draw_box(rng, ranges, roi, ROAD_Z, i, (car,)) for i in range(400)]
    for b in boxes:
        c = b.footprint.corners()
        assert roi.contains(c[:, 0], c[:, 1]).all()
        assert not footprints_overlap(b.footprint, car)
        assert ranges.size_m[0] <= min(b.length, b.width, b.height) and max(b.length, b.width, b.height) <= ranges.size_m[1]
    durations = np.bincount([b.duration for b in boxes], minlength=4)[1:]
    assert durations.min() > 100  # equal shares of 1, 2, 3 frames
    assert footprints_overlap(car, Footprint(17.0, 0.5, 0.7, 1.0, 1.0))


def test_a_side_longer_than_the_roi_allows_is_an_error():
    roi = Roi.paper()
    with pytest.raises(ObstacleError, match="do not fit the ROI"):
        check_fits(BoxRanges.paper((0.2, roi.largest_side_m() + 0.1)), roi)
    check_fits(BoxRanges.paper((0.2, roi.largest_side_m() - 0.1)), roi)


def _frames(pattern, n=3):
    """Recorded frames: a wall at 25 m in front (every channel, +-40 deg)."""
    out = []
    cols = np.flatnonzero(np.abs(pattern.column_azimuth) < math.radians(40))
    for _ in range(n):
        out.append(np.concatenate([_beam_point(pattern, ch, c, 25.0) for ch in range(0, 16, 3) for c in cols[::4]]))
    return out


def test_same_seed_same_output_other_seed_other_boxes(vlp16, pattern):
    frames = _frames(pattern)

    def run(seed):
        aug = ObstacleAugmenter(vlp16, objects=2, seed=seed)
        return [aug.frame(f, i, ROAD_Z) for i, f in enumerate(frames)]

    a, b, c = run(7), run(7), run(8)
    for (pa, ba), (pb, bb) in zip(a, b):
        assert ba == bb
        np.testing.assert_array_equal(pa, pb)
    assert [x[1] for x in a] != [x[1] for x in c]
    for points, boxes in a:
        assert len(boxes) == 2
        obstacle = points[points["label"] == Label.OBSTACLE]
        assert set(obstacle["object_id"].tolist()) <= {bx.object_id for bx in boxes}
        # no wall return left behind an obstacle point of the same beam
        walls = points[points["label"] == Label.STATIC]
        wk = beam_key(pattern, walls["channel"], walls["azimuth"])
        ok = beam_key(pattern, obstacle["channel"], obstacle["azimuth"])
        assert not np.isin(wk, ok).any()


def test_boxes_are_held_for_their_duration(vlp16, pattern):
    aug = ObstacleAugmenter(vlp16, objects=1, seed=3)
    seen = [aug.boxes(ROAD_Z)[0] for _ in range(30)]
    i = 0
    while i < len(seen):
        run = seen[i : i + seen[i].duration]
        assert all(b == seen[i] for b in run)
        i += seen[i].duration


def test_a_cloud_without_epw_or_ground_truth_gets_labels_but_no_epw(vlp16, pattern):
    from lidar_weather_sim.core.points import POINT_DTYPE_NO_EPW

    frame = _frames(pattern, 1)[0]
    real = np.zeros(len(frame), POINT_DTYPE_NO_EPW)
    for name in POINT_DTYPE_NO_EPW.names:
        real[name] = frame[name]
    out, boxes = ObstacleAugmenter(vlp16, seed=2).frame(real, 0, ROAD_Z)
    assert "epw" not in out.dtype.names and {"label", "object_id"} <= set(out.dtype.names)
    assert out.dtype.itemsize == 44
    assert set(out["object_id"][out["label"] == Label.OBSTACLE].tolist()) == {boxes[0].object_id}
    assert set(out["label"][out["label"] != Label.OBSTACLE].tolist()) == {Label.UNKNOWN}
