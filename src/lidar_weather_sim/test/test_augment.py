"""A simulated effect on top of real frames: added weather returns, removed extinguished ones."""

from __future__ import annotations

import subprocess
import sys

import numpy as np
import pytest

from lidar_weather_sim.core.paths import cache_dir
from lidar_weather_sim.core.points import POINT_DTYPE_NO_EPW, Label, empty_points, fill_polar
from lidar_weather_sim.gap.augment import augment_frame
from lidar_weather_sim.gap.signatures import beam_keys

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
