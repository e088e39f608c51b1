"""The 12 per-frame parameters of paper 2 Fig. 4 on hand-made detections."""

import numpy as np
import pytest

from lidar_weather_sim.core.frame_parameters import FEATURES, frame_features, summarize


def test_features_of_a_known_frame():
    # 3 detections in bin 0.20-0.25, 1 at 1.02, 1 outside the region
    x = np.array([0.21, 0.22, 0.24, 1.02, 6.0])
    echo = np.array([1, 1, 2, 3, 1])
    epw = np.array([1.0, 0.8, 0.6, 0.4, 9.9])
    f = frame_features(x, echo, epw, 0.0, 5.0)
    assert set(f) == set(FEATURES)
    assert f["n_total"] == 4 and f["n_peak"] == 3
    assert f["x_max"] == pytest.approx(0.225)
    assert f["x_mean"] == pytest.approx(np.mean(x[:4]))
    assert f["x_sigma"] == pytest.approx(np.std(x[:4]))
    assert f["x_90"] == pytest.approx(1.05)  # 90 % of 4 = 3.6 detections reached in bin 1.00-1.05
    assert f["n_dd"] == pytest.approx(2 / 4)
    assert (f["n_e1"], f["n_e2"], f["n_e3"]) == (2, 1, 1)
    assert f["epw_mean"] == pytest.approx(0.7) and f["epw_std"] == pytest.approx(np.std([1.0, 0.8, 0.6, 0.4]))


def test_empty_region_and_summary():
    f = frame_features(np.array([10.0]), np.array([1]), np.array([1.0]), 33.0, 37.0)
    assert f["n_total"] == 0 and f["n_peak"] == 0 and np.isnan(f["x_mean"])
    g = frame_features(np.array([34.0, 34.1]), np.array([1, 2]), np.array([1.0, 1.2]), 33.0, 37.0)
    s = summarize([f, g])
    assert s["n_total"] == (1.0, 1.0)
    assert s["x_mean"][0] == pytest.approx(34.05) and s["x_mean"][1] == 0.0
    with pytest.raises(ValueError, match="one shape"):
        frame_features(np.zeros(2), np.zeros(3), np.zeros(2), 0, 5)
