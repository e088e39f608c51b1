"""What a recording shows around the sensor: the road level and the vehicles as boxes (sensor frame, REP-103, m)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from lidar_weather_sim.io.recording import Recording


@dataclass(frozen=True)
class ActorBox:
    """A vehicle in the sensor frame: ``pose`` body-to-sensor 4x4 (body origin: centre of the
    footprint on the road, x forward), size in m (default: a mid-size car)."""

    actor_id: int
    pose: np.ndarray
    length_m: float = 4.7
    width_m: float = 1.85
    height_m: float = 1.45


def road_level(recording: Recording, max_frames: int = 50) -> float:
    """z of the road in the sensor frame (m): the road is the lowest surface around, so the 2nd
    percentile of the z of the returns 5-60 m away, over up to ``max_frames`` frames."""
    step = max(1, len(recording.frames) // max_frames)
    z = []
    for frame in recording.frames[::step]:
        p = frame.points
        keep = (p["distance"] >= 5.0) & (p["distance"] <= 60.0)
        z.append(p["z"][keep].astype(np.float64))
    z = np.concatenate(z) if z else np.zeros(0)
    return float(np.percentile(z, 2.0)) if len(z) else -1.0e3  # no returns: no road zone
