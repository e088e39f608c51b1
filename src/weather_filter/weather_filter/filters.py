"""Weather-detection filters: structured point array in, boolean *remove* mask out.

Every filter derives from :class:`PointFilter`, which checks the fields a
filter needs, sets aside the points no filter can use (:mod:`weather_filter.cloud_check`:
non-finite or out-of-reach coordinates, (0, 0, 0) placeholders; removed and counted) and times
it; a filter implements only :meth:`PointFilter.remove_mask` on the usable points
(array in, mask out, True = weather/artefact to remove). No ROS import here:
message conversion lives in :mod:`weather_filter.ros.weather_filter_node`.

Neighbour queries use :class:`scipy.spatial.cKDTree` (vectorised, no per-point
Python loops). Ranges are horizontal (``hypot(x, y)``, sensor frame) unless
noted.

| Method  | Needs                  | Reference                                          |
|---------|------------------------|----------------------------------------------------|
| ``dror``  | x, y, z                | Charron, Phillips, Waslander 2018 (CRV)            |
| ``dsor``  | x, y, z                | Kurup & Bos 2021 (arXiv:2109.07078)                |
| ``lior``  | x, y, z, intensity, epw| LIOR-style: Park et al. 2020 (IEEE RA-L), plus EPW |
| ``echo``  | + echo, channel        | multi-echo structure of the beam (this project)    |
| ``learned`` | + echo, channel, epw | paper 4 per-point features, scikit-learn MLP       |

Why one module of ~410 lines: the filters' table above, their parameter models and the factory
(`make_filter`, the fallback) are read together; each filter is ~40 lines.
"""

from __future__ import annotations

import time
import warnings
from abc import ABC, abstractmethod
from dataclasses import dataclass
from functools import partial
from typing import Annotated, Any, Callable, ClassVar

import numpy as np
import pydantic
from pydantic import Field
from pydantic_core import PydanticCustomError
from scipy.spatial import cKDTree

from lidar_weather_sim.core.config import ConfigModel, validate
from lidar_weather_sim.core.registry import Registry
from weather_filter.cloud_check import usable_points
from weather_filter.scan_geometry import angular_resolution_rad

GEOMETRY_FIELDS = frozenset({"x", "y", "z"})
#: Fields a filter reads when the cloud has them (the scan geometry's channel and angles, the shot time).
OPTIONAL_FIELDS = frozenset({"channel", "echo", "azimuth", "elevation", "time_stamp"})


class MissingFieldsError(ValueError):
    """The cloud lacks a field the filter needs (the node falls back to a geometry-only filter)."""


@dataclass(frozen=True)
class FilterResult:
    """``remove``: True for points the filter removes (the set-aside ones included); ``elapsed_s``:
    wall time of the filter; ``set_aside``: points no filter could use (see :mod:`weather_filter.cloud_check`)."""

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
        :class:`~weather_filter.cloud_check.CloudFieldError` for a field it cannot use (both name it)."""
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


class DRORParams(FilterParams):
    """Charron et al. 2018, as published unless ``max_range_m`` is set."""

    angular_resolution_deg: NonNegative | None = Field(
        None, description="alpha, the scan's angular step (deg); None = estimated from the cloud (the coarser of "
        "its azimuth and elevation steps, weather_filter.scan_geometry)")  # fmt: skip
    multiplier: NonNegative = Field(3.0, description="beta: search radius beta * alpha * r, r the horizontal range (-)")
    min_search_radius_m: NonNegative = Field(0.04, description="SR_min: the least search radius (m)")
    min_neighbours: Count = Field(3, description="k_min: fewer neighbours (self excluded) in the radius: removed (count)")
    max_range_m: NonNegative | None = Field(
        None, description="points farther than this from the sensor (m) are left alone; None = every range (as published)")


#: alpha when the cloud has no scan structure to estimate it from (no ``channel``, or not a scanning
#: pattern, e.g. a hand-made test cloud): the project's reference sensor's step (scala4, 0.25 deg).
DEFAULT_ANGULAR_RESOLUTION_DEG = 0.25


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


class DSORParams(FilterParams):
    """Kurup & Bos 2021: k and s as published; r from the cloud unless set."""

    neighbours: Annotated[int, Field(ge=1, strict=True)] = Field(
        4, description="k: nearest neighbours (self excluded) whose mean distance d_i is compared (count, >= 1)")
    std_multiplier: NonNegative = Field(0.01, description="s: global threshold T = mean(d) + s * std(d) (-)")
    range_multiplier: NonNegative | None = Field(
        None, description="r (1/m); None = 1 / (the cloud's mean horizontal range); the paper's fixed value: 0.05")


class DSORFilter(PointFilter):
    """Dynamic statistical outlier removal: mean distance d_i to the k nearest neighbours; global threshold
    T = mean(d) + s * std(d); a point is removed if d_i > T * r * range_i (range_i horizontal, as in the
    authors' PCL implementation).

    T * r * range_i compares a point with the global mean *scaled to its range*, which is only consistent
    when r is the inverse of the range at which the cloud's mean spacing T is observed: the paper's
    r = 0.05 1/m encodes its data set's 20 m. On a cloud whose points are mostly nearer (a street
    scanned by an OS1-128: mean 12 m) the fixed value puts every point's threshold below its own spacing
    (63 % removed on the real clear frames). So r defaults to 1 / mean horizontal range of the cloud."""

    name = "dsor"

    def __init__(self, params: DSORParams = DSORParams()) -> None:
        self.params = params

    def remove_mask(self, points: np.ndarray) -> np.ndarray:
        p = self.params
        coords = xyz(points)
        k = min(p.neighbours + 1, len(points))
        if k < 2:
            return np.zeros(len(points), bool)
        dist, _ = cKDTree(coords).query(coords, k=k, workers=-1)
        mean_d = dist[:, 1:].mean(axis=1)
        threshold = mean_d.mean() + p.std_multiplier * mean_d.std()
        r = horizontal_range(points)
        range_multiplier = p.range_multiplier if p.range_multiplier is not None else 1.0 / max(float(r.mean()), 1e-6)
        return mean_d > threshold * range_multiplier * r


class LIORParams(FilterParams):
    """Candidates are weak, short and near; a candidate with fewer than ``min_neighbours`` inside the
    DROR-style radius max(``min_search_radius_m``, ``multiplier`` * alpha * r) is removed."""

    intensity_threshold: NonNegative = Field(60.0, description="a candidate's intensity is below this (0-255)")
    epw_threshold_m: NonNegative = Field(0.9, description="a candidate's EPW is below this (m)")
    max_range_m: NonNegative = Field(40.0, description="a candidate's horizontal range is at most this (m): weather is near")
    angular_resolution_deg: NonNegative | None = Field(
        None, description="alpha (deg); None = the cloud's azimuth step (weather_filter.scan_geometry)")
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


#: Geometry-only filters usable on any cloud with x, y, z.
GEOMETRY_METHODS = ("dror", "dsor")

#: Parameters of a geometry-only filter when it stands in for a method whose fields the cloud lacks (the target:
#: on real clear frames the filter must remove <= 0.5 % of the points). Without intensity/EPW/echo nothing
#: tells a raindrop from a leaf or an edge pixel, so the fallback removes only what a clear scene does not
#: produce: fewer than 2 neighbours within 5 angular steps (sizes in units of the cloud's own resolution,
#: not metres), and only within the near field where the weather filters look for weather (LIOR's 40 m).
#: Published DROR (beta 3, k_min 3) removes 2.4 % of the real clear OS1-128 frames (foliage, thin
#: structures, mixed pixels at edges); this setting 0.3 %.
FALLBACK_PARAMS = {
    "dror": dict(multiplier=5.0, min_neighbours=2, max_range_m=LIORParams().max_range_m),
    "dsor": dict(std_multiplier=1.0),
}


class GeometryFallbackWarning(UserWarning):
    """A cloud lacked the fields of the requested filter; the geometry-only fallback filtered it."""


class FallbackFilter(PointFilter):
    """``primary`` where the cloud has its fields, else the geometry-only ``fallback`` with a
    :class:`GeometryFallbackWarning` (once per set of missing fields). ``last_used`` names the filter
    that ran on the latest cloud."""

    required_fields = GEOMETRY_FIELDS

    def __init__(self, primary: PointFilter, fallback: PointFilter) -> None:
        self.primary, self.fallback = primary, fallback
        self.name = primary.name
        self.last_used = primary.name
        self._warned: set[tuple[str, ...]] = set()

    def remove_mask(self, points: np.ndarray) -> np.ndarray:
        missing = tuple(self.primary.missing_fields(points))
        filt = self.primary
        if missing:
            filt = self.fallback
            if missing not in self._warned:
                self._warned.add(missing)
                warnings.warn(fallback_message(self.primary.name, list(missing), self.fallback.name), GeometryFallbackWarning, stacklevel=3)
        self.last_used = filt.name
        return filt.remove_mask(points)

    def fields_read(self, points: np.ndarray) -> frozenset[str]:
        """The primary's fields where the cloud has them all, else the fallback's."""
        return self.fallback.required_fields if self.primary.missing_fields(points) else self.primary.required_fields

    def reset(self) -> None:
        self.primary.reset()
        self.fallback.reset()


def fallback_message(method: str, missing: list[str], fallback: str) -> str:
    return f"cloud lacks {', '.join(missing)} (needed by '{method}'): using geometry-only '{fallback}'"


def make_fallback_filter(method: str = "dror") -> PointFilter:
    """The geometry-only filter ``method`` with :data:`FALLBACK_PARAMS`."""
    if method not in GEOMETRY_METHODS:
        raise ValueError(f"fallback method must be one of {', '.join(GEOMETRY_METHODS)}, not {method!r}")
    return make_filter(method, **FALLBACK_PARAMS[method])


def make_filter_with_fallback(method: str, fallback: str = "dror", **overrides) -> PointFilter:
    """``make_filter(method)`` that filters clouds lacking its fields with :func:`make_fallback_filter`."""
    primary = make_filter(method, **overrides)
    if primary.required_fields <= GEOMETRY_FIELDS:
        return primary
    return FallbackFilter(primary, make_fallback_filter(fallback))


def make_filter(method: str, **overrides) -> PointFilter:
    """A filter by method name (:data:`FILTERS`); ``overrides`` replace its default parameters."""
    return FILTERS.get(method)(**overrides)


def _with_params(filter_cls: type[PointFilter], params_cls: type[FilterParams], /, **overrides) -> PointFilter:
    """``filter_cls`` with the defaults of ``params_cls`` replaced by ``overrides`` (validated)."""
    return filter_cls(validate(overrides, params_cls, f"filter '{filter_cls.name}'"))


def _learned(**overrides) -> PointFilter:
    """The learned filter (imported on use: scikit-learn and its compiled features); its parameters are
    ``model_path`` and ``threshold``."""
    from weather_filter.learned import LearnedFilter

    known = ("model_path", "threshold")
    unknown = sorted(set(overrides) - set(known))
    if unknown:
        raise ValueError("filter 'learned' " + UNKNOWN_PARAMETERS.format(unknown=", ".join(unknown), known=", ".join(known)))
    return LearnedFilter.load(**overrides)


#: Filter factories by method name: ``FILTERS.get(method)(**overrides)``.
FILTERS: Registry[Callable[..., PointFilter]] = Registry("filter method")
FILTERS.register("dror", partial(_with_params, DRORFilter, DRORParams))
FILTERS.register("dsor", partial(_with_params, DSORFilter, DSORParams))
FILTERS.register("lior", partial(_with_params, LIORFilter, LIORParams))
FILTERS.register("echo", partial(_with_params, EchoAwareFilter, EchoParams))
FILTERS.register("learned", _learned)
METHODS = tuple(FILTERS.names())
#: What a user who names no method gets: the best weather F1 at object recall >= 0.995 on the held-out runs
#: of every shipped profile (src/weather_filter/README.md, `benchmarks/validation/weather_filter_eval.py`).
DEFAULT_METHOD = "learned"
#: One line per method for ``--help`` and the node's parameter description.
METHOD_HELP = {
    "learned": "per-point MLP on echo, EPW, intensity and neighbourhood features; the best on every shipped profile",
    "echo": "weak, short, sparsely surrounded first echoes of multi-echo beams, plus a LIOR stage",
    "lior": "weak (low intensity, short EPW) points that are also isolated (Park et al. 2020)",
    "dror": "too few neighbours within a range-scaled radius (geometry only: clouds without intensity/EPW)",
    "dsor": "mean neighbour distance above the frame's mean + k std (geometry only)",
}
