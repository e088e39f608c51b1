"""The base of the point filters: structured point array in, boolean *remove* mask out.

Every filter derives from :class:`PointFilter`, which checks the fields a filter needs, sets aside the points
no filter can use (:mod:`weather_filter.points.cloud_check`: non-finite or out-of-reach coordinates, (0, 0, 0)
placeholders; removed and counted) and times it; a filter implements only :meth:`PointFilter.remove_mask` on
the usable points (array in, mask out, True = weather/artefact to remove). Its parameters are a
:class:`FilterParams` model. No ROS import here: message conversion lives in
:mod:`weather_filter.ros.weather_filter_node`.

Neighbour queries use :class:`scipy.spatial.cKDTree` (vectorised, no per-point Python loops). Ranges are
horizontal (``hypot(x, y)``, sensor frame, m) unless noted.
"""

from __future__ import annotations

import time
from abc import ABC, abstractmethod
from dataclasses import dataclass
from typing import Annotated, Any, ClassVar

import numpy as np
import pydantic
from pydantic import Field
from pydantic_core import PydanticCustomError
from scipy.spatial import cKDTree

from lidar_weather_sim.core.config import ConfigModel
from weather_filter.points.cloud_check import usable_points

GEOMETRY_FIELDS = frozenset({"x", "y", "z"})
#: Fields a filter reads when the cloud has them (the scan geometry's channel and angles, the shot time).
OPTIONAL_FIELDS = frozenset({"channel", "echo", "azimuth", "elevation", "time_stamp"})


class MissingFieldsError(ValueError):
    """The cloud lacks a field the filter needs (the node falls back to a geometry-only filter)."""


@dataclass(frozen=True)
class FilterResult:
    """``remove``: True for points the filter removes (the set-aside ones included); ``elapsed_s``:
    wall time of the filter; ``set_aside``: points no filter could use (see :mod:`weather_filter.points.cloud_check`)."""

    remove: np.ndarray
    elapsed_s: float
    set_aside: int = 0


class PointFilter(ABC):
    """Base of all filters: field check and timing; subclasses implement :meth:`remove_mask`."""

    name: ClassVar[str]
    required_fields: ClassVar[frozenset[str]] = GEOMETRY_FIELDS

    def missing_fields(self, points: np.ndarray) -> list[str]:
        names = set(points.dtype.names or ())
        return sorted(self.required_fields - names)

    def fields_read(self, points: np.ndarray) -> frozenset[str]:
        """The fields this filter reads of ``points`` (checked before it runs)."""
        return self.required_fields

    def __call__(self, points: np.ndarray) -> FilterResult:
        """The remove mask of ``points``; raises :class:`MissingFieldsError` for a missing field and
        :class:`~weather_filter.points.cloud_check.CloudFieldError` for a field it cannot use (both name it)."""
        missing = self.missing_fields(points)
        if missing:
            raise MissingFieldsError(f"filter '{self.name}' needs field(s) {', '.join(missing)}")
        start = time.perf_counter()
        readable, usable = usable_points(points, self.fields_read(points), OPTIONAL_FIELDS)
        if usable.set_aside == 0:
            remove = np.zeros(0, bool) if len(points) == 0 else np.asarray(self.remove_mask(readable), dtype=bool)
        else:
            remove = np.ones(len(points), bool)
            kept = readable[usable.keep]
            if len(kept):
                remove[usable.keep] = np.asarray(self.remove_mask(kept), dtype=bool)
        return FilterResult(remove, time.perf_counter() - start, usable.set_aside)

    @abstractmethod
    def remove_mask(self, points: np.ndarray) -> np.ndarray:
        """Boolean mask over ``points``: True where the point is removed."""

    def reset(self) -> None:
        """Forget state carried between frames (only stateful filters override)."""


def xyz(points: np.ndarray) -> np.ndarray:
    """(N, 3) float64 coordinates."""
    return np.column_stack([points["x"], points["y"], points["z"]]).astype(np.float64)


def horizontal_range(points: np.ndarray) -> np.ndarray:
    return np.hypot(points["x"].astype(np.float64), points["y"].astype(np.float64))


def neighbour_counts(tree: cKDTree, query: np.ndarray, radius: np.ndarray | float) -> np.ndarray:
    """Number of tree points within ``radius`` (scalar or per query point) of each query point, self included."""
    return np.asarray(tree.query_ball_point(query, r=radius, return_length=True, workers=-1), dtype=np.int64)


#: A real-valued parameter: a finite number >= 0 (an integer is taken as that number; bools and strings are refused).
NonNegative = Annotated[float, Field(ge=0, strict=True, allow_inf_nan=False)]
#: A counting parameter: an integer >= 0.
Count = Annotated[int, Field(ge=0, strict=True)]


#: How a filter refuses parameter names it does not have.
UNKNOWN_PARAMETERS = "has no parameter(s) {unknown} (its parameters: {known})"


class FilterParams(ConfigModel):
    """Base of the filters' parameter sets (validated by :func:`lidar_weather_sim.core.config.validate`):
    an unknown name is refused with the list of the known ones."""

    @pydantic.model_validator(mode="before")
    @classmethod
    def _refuse_unknown_names(cls, data: Any) -> Any:
        unknown = sorted(set(data) - set(cls.model_fields)) if isinstance(data, dict) else []
        if unknown:
            names = {"unknown": ", ".join(unknown), "known": ", ".join(cls.model_fields)}
            raise PydanticCustomError("unknown_parameter", UNKNOWN_PARAMETERS, names)
        return data
