"""Weather-detection filters: structured point array in, boolean *remove* mask out.

Every filter derives from :class:`PointFilter`, which checks the fields a
filter needs and times it; a filter implements only :meth:`PointFilter.remove_mask`
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
"""

from __future__ import annotations

import time
import warnings
from abc import ABC, abstractmethod
from dataclasses import dataclass
from dataclasses import fields as dc_fields
from typing import ClassVar

import numpy as np
from scipy.spatial import cKDTree

from weather_filter.scan_geometry import angular_resolution_rad

GEOMETRY_FIELDS = frozenset({"x", "y", "z"})


class MissingFieldsError(ValueError):
    """The cloud lacks a field the filter needs (the node falls back to a geometry-only filter)."""


@dataclass(frozen=True)
class FilterResult:
    """``remove``: True for points the filter removes; ``elapsed_s``: wall time of the filter."""

    remove: np.ndarray
    elapsed_s: float


class PointFilter(ABC):
    """Base of all filters: field check and timing; subclasses implement :meth:`remove_mask`."""

    name: ClassVar[str]
    required_fields: ClassVar[frozenset[str]] = GEOMETRY_FIELDS

    def missing_fields(self, points: np.ndarray) -> list[str]:
        names = set(points.dtype.names or ())
        return sorted(self.required_fields - names)

    def __call__(self, points: np.ndarray) -> FilterResult:
        missing = self.missing_fields(points)
        if missing:
            raise MissingFieldsError(f"filter '{self.name}' needs field(s) {', '.join(missing)}")
        start = time.perf_counter()
        remove = np.zeros(0, bool) if len(points) == 0 else np.asarray(self.remove_mask(points), dtype=bool)
        return FilterResult(remove, time.perf_counter() - start)

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


@dataclass(frozen=True)
class DRORParams:
    """Charron et al. 2018: ``multiplier`` (beta), ``min_search_radius_m`` (SR_min), ``min_neighbours``
    (k_min, self excluded) as published. ``angular_resolution_deg`` (alpha): None = estimated from the cloud
    (the coarser of its azimuth and elevation steps, :mod:`weather_filter.scan_geometry`); a number fixes it.
    ``max_range_m``: None = the published filter (every range); a number leaves points beyond it alone."""

    angular_resolution_deg: float | None = None
    multiplier: float = 3.0
    min_search_radius_m: float = 0.04
    min_neighbours: int = 3
    max_range_m: float | None = None


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


@dataclass(frozen=True)
class DSORParams:
    """Kurup & Bos 2021: k nearest neighbours and global std multiplier s as published; range multiplier r
    (1/m): None = 1 / (the cloud's mean horizontal range), a number fixes it (the paper's 0.05)."""

    neighbours: int = 4
    std_multiplier: float = 0.01
    range_multiplier: float | None = None


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


@dataclass(frozen=True)
class LIORParams:
    """Candidates: intensity below ``intensity_threshold`` (0-255) *and* EPW below ``epw_threshold_m``;
    within ``max_range_m`` (weather returns are near-field). A candidate is removed if it has fewer than
    ``min_neighbours`` (self excluded) inside a DROR-style radius
    max(``min_search_radius_m``, ``multiplier`` * alpha * r), alpha = ``angular_resolution_deg`` or, when
    None, the cloud's azimuth step (:mod:`weather_filter.scan_geometry`)."""

    intensity_threshold: float = 60.0
    epw_threshold_m: float = 0.9
    max_range_m: float = 40.0
    angular_resolution_deg: float | None = None
    multiplier: float = 3.0
    min_search_radius_m: float = 0.2
    min_neighbours: int = 3


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


@dataclass(frozen=True)
class EchoParams:
    """Weak-first-echo rule: echo 1 of a beam that has a later echo, with intensity below
    ``weak_intensity`` and EPW below ``weak_epw_m``, within ``max_range_m``, and with fewer than
    ``max_neighbours_for_weather`` (self excluded) neighbours in ``neighbour_radius_m``. Single-echo weak
    isolated points are handled by the embedded LIOR stage (``lior``)."""

    weak_intensity: float = 80.0
    weak_epw_m: float = 1.0
    max_range_m: float = 40.0
    neighbour_radius_m: float = 0.3
    max_neighbours_for_weather: int = 3
    lior: LIORParams = LIORParams()


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
METHODS = ("dror", "dsor", "lior", "echo", "learned")

#: Parameters of a geometry-only filter when it stands in for a method whose fields the cloud lacks (issue 6:
#: on real clear frames the filter must remove <= 0.5 % of the points). Without intensity/EPW/echo nothing
#: tells a raindrop from a leaf or an edge pixel, so the fallback removes only what a clear scene does not
#: produce: fewer than 2 neighbours within 5 angular steps (sizes in units of the cloud's own resolution,
#: not metres), and only within the near field where the weather filters look for weather (LIOR's 40 m).
#: Published DROR (beta 3, k_min 3) removes 2.4 % of the real clear OS1-128 frames (foliage, thin
#: structures, mixed pixels at edges); this setting 0.3 %.
FALLBACK_PARAMS = {
    "dror": dict(multiplier=5.0, min_neighbours=2, max_range_m=LIORParams.max_range_m),
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
    """A filter by method name; ``overrides`` replace fields of its parameter dataclass."""
    simple = {"dror": (DRORFilter, DRORParams), "dsor": (DSORFilter, DSORParams), "lior": (LIORFilter, LIORParams),
              "echo": (EchoAwareFilter, EchoParams)}  # fmt: skip
    if method in simple:
        cls, params_cls = simple[method]
        return cls(checked_params(params_cls, overrides, f"filter '{method}'"))
    if method == "learned":
        from weather_filter.learned import LearnedFilter

        unknown = set(overrides) - {"model_path", "threshold"}
        if unknown:
            raise ValueError(f"filter 'learned' has no parameter(s) {', '.join(sorted(unknown))} "
                             "(its parameters: model_path, threshold)")  # fmt: skip
        return LearnedFilter.load(**overrides)
    raise ValueError(f"unknown filter method '{method}' (choose from {', '.join(METHODS)})")


#: least value of integer parameters that count neighbours to average over (0 would average nothing)
MIN_INT_PARAMS = {"neighbours": 1}


def checked_params(params_cls, overrides: dict, where: str):
    """``params_cls(**overrides)`` with every override checked against the field's default: numbers must be
    finite and >= 0 (integers for integer fields, >= MIN_INT_PARAMS where listed), None only where the
    default is None, a nested parameter set a mapping of its own fields. Errors name the parameter."""
    known = {f.name: f.default for f in dc_fields(params_cls)}
    unknown = set(overrides) - set(known)
    if unknown:
        raise ValueError(f"{where} has no parameter(s) {', '.join(sorted(unknown))} (its parameters: {', '.join(known)})")
    values = {}
    for name, value in overrides.items():
        default = known[name]
        if hasattr(default, "__dataclass_fields__"):
            if not isinstance(value, dict):
                raise ValueError(f"{where}: {name} must be a mapping of its own parameters, got {value!r}")
            values[name] = checked_params(type(default), value, f"{where} {name}")
            continue
        if value is None and default is None:
            values[name] = None
            continue
        integer = isinstance(default, int)
        ok_type = isinstance(value, int) if integer else isinstance(value, (int, float))
        if isinstance(value, bool) or not ok_type or not np.isfinite(value):
            kind = "an integer" if integer else "a number" + (" or null" if default is None else "")
            raise ValueError(f"{where}: {name} must be {kind}, got {value!r}")
        least = MIN_INT_PARAMS.get(name, 0) if integer else 0
        if value < least:
            raise ValueError(f"{where}: {name} must be at least {least}, got {value!r}")
        values[name] = value
    return params_cls(**values)
