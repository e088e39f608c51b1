"""EPW of inserted obstacle points matched to the car ahead's rear (paper 4, Fig. A4)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from lidar_weather_sim.core.points import Label, empty_points
from lidar_weather_sim.augment.boxes import Footprint
from lidar_weather_sim.augment.epw import (
    MIN_REAR_POINTS,
    EpwStats,
    lead_car,
    match_epw,
    match_to_lead,
    rear_mask,
)


def test_mean_and_sd_become_the_rears_and_the_range_is_trimmed():
    rng = np.random.default_rng(0)
    inserted = rng.normal(1.0, 0.5, 20000).clip(0.05)
    rear = rng.normal(2.0, 0.2, 5000)
    out = match_epw(inserted, EpwStats.of(inserted), EpwStats.of(rear))
    assert abs(np.mean(out) - 2.0) < 0.01 and abs(np.std(out) - 0.2) < 0.01
    assert abs(np.median(out) - np.median(rear)) < 0.02  # both near-normal: the medians follow
    assert out.min() >= rear.min() and out.max() <= rear.max()  # trimmed to the rear's range
    order = np.argsort(inserted, kind="stable")
    assert np.all(np.diff(out[order]) >= 0)  # a brighter point keeps the wider echo


def test_the_rear_is_the_points_near_the_back_face_of_the_nearest_car_ahead():
    behind = Footprint(-10.0, 0.0, 0.0, 4.7, 1.85)
    far, near = Footprint(40.0, 0.0, 0.0, 4.7, 1.85), Footprint(20.0, 3.7, 0.0, 4.7, 1.85)
    car = lead_car((behind, far, near))
    assert car is near and lead_car((behind,)) is None
    p = empty_points(6)
    # rear face x = 17.65 m: on it, 0.4 m into the car, the middle of the car, beside it, the road, spray
    p["x"] = [17.65, 18.05, 20.0, 17.7, 17.7, 17.6]
    p["y"] = [3.7, 4.2, 3.7, 3.7 + 1.5, 3.7, 3.7]
    p["z"] = [0.0, 0.3, 0.0, 0.0, -1.5, 0.0]
    p["label"] = [Label.VEHICLE, Label.VEHICLE, Label.VEHICLE, Label.STATIC, Label.STATIC, Label.SPRAY]
    assert rear_mask(p, car, road_z_m=-1.5).tolist() == [True, True, False, False, False, False]


def _frames_with(epw_obstacle, epw_rest):
    f = empty_points(len(epw_obstacle) + len(epw_rest))
    f["epw"] = np.concatenate([epw_obstacle, epw_rest])
    return [f], [np.arange(len(f)) < len(epw_obstacle)]


def test_only_inserted_points_change_and_a_missing_car_is_said():
    frames, inserted = _frames_with(np.linspace(0.5, 1.0, 50), np.full(10, 3.0))
    note = match_to_lead(frames, inserted, np.linspace(1.5, 2.5, 100))
    assert note.startswith("EPW matched") and (frames[0]["epw"][~inserted[0]] == 3.0).all()
    assert frames[0]["epw"][inserted[0]].mean() == pytest.approx(2.0, abs=1e-3)
    frames, inserted = _frames_with(np.linspace(0.5, 1.0, 50), [])
    before = frames[0]["epw"].copy()
    assert match_to_lead(frames, inserted, None, "no car") == "EPW not matched to the car ahead: no car"
    few = match_to_lead(frames, inserted, np.ones(MIN_REAR_POINTS - 1))
    assert f"only {MIN_REAR_POINTS - 1} points" in few
    np.testing.assert_array_equal(frames[0]["epw"], before)
    assert math.isfinite(float(before.sum()))
