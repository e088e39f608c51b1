"""LIOR-style low-intensity outlier removal (Park et al. 2020, IEEE RA-L) with an EPW term: needs x, y, z,
intensity and epw."""

from __future__ import annotations

import numpy as np
from pydantic import Field
from scipy.spatial import cKDTree

from weather_filter.points.base import (
    GEOMETRY_FIELDS,
    Count,
    FilterParams,
    NonNegative,
    PointFilter,
    horizontal_range,
    neighbour_counts,
    xyz,
)
from weather_filter.points.scan_geometry import DEFAULT_ANGULAR_RESOLUTION_DEG, angular_resolution_rad


class LIORParams(FilterParams):
    """Candidates are weak, short and near; a candidate with fewer than ``min_neighbours`` inside the
    DROR-style radius max(``min_search_radius_m``, ``multiplier`` * alpha * r) is removed."""

    intensity_threshold: NonNegative = Field(60.0, description="a candidate's intensity is below this (0-255)")
    epw_threshold_m: NonNegative = Field(0.9, description="a candidate's EPW is below this (m)")
    max_range_m: NonNegative = Field(40.0, description="a candidate's horizontal range is at most this (m): weather is near")
    angular_resolution_deg: NonNegative | None = Field(
        None, description="alpha (deg); None = the cloud's azimuth step (weather_filter.points.scan_geometry)")
    multiplier: NonNegative = Field(3.0, description="search radius multiplier * alpha * r, r the horizontal range (-)")
    min_search_radius_m: NonNegative = Field(0.2, description="the least search radius (m)")
    min_neighbours: Count = Field(3, description="fewer neighbours (self excluded) in the radius: removed (count)")


class LIORFilter(PointFilter):
    """Low-intensity outlier removal (Park et al. 2020) with an EPW term: weak (low intensity, short pulse)
    points that are also isolated are weather. The intensity and EPW thresholds replace LIOR's
    range-dependent intensity curve because this sensor's intensity is already range-compensated
    only by the target's reflectance, not by weather.

    EPW is required: ``intensity`` is "received power on the sensor's scale" and the threshold is only
    meaningful on the scale of the echo-measuring sensor it was set for. A cloud without EPW (a real
    OS1-128, whose ``intensity`` is Ouster's 8-bit *reflectivity*, median 8 on a clear street, so that
    nearly every point is a "weak" candidate) goes to the geometry-only fallback instead."""

    name = "lior"
    required_fields = GEOMETRY_FIELDS | {"intensity", "epw"}

    def __init__(self, params: LIORParams = LIORParams()) -> None:
        self.params = params

    def candidates(self, points: np.ndarray, r: np.ndarray) -> np.ndarray:
        p = self.params
        weak = (points["intensity"].astype(np.float64) < p.intensity_threshold) & (points["epw"] < p.epw_threshold_m)
        return weak & (r <= p.max_range_m)

    def isolated(self, points: np.ndarray, r: np.ndarray, subset: np.ndarray, tree: cKDTree | None = None) -> np.ndarray:
        """Boolean over ``subset`` indices: fewer than k_min neighbours in the dynamic radius."""
        p = self.params
        if tree is None:
            tree = cKDTree(xyz(points))
        # the candidates are already weak short pulses: the horizontal step, as in DROR's paper, suffices here
        alpha = angular_resolution_rad(points, p.angular_resolution_deg, DEFAULT_ANGULAR_RESOLUTION_DEG, "azimuth")
        radius = np.maximum(p.min_search_radius_m, p.multiplier * alpha * r[subset])
        return neighbour_counts(tree, xyz(points[subset]), radius) - 1 < p.min_neighbours

    def remove_mask(self, points: np.ndarray) -> np.ndarray:
        r = horizontal_range(points)
        remove = np.zeros(len(points), bool)
        idx = np.flatnonzero(self.candidates(points, r))
        if len(idx):
            remove[idx] = self.isolated(points, r, idx)
        return remove
