"""The per-frame weather classifier's features (weather_filter.weather_class.RegionFeatures)."""

import numpy as np

from lidar_weather_sim.core.frame_parameters import FEATURES
from weather_filter.weather_class import RegionFeatures, log_counts

N_TOTAL = FEATURES.index("n_total")


def cloud(azimuth_deg: np.ndarray, range_m: np.ndarray) -> np.ndarray:
    points = np.zeros(len(range_m), dtype=[("x", "f4"), ("y", "f4"), ("echo", "u1"), ("epw", "f4")])
    az = np.radians(azimuth_deg)
    points["x"], points["y"] = range_m * np.cos(az), range_m * np.sin(az)
    points["echo"], points["epw"] = 1, 0.5
    return points


def frame(rng, blob: int) -> np.ndarray:
    """A scala4-like frame: a wall at 30 m over +-72.5 deg, 400 weather detections at 0.2-3 m spread over the
    field of view, and ``blob`` detections at 1-3 m within 10 deg (spray ahead-left)."""
    wall = cloud(np.linspace(-72.5, 72.5, 580), np.full(580, 30.0))
    weather = cloud(rng.uniform(-72.5, 72.5, 400), rng.uniform(0.2, 3.0, 400))
    spray = cloud(rng.uniform(20.0, 30.0, blob), rng.uniform(1.0, 3.0, blob))
    return np.concatenate([wall, weather, spray])


def test_the_isotropic_part_leaves_out_a_crowded_direction():
    rng = np.random.default_rng(3)
    features = RegionFeatures()(frame(rng, blob=300))
    assert features.shape == (24,)
    assert features[N_TOTAL] == 700  # the whole region: weather + spray
    assert abs(features[12 + N_TOTAL] - 400) < 40  # the isotropic part: the weather, scaled to the whole span


def test_without_a_crowded_direction_the_isotropic_part_is_the_whole_region():
    features = RegionFeatures()(frame(np.random.default_rng(4), blob=0))
    np.testing.assert_array_equal(features[:12], features[12:])


def test_empty_region_gives_fixed_values_and_log_counts_compress_both_halves():
    features = RegionFeatures()(cloud(np.linspace(-72.5, 72.5, 580), np.full(580, 30.0)))
    assert np.isfinite(features).all() and features[N_TOTAL] == 0 and features[12 + N_TOTAL] == 0
    logged = log_counts(np.array([RegionFeatures()(frame(np.random.default_rng(5), blob=300))]))[0]
    assert logged[N_TOTAL] == np.log1p(700) and abs(logged[12 + N_TOTAL] - np.log1p(400)) < 0.1
