"""The weather filter as a frame filter of ``lidar-weather-sim twin`` (entry point ``lidar_weather_sim.point_filters``,
name ``weather``): the twin removes what the filter calls weather from each frame before it meshes the scene.

It is the node's default (:data:`~weather_filter.filter_methods.DEFAULT_METHOD`, the learned filter: the EPW model
on clouds with EPW and echo fields, the single-return model on the others, the geometry-only fallback on clouds
lacking the single-return model's fields), on the project's structured points of one frame (sensor frame).
"""

from __future__ import annotations

import warnings

import numpy as np

from weather_filter.filter_methods import DEFAULT_METHOD, make_filter_with_fallback
from weather_filter.points.base import PointFilter
from weather_filter.points.fallback import GeometryFallbackWarning


def ran(filt: PointFilter) -> str:
    """The name of the model or method that filtered the latest cloud (the geometry fallback's wrapper names the
    learned filter's choice: ``learned``, the EPW model, ``learned-single``, the single-return one)."""
    return str(getattr(filt, "last_used", filt.name))


def weather_keep_mask(filt: PointFilter, points: np.ndarray) -> np.ndarray:
    """(N,) bool: True for the points of ``points`` that ``filt`` keeps (not weather, not unusable)."""
    return ~filt(points).remove


class TwinWeatherFilter:
    """:func:`weather_keep_mask` of the default filter; ``name`` is the filter that ran on the latest frame."""

    def __init__(self, method: str = DEFAULT_METHOD, fallback: str = "dror") -> None:
        self.filter = make_filter_with_fallback(method, fallback)
        self.name = self.filter.name

    def keep(self, points: np.ndarray) -> np.ndarray:
        with warnings.catch_warnings():  # the twin names the filter that ran in its own line
            warnings.simplefilter("ignore", GeometryFallbackWarning)
            keep = weather_keep_mask(self.filter, points)
        self.name = ran(self.filter)
        return keep

    def reset(self) -> None:
        self.filter.reset()


def make() -> TwinWeatherFilter:
    """The entry point's factory."""
    return TwinWeatherFilter()
