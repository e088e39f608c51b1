"""EPW of inserted obstacle points matched to the car ahead's rear (paper 4, Fig. A4, thesis lines 2739, 2871).

The paper: "before training the classifier the histogram of the EPW values of the detections caused
by the synthetic object is adjusted to resemble the one obtained by the real reflections on the rear
of the LV [...] in order to avoid biasing the classifier towards this difference. The histograms are
also trimmed to have the same maximum value" and (Fig. A4) "the mean and standard deviation as
obtained after rendering the scene for the synthetic object are adjusted to resemble those of the LV".

So, over the whole recording (the histograms of Fig. A4 are the data set's):

1. the car ahead's rear points: in every frame, the recorded points of the nearest ``actor_<id>``
   ahead (x > 0) whose position along the car lies within :data:`REAR_DEPTH_M` of its rear face
   (-length/2), at most :data:`REAR_MARGIN_M` outside its footprint, above the road by
   :data:`ROAD_CLEARANCE_M`; when the cloud has ground truth, weather labels are left out;
2. every inserted point's EPW (m) is mapped linearly so that the inserted points' mean and standard
   deviation become the rear's: ``epw' = mean_rear + (epw - mean_ins) * std_rear / std_ins``;
3. then trimmed to the rear's range (its largest EPW, as the paper trims to the same maximum; its
   smallest, as a narrower echo than any recorded would not have been detected).

Relative order is kept (a brighter obstacle keeps the wider echoes); intensity is not changed (the
paper matched EPW only). Without a car ahead, an EPW field or :data:`MIN_REAR_POINTS` rear points the
EPW stays the sensor model's and the reason is logged (warning) and returned. Frames: the sensor
frame (REP-103); m.
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass

import numpy as np

from lidar_weather_sim.core.points import WEATHER_LABELS
from lidar_weather_sim.augment.boxes import Footprint

_log = logging.getLogger(__name__)
_log.addHandler(logging.NullHandler())  # a library: the application shows it (the CLI: a note on stderr)

EPW_MATCH = ("none", "lead")
#: Points up to this far (m) in front of the car's rear face, along the car, count as its rear.
REAR_DEPTH_M = 0.5
#: Points this far (m) outside the car's footprint still count (range noise, a bag's nominal car size).
REAR_MARGIN_M = 0.3
#: Rear points must be this far (m) above the road (the road under the car is not its rear).
ROAD_CLEARANCE_M = 0.1
#: Fewer rear points than this over the recording: no matching (the statistics would be noise).
MIN_REAR_POINTS = 30


def lead_car(cars: tuple[Footprint, ...]) -> Footprint | None:
    """The car ahead: the nearest footprint whose centre is in front of the sensor (x > 0), or None."""
    ahead = [c for c in cars if c.x > 0.0]
    return min(ahead, key=lambda c: math.hypot(c.x, c.y)) if ahead else None


def rear_mask(points: np.ndarray, car: Footprint, road_z_m: float) -> np.ndarray:
    """Points (sensor frame) on the rear of ``car`` (module doc, step 1)."""
    c, s = math.cos(car.yaw), math.sin(car.yaw)
    dx, dy = points["x"].astype(np.float64) - car.x, points["y"].astype(np.float64) - car.y
    u, v = c * dx + s * dy, -s * dx + c * dy  # along / across the car
    back = -0.5 * car.length
    mask = (u >= back - REAR_MARGIN_M) & (u <= back + REAR_DEPTH_M) & (np.abs(v) <= 0.5 * car.width + REAR_MARGIN_M)
    mask &= points["z"].astype(np.float64) >= road_z_m + ROAD_CLEARANCE_M
    if "label" in points.dtype.names:
        mask &= ~np.isin(points["label"], list(WEATHER_LABELS))
    return mask


@dataclass(frozen=True)
class EpwStats:
    """Mean, standard deviation, smallest and largest EPW (m) of ``n`` points."""

    mean: float
    std: float
    low: float
    high: float
    n: int

    @classmethod
    def of(cls, epw: np.ndarray) -> "EpwStats":
        e = np.asarray(epw, np.float64)
        return cls(float(e.mean()), float(e.std()), float(e.min()), float(e.max()), len(e))


def match_epw(epw: np.ndarray, inserted: EpwStats, rear: EpwStats) -> np.ndarray:
    """``epw`` (m) of inserted points mapped to the rear's mean and standard deviation, trimmed to its
    range (module doc, steps 2-3); float32."""
    scale = rear.std / inserted.std if inserted.std > 0.0 else 1.0
    out = rear.mean + (np.asarray(epw, np.float64) - inserted.mean) * scale
    return np.clip(out, rear.low, rear.high).astype(np.float32)


def match_to_lead(frames: list[np.ndarray], inserted: list[np.ndarray], rear_epw: np.ndarray | None,
                  reason: str = "") -> str:  # fmt: skip
    """Set the EPW of the ``inserted`` points (a boolean mask per frame) of ``frames`` in place from
    ``rear_epw`` (m; the recording's car-rear EPWs, None when there are none: ``reason`` says why).
    Returns one line saying what was done, or why nothing was (also logged as a warning)."""
    if not frames or "epw" not in frames[0].dtype.names:
        reason = "the cloud has no EPW field"
    elif rear_epw is not None and len(rear_epw) < MIN_REAR_POINTS:
        reason = f"only {len(rear_epw)} points on the car ahead's rear (need {MIN_REAR_POINTS})"
    elif rear_epw is None:
        reason = reason or "no car ahead"
    else:
        ins = np.concatenate([f["epw"][m] for f, m in zip(frames, inserted)])
        if not len(ins):
            return "EPW not matched: no obstacle point was inserted"
        before, rear = EpwStats.of(ins), EpwStats.of(rear_epw)
        for f, m in zip(frames, inserted):
            f["epw"][m] = match_epw(f["epw"][m], before, rear)
        return (f"EPW matched to the car ahead's rear ({rear.n} points, mean {rear.mean:.3f} sd {rear.std:.3f} m): "
                f"inserted mean {before.mean:.3f} sd {before.std:.3f} m before")  # fmt: skip
    _log.warning("EPW not matched to the car ahead: %s", reason)
    return f"EPW not matched to the car ahead: {reason}"
