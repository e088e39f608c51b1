"""The point filters by method name: :data:`FILTERS`, :func:`make_filter` and the geometry-only fallback.

| Method  | Needs                  | Module                              | Reference                                          |
|---------|------------------------|-------------------------------------|----------------------------------------------------|
| ``dror``  | x, y, z                | :mod:`weather_filter.points.dror`   | Charron, Phillips, Waslander 2018 (CRV)            |
| ``dsor``  | x, y, z                | :mod:`weather_filter.points.dsor`   | Kurup & Bos 2021 (arXiv:2109.07078)                |
| ``lior``  | x, y, z, intensity, epw| :mod:`weather_filter.points.lior`   | LIOR-style: Park et al. 2020 (IEEE RA-L), plus EPW |
| ``echo``  | + echo, channel        | :mod:`weather_filter.points.echo`   | multi-echo structure of the beam (this project)    |
| ``learned`` | + echo, channel, epw | :mod:`weather_filter.learned.filter`| paper 4 per-point features, scikit-learn MLP       |
|           | or x, y, z, intensity, channel | (single-return model)   | clouds without EPW / later echoes                  |

The learned filter is imported on use (scikit-learn and its compiled features), so the geometry filters load
without them.
"""

from __future__ import annotations

from functools import partial
from typing import Callable

from lidar_weather_sim.core.config import validate
from lidar_weather_sim.core.registry import Registry
from weather_filter.points.base import GEOMETRY_FIELDS, UNKNOWN_PARAMETERS, FilterParams, PointFilter
from weather_filter.points.dror import DRORFilter, DRORParams
from weather_filter.points.dsor import DSORFilter, DSORParams
from weather_filter.points.echo import EchoAwareFilter, EchoParams
from weather_filter.points.fallback import FallbackFilter
from weather_filter.points.lior import LIORFilter, LIORParams

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
    ``model_path`` (one model file, used on every cloud: the EPW model or the single-return one, as the file
    says), ``single_return_model_path`` and ``threshold``. Without ``model_path``: the EPW model on clouds with
    EPW and echo fields, the single-return model on the others (:class:`~weather_filter.learned.filter.LearnedByFields`)."""
    from weather_filter.learned.filter import LearnedByFields, LearnedFilter, SingleReturnLearnedFilter

    known = ("model_path", "single_return_model_path", "threshold")
    unknown = sorted(set(overrides) - set(known))
    if unknown:
        raise ValueError("filter 'learned' " + UNKNOWN_PARAMETERS.format(unknown=", ".join(unknown), known=", ".join(known)))
    single_path = overrides.pop("single_return_model_path", None)
    if overrides.get("model_path"):
        return LearnedFilter.load(**overrides)
    threshold = overrides.get("threshold")
    return LearnedByFields(LearnedFilter.load(None, threshold), SingleReturnLearnedFilter.load(single_path, threshold))


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
    "learned": "per-point MLP on echo, EPW, intensity and neighbourhood features; the best on every shipped profile; "
               "clouds without EPW/echo fields get the single-return model (intensity, range, ring and previous-frame features)",
    "echo": "weak, short, sparsely surrounded first echoes of multi-echo beams, plus a LIOR stage",
    "lior": "weak (low intensity, short EPW) points that are also isolated (Park et al. 2020)",
    "dror": "too few neighbours within a range-scaled radius (geometry only: clouds without intensity/EPW)",
    "dsor": "mean neighbour distance above the frame's mean + k std (geometry only)",
}
