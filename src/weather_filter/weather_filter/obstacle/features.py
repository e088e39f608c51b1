"""The obstacle classifier's per-detection features, computed on the detections of paper 4's feature region
only (``feature_region_m`` of ``thesis_tables.yaml``: x 0-20 m, |y| <= 6 m, sensor frame): the learned weather
filter's extractor (:class:`weather_filter.learned.features.PointFeatures`), plus the extents of each detection's
bird's-eye cluster (:mod:`weather_filter.obstacle.clusters`) and its cell's occupancy history
(:mod:`weather_filter.obstacle.history`). Which model uses which: ``models/obstacle_point_hgb_v4.md``."""

from __future__ import annotations

import numpy as np

from lidar_weather_sim.augment.boxes import augmentation_table
from weather_filter.learned.features import FEATURE_NAMES, PointFeatures
from weather_filter.obstacle.clusters import CLUSTER_FEATURES, cluster_extents
from weather_filter.obstacle.history import HISTORY_FEATURES, CellHistory

#: Paper 4's 15 per-detection parameters (the v1 model's features).
PAPER_FEATURES = ("x", "y", "echo", "channel", "epw", "n_radial", "n_small", "n_rear", "n_side", "n_middle",
                  "d_radial", "conv_horizontal", "conv_corner", "conv_corner_rot90", "conv_impulse")  # fmt: skip
#: The v2 model's features: every column of the learned filter's extractor.
V2_FEATURES = tuple(FEATURE_NAMES)
#: The v3 model's features: v2's plus the extents of each detection's bird's-eye cluster (the car ahead's rear).
V3_FEATURES = V2_FEATURES + CLUSTER_FEATURES
#: The v4 model's features: v3's plus the occupancy history of each detection's cell (the car ahead holds its
#: place frame after frame, an obstacle does not).
V4_FEATURES = V3_FEATURES + HISTORY_FEATURES


def feature_region_mask(points: np.ndarray) -> np.ndarray:
    """Detections inside the paper's feature region (sensor frame, m)."""
    region = augmentation_table()["feature_region_m"]
    x, y = points["x"], points["y"]
    return (x >= region["x"][0]) & (x <= region["x"][1]) & (y >= region["y"][0]) & (y <= region["y"][1])


class ObstacleFeatures:
    """The features ``names`` (default: the paper's) of the feature region's detections, frame after frame of one
    sequence."""

    def __init__(self, names: tuple[str, ...] = PAPER_FEATURES) -> None:
        region = augmentation_table()["feature_region_m"]
        extent = max(abs(v) for v in (*region["x"], *region["y"]))
        self._extractor = PointFeatures(extent_m=extent, radial_bin_deg=augmentation_table()["histogram_cells_m"]["radial_deg"])
        known = FEATURE_NAMES + CLUSTER_FEATURES + HISTORY_FEATURES
        unknown = [n for n in names if n not in known]
        if unknown:
            raise ValueError(f"unknown obstacle features {unknown} (weather_filter.learned.features.FEATURE_NAMES, "
                             "weather_filter.obstacle.clusters.CLUSTER_FEATURES, "
                             "weather_filter.obstacle.history.HISTORY_FEATURES)")  # fmt: skip
        self.names = tuple(names)
        self._columns = [known.index(n) for n in names]
        self._clusters = any(n in CLUSTER_FEATURES for n in names)
        self._history = CellHistory(region["x"], region["y"]) if any(n in HISTORY_FEATURES for n in names) else None

    def reset(self) -> None:
        self._extractor.reset()
        if self._history is not None:
            self._history.reset()

    def __call__(self, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(mask of the region's detections, (M, len(names)) float32 features of those)."""
        mask = feature_region_mask(points)
        columns = self._extractor(points[mask])
        x, y, z, dz_min = (columns[:, FEATURE_NAMES.index(n)] for n in ("x", "y", "z", "dz_min"))
        extra = [cluster_extents(x, y, z, dz_min) if self._clusters else np.zeros((len(x), len(CLUSTER_FEATURES)), np.float32)]
        if self._history is not None:
            extra.append(self._history(x, y, dz_min))
        columns = np.concatenate([columns, *extra], axis=1)
        return mask, np.ascontiguousarray(columns[:, self._columns])
