"""The echo-aware filter (this project): weak, sparsely surrounded first echoes of multi-echo beams, plus a
LIOR stage; needs x, y, z, intensity, echo, channel and epw."""

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
from weather_filter.points.lior import LIORFilter, LIORParams


class EchoParams(FilterParams):
    """Weak-first-echo rule: echo 1 of a beam that has a later echo, weak, short, near and sparsely
    surrounded, is removed. Single-echo weak isolated points are handled by the embedded LIOR stage."""

    weak_intensity: NonNegative = Field(80.0, description="a weak first echo's intensity is below this (0-255)")
    weak_epw_m: NonNegative = Field(1.0, description="a weak first echo's EPW is below this (m)")
    max_range_m: NonNegative = Field(40.0, description="a weak first echo's horizontal range is at most this (m)")
    neighbour_radius_m: NonNegative = Field(0.3, description="radius of a weak first echo's neighbour count (m)")
    max_neighbours_for_weather: Count = Field(
        3, description="a weak first echo with fewer neighbours (self excluded) in that radius is removed (count)")
    lior: LIORParams = Field(LIORParams(), description="the embedded LIOR stage (a mapping of LIOR's parameters)")


class EchoAwareFilter(PointFilter):
    """Multi-echo aware: weather returns tend to be weak first echoes followed by a second echo from the same
    beam (the beam goes on to a solid target). Beams are grouped by (channel, time_stamp); a weak, sparsely
    surrounded first echo of a multi-echo beam is removed, as is any weak isolated point (LIOR stage)."""

    name = "echo"
    required_fields = GEOMETRY_FIELDS | {"intensity", "echo", "channel", "epw"}

    def __init__(self, params: EchoParams = EchoParams()) -> None:
        self.params = params
        self._lior = LIORFilter(params.lior)

    @staticmethod
    def beam_has_later_echo(points: np.ndarray) -> np.ndarray:
        """True for points whose beam (channel, firing time or azimuth) has an echo with a higher number."""
        channel = points["channel"].astype(np.int64)
        if "time_stamp" in points.dtype.names:
            shot = points["time_stamp"].astype(np.int64)
        else:
            shot = np.round(np.degrees(np.arctan2(points["y"], points["x"])) * 100).astype(np.int64)
        key = (channel << 40) ^ (shot & ((1 << 40) - 1))
        _, inverse = np.unique(key, return_inverse=True)
        max_echo = np.zeros(inverse.max() + 1, np.int64)
        np.maximum.at(max_echo, inverse, points["echo"].astype(np.int64))
        return max_echo[inverse] > points["echo"]

    def remove_mask(self, points: np.ndarray) -> np.ndarray:
        p = self.params
        r = horizontal_range(points)
        tree = cKDTree(xyz(points))
        weak_first = (
            (points["echo"] == 1)
            & (points["intensity"].astype(np.float64) < p.weak_intensity)
            & (points["epw"] < p.weak_epw_m)
            & (r <= p.max_range_m)
        )
        weak_first &= self.beam_has_later_echo(points)
        remove = np.zeros(len(points), bool)
        idx = np.flatnonzero(weak_first)
        if len(idx):
            others = np.flatnonzero(~weak_first)
            if len(others):
                counts = neighbour_counts(cKDTree(xyz(points[others])), xyz(points[idx]), p.neighbour_radius_m)
                remove[idx] = counts < p.max_neighbours_for_weather
            else:
                remove[idx] = True
        idx = np.flatnonzero(self._lior.candidates(points, r) & ~remove)
        if len(idx):
            remove[idx] = self._lior.isolated(points, r, idx, tree)
        return remove
