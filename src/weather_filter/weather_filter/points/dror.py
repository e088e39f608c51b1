"""DROR, dynamic radius outlier removal (Charron, Phillips, Waslander 2018, CRV): needs x, y, z only."""

from __future__ import annotations

import numpy as np
from pydantic import Field
from scipy.spatial import cKDTree

from weather_filter.points.base import Count, FilterParams, NonNegative, PointFilter, horizontal_range, neighbour_counts, xyz
from weather_filter.points.scan_geometry import DEFAULT_ANGULAR_RESOLUTION_DEG, angular_resolution_rad


class DRORParams(FilterParams):
    """Charron et al. 2018, as published unless ``max_range_m`` is set."""

    angular_resolution_deg: NonNegative | None = Field(
        None, description="alpha, the scan's angular step (deg); None = estimated from the cloud (the coarser of "
        "its azimuth and elevation steps, weather_filter.points.scan_geometry)")  # fmt: skip
    multiplier: NonNegative = Field(3.0, description="beta: search radius beta * alpha * r, r the horizontal range (-)")
    min_search_radius_m: NonNegative = Field(0.04, description="SR_min: the least search radius (m)")
    min_neighbours: Count = Field(3, description="k_min: fewer neighbours (self excluded) in the radius: removed (count)")
    max_range_m: NonNegative | None = Field(
        None, description="points farther than this from the sensor (m) are left alone; None = every range (as published)")


class DRORFilter(PointFilter):
    """Dynamic radius outlier removal: search radius SR = max(SR_min, beta * alpha * r), r the horizontal range,
    alpha the scan's angular resolution; a point with fewer than k_min neighbours inside SR is removed."""

    name = "dror"

    def __init__(self, params: DRORParams = DRORParams()) -> None:
        self.params = params

    def remove_mask(self, points: np.ndarray) -> np.ndarray:
        p = self.params
        coords = xyz(points)
        r = horizontal_range(points)
        alpha = angular_resolution_rad(points, p.angular_resolution_deg, DEFAULT_ANGULAR_RESOLUTION_DEG)
        radius = np.maximum(p.min_search_radius_m, p.multiplier * alpha * r)
        remove = neighbour_counts(cKDTree(coords), coords, radius) - 1 < p.min_neighbours
        if p.max_range_m is not None:
            remove &= np.linalg.norm(coords, axis=1) <= p.max_range_m
        return remove
