"""Point filters the twin runs on every frame before meshing, found by name as the regions are.

A package adds a filter under the entry-point group :data:`POINT_FILTERS_GROUP`
(``lidar_weather_sim.point_filters``) in its setup.py, as the region plug-ins use ``lidar_weather_sim.regions``::

    entry_points={"lidar_weather_sim.point_filters": ["weather = weather_filter.twin_filter:make"]}

The entry point is a factory called without arguments; it returns a *frame filter*:

- ``keep(points) -> (N,) bool``: True for the points the twin keeps, of one frame's structured points in the
  project's layout (:mod:`lidar_weather_sim.core.points`, sensor frame, as
  :class:`~lidar_weather_sim.io.recording.Recording` reads them); frames come in time order;
- ``name``: what ran on the latest frame (e.g. ``learned-single``), for the report;
- ``reset()``: forget earlier frames (a filter with features of the previous frame).

The simulator does not import the filter package (weather_filter builds on lidar_weather_sim, not the
reverse): the twin asks for :data:`DEFAULT_FILTER` and runs without a filter, saying so, when no package
registers it.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Protocol

import numpy as np

#: Entry-point group of the frame filters (weather_filter registers ``weather``, its default learned filter).
POINT_FILTERS_GROUP = "lidar_weather_sim.point_filters"
#: The filter ``twin`` uses unless told otherwise (``--weather-filter``), when a package registers it.
DEFAULT_FILTER = "weather"
#: ``--weather-filter`` values that are not filter names.
AUTO, NONE = "auto", "none"


class FrameFilter(Protocol):
    name: str

    def keep(self, points: np.ndarray) -> np.ndarray: ...

    def reset(self) -> None: ...


@dataclass(frozen=True)
class FilterChoice:
    """The frame filter to run (None: none) and one line saying what was chosen."""

    filter: FrameFilter | None
    requested: str
    note: str


def registered_filters() -> list[str]:
    """Names registered under :data:`POINT_FILTERS_GROUP`, sorted."""
    from importlib.metadata import entry_points

    return sorted({ep.name for ep in entry_points(group=POINT_FILTERS_GROUP)})


def load_filter(name: str) -> FrameFilter:
    """The frame filter registered as ``name`` (its factory called); LookupError naming the registered ones."""
    from importlib.metadata import entry_points

    found = [ep for ep in entry_points(group=POINT_FILTERS_GROUP) if ep.name == name]
    if not found:
        known = ", ".join(registered_filters()) or "none"
        raise LookupError(f"--weather-filter {name}: no package registers it (entry points {POINT_FILTERS_GROUP}: "
                          f"{known}; or 'none')")  # fmt: skip
    return found[0].load()()


def choose_filter(requested: str = AUTO) -> FilterChoice:
    """``auto``: :data:`DEFAULT_FILTER` when a package registers it, else none (the note says so); ``none``: no
    filter; a name: that filter (LookupError when nothing registers it)."""
    if requested == NONE:
        return FilterChoice(None, requested, "no weather filter (--weather-filter none)")
    if requested == AUTO:
        if DEFAULT_FILTER not in registered_filters():
            return FilterChoice(None, requested, f"no weather filter installed (no '{DEFAULT_FILTER}' entry point in "
                                                 f"{POINT_FILTERS_GROUP}): every point goes to the mesh")  # fmt: skip
        requested = DEFAULT_FILTER
    return FilterChoice(load_filter(requested), requested, "")


def filter_frames(filt: FrameFilter, frames: list[np.ndarray], previous: list[np.ndarray | None]) -> tuple[list[np.ndarray], list[str]]:
    """Keep masks of ``frames`` (each frame's points), each filtered after its ``previous`` frame (the one
    before it in the recording, or None) so that a filter with previous-frame features sees consecutive
    frames; and the name of what ran on each."""
    masks, used = [], []
    for points, before in zip(frames, previous):
        filt.reset()
        if before is not None and len(before):
            filt.keep(before)
        keep = np.asarray(filt.keep(points), dtype=bool)
        if keep.shape != (len(points),):
            raise ValueError(f"point filter {filt.name}: keep mask of shape {keep.shape} for {len(points)} points")
        masks.append(keep)
        used.append(str(filt.name))
    return masks, used
