"""Each filter on constructed clouds with known outliers (no ROS)."""

import numpy as np
import pytest

from lidar_weather_sim.core.points import (
    SOLID_LABELS,
    WEATHER_LABELS,
    Label,
    empty_points,
    fill_polar,
    strip_ground_truth,
)
from weather_filter.filter_methods import make_filter
from weather_filter.points.base import MissingFieldsError
from weather_filter.points.dror import DRORFilter
from weather_filter.points.dsor import DSORFilter, DSORParams
from weather_filter.points.echo import EchoAwareFilter
from weather_filter.points.lior import LIORFilter
from weather_filter.synthetic import highway_frame


def wall_with_outliers(seed: int = 0):
    """A dense wall at x = 10 m (1 cm noise) and 30 isolated far-apart points near the sensor."""
    rng = np.random.default_rng(seed)
    yy, zz = np.meshgrid(np.arange(-3, 3, 0.05), np.arange(-0.5, 1.5, 0.05))
    n_wall = yy.size
    pts = empty_points(n_wall + 30)
    pts["x"][:n_wall] = 10 + rng.normal(0, 0.01, n_wall)
    pts["y"][:n_wall], pts["z"][:n_wall] = yy.ravel(), zz.ravel()
    pts["label"][:n_wall] = Label.STATIC
    pts["intensity"][:n_wall], pts["epw"][:n_wall], pts["echo"][:n_wall] = 150, 1.5, 1
    ang = np.linspace(-1, 1, 30)
    r = np.linspace(1.5, 6, 30)
    pts["x"][n_wall:], pts["y"][n_wall:], pts["z"][n_wall:] = r * np.cos(ang), r * np.sin(ang), np.linspace(-0.3, 0.8, 30)
    pts["label"][n_wall:] = Label.RAIN
    pts["intensity"][n_wall:], pts["epw"][n_wall:], pts["echo"][n_wall:] = 10, 0.4, 1
    pts["channel"] = np.arange(len(pts)) % 16
    pts["time_stamp"] = np.arange(len(pts))
    fill_polar(pts)
    return pts


@pytest.mark.parametrize("method", ["dror", "lior", "echo"])
def test_filter_removes_isolated_outliers_and_keeps_the_wall(method):
    pts = wall_with_outliers()
    remove = make_filter(method)(pts).remove
    weather = pts["label"] == Label.RAIN
    assert remove.dtype == bool and remove.shape == (len(pts),)
    assert remove[weather].all()
    assert not remove[~weather].any()


def test_dror_radius_grows_with_range():
    # five points 0.3 m apart: kept at 100 m (SR = 3 * 0.25 deg * 100 m = 1.3 m), removed at 5 m (SR 0.065 m)
    def cluster(x):
        pts = empty_points(5)
        pts["x"] = x
        pts["y"] = np.arange(5) * 0.3
        return pts

    f = DRORFilter()
    assert f(cluster(100.0)).remove.sum() == 0
    assert f(cluster(5.0)).remove.all()


def test_dsor_removes_near_isolated_points_and_keeps_a_far_wall_scanned_at_0_25_deg():
    # DSOR (published k=4, s=0.01, r=0.05) assumes point spacing grows with range: a wall at 40 m
    # scanned at 0.25 deg x 0.25 deg keeps every point, isolated points at 1.5-6 m are removed.
    az, el = np.meshgrid(np.radians(np.arange(-10, 10, 0.25)), np.radians(np.arange(-2, 2, 0.25)))
    n_wall = az.size
    pts = empty_points(n_wall + 30)
    pts["x"][:n_wall] = 40.0
    pts["y"][:n_wall], pts["z"][:n_wall] = 40.0 * np.tan(az).ravel(), 40.0 * np.tan(el).ravel()
    outliers = wall_with_outliers()[-30:]
    for axis in "xyz":
        pts[axis][n_wall:] = outliers[axis]
    remove = DSORFilter(DSORParams(range_multiplier=0.05))(pts).remove
    assert remove[n_wall:].all() and not remove[:n_wall].any()


def test_dsor_threshold_scales_with_range():
    pts = wall_with_outliers()
    far = pts.copy()
    far["x"] += 200.0  # everything far away: dynamic threshold large, nothing removed
    published = DSORFilter(DSORParams(range_multiplier=0.05))  # fixed r: the threshold grows with absolute range
    assert published(far).remove.sum() < published(pts).remove.sum()


def test_lior_keeps_strong_isolated_points():
    pts = wall_with_outliers()
    outliers = pts["label"] == Label.RAIN
    pts["intensity"][outliers] = 200  # bright isolated returns are not weather for LIOR
    pts["epw"][outliers] = 1.6
    assert not LIORFilter()(pts).remove.any()


def test_echo_filter_removes_weak_first_echo_of_a_multi_echo_beam_even_in_a_cluster():
    # a tight clump of 10 weak first echoes (a DROR/LIOR would keep it) each followed by a wall echo
    pts = empty_points(20)
    pts["x"][:10] = 3.0 + np.arange(10) * 0.02
    pts["y"][:10] = np.arange(10) * 0.02
    pts["echo"][:10], pts["intensity"][:10], pts["epw"][:10], pts["label"][:10] = 1, 10, 0.4, Label.SPRAY
    pts["x"][10:], pts["y"][10:] = 20.0, np.arange(10) * 0.05
    pts["echo"][10:], pts["intensity"][10:], pts["epw"][10:], pts["label"][10:] = 2, 150, 1.5, Label.STATIC
    pts["time_stamp"] = np.tile(np.arange(10), 2)
    remove = EchoAwareFilter()(pts).remove
    assert remove[:10].all() and not remove[10:].any()
    assert not LIORFilter()(pts).remove[:10].all()


def test_filters_accept_an_empty_cloud():
    for method in ("dror", "dsor", "lior", "echo"):
        assert make_filter(method)(empty_points(0)).remove.shape == (0,)


def test_missing_fields_are_reported():
    pts = strip_ground_truth(wall_with_outliers())
    no_echo = np.zeros(len(pts), dtype=[("x", "f4"), ("y", "f4"), ("z", "f4")])
    with pytest.raises(MissingFieldsError, match="echo"):
        EchoAwareFilter()(no_echo)
    assert DRORFilter()(no_echo).remove.shape == (len(pts),)


def test_unknown_method_and_parameter_are_rejected():
    with pytest.raises(ValueError, match="unknown filter method"):
        make_filter("median")
    with pytest.raises(ValueError, match="no parameter"):
        make_filter("dror", radius=3)


def test_echo_filter_keeps_every_solid_point_on_the_constructed_highway():
    pts = highway_frame("rain", seed=5, obstacle_in_spray=True)
    remove = EchoAwareFilter()(pts).remove
    solid = np.isin(pts["label"], list(SOLID_LABELS))
    weather = np.isin(pts["label"], list(WEATHER_LABELS))
    assert not remove[solid].any()
    assert remove[weather].mean() > 0.6
