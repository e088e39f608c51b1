"""The geometry-only stand-in for a filter whose fields a cloud lacks: :class:`FallbackFilter`."""

from __future__ import annotations

import warnings

import numpy as np

from weather_filter.points.base import GEOMETRY_FIELDS, PointFilter


class GeometryFallbackWarning(UserWarning):
    """A cloud lacked the fields of the requested filter; the geometry-only fallback filtered it."""


class FallbackFilter(PointFilter):
    """``primary`` where the cloud has its fields, else the geometry-only ``fallback`` with a
    :class:`GeometryFallbackWarning` (once per set of missing fields). ``last_used`` names the filter
    that ran on the latest cloud (the model a primary that chooses one ran: ``learned-single``)."""

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
        mask = filt.remove_mask(points)
        self.last_used = getattr(filt, "last_used", filt.name)  # through a filter that chooses its model itself
        return mask

    def fields_read(self, points: np.ndarray) -> frozenset[str]:
        """The primary's fields where the cloud has them all, else the fallback's."""
        return self.fallback.required_fields if self.primary.missing_fields(points) else self.primary.required_fields

    def reset(self) -> None:
        self.primary.reset()
        self.fallback.reset()


def fallback_message(method: str, missing: list[str], fallback: str) -> str:
    return f"cloud lacks {', '.join(missing)} (needed by '{method}'): using geometry-only '{fallback}'"
