"""The point layout is part of the interface: names, types and offsets are fixed."""

import numpy as np
import pytest

from lidar_weather_sim.core.points import (
    POINT_DTYPE,
    POINT_DTYPE_NO_GROUND_TRUTH,
    Label,
    empty_points,
    fill_polar,
    strip_ground_truth,
)

EXPECTED = [
    ("x", "<f4", 0),
    ("y", "<f4", 4),
    ("z", "<f4", 8),
    ("intensity", "u1", 12),
    ("return_type", "u1", 13),
    ("channel", "<u2", 14),
    ("azimuth", "<f4", 16),
    ("elevation", "<f4", 20),
    ("distance", "<f4", 24),
    ("time_stamp", "<u4", 28),
    ("echo", "u1", 32),
    ("label", "u1", 33),
    ("epw", "<f4", 36),
    ("object_id", "<u4", 40),
]


def _layout(dtype):
    return [(n, dtype.fields[n][0].str.replace("|", ""), dtype.fields[n][1]) for n in dtype.names]


def test_ground_truth_layout_matches_the_published_table():
    assert sorted(_layout(POINT_DTYPE), key=lambda f: f[2]) == EXPECTED
    assert POINT_DTYPE.itemsize == 44


def test_layout_without_ground_truth_drops_label_and_object_id():
    expected = [f for f in EXPECTED if f[0] not in ("label", "object_id")]
    assert sorted(_layout(POINT_DTYPE_NO_GROUND_TRUTH), key=lambda f: f[2]) == expected
    assert POINT_DTYPE_NO_GROUND_TRUTH.itemsize == 40


def test_label_codes():
    assert {label.name: int(label) for label in Label} == {
        "UNKNOWN": 0, "STATIC": 1, "VEHICLE": 2, "OBSTACLE": 3, "COVER": 10,
        "RAIN": 11, "FOG": 12, "SNOW": 13, "SPRAY": 14, "NOISE": 15,
    }  # fmt: skip


def test_fill_polar_follows_rep103_and_the_field_definitions():
    points = empty_points(3)
    points["x"], points["y"], points["z"] = [1.0, 0.0, -2.0], [0.0, 2.0, 0.0], [0.0, 0.0, 2.0]
    fill_polar(points)
    np.testing.assert_allclose(points["azimuth"], [0.0, np.pi / 2, np.pi], rtol=1e-6)
    np.testing.assert_allclose(points["elevation"], [0.0, 0.0, np.pi / 4], rtol=1e-6)
    np.testing.assert_allclose(points["distance"], [1.0, 2.0, np.sqrt(8.0)], rtol=1e-6)


def test_strip_ground_truth_keeps_every_other_field():
    points = empty_points(4)
    for name in POINT_DTYPE.names:
        points[name] = np.arange(4) + 1
    stripped = strip_ground_truth(points)
    assert stripped.dtype == POINT_DTYPE_NO_GROUND_TRUTH
    for name in POINT_DTYPE_NO_GROUND_TRUTH.names:
        np.testing.assert_array_equal(stripped[name], points[name])
    with pytest.raises(ValueError):
        stripped["label"]
