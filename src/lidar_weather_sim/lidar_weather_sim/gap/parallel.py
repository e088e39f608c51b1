"""The gap search's evaluations on Dask workers (``lidar-weather-sim gap --workers N | --scheduler ADDR``).

Each worker process builds the search once from a :class:`SearchSource` (the recording's path,
the scenario as data, the profile, topic and budgets: a few hundred bytes per task) and keeps it
for the next task of the same search; the driver sends only effect lists. Re-simulation uses
common random numbers (:mod:`lidar_weather_sim.gap.resim`), so a gap computed on a worker is the
gap the driver would compute: the diagnosis does not depend on where it ran. The recording must
be readable at the same path on every worker.
"""

from __future__ import annotations

import json
from dataclasses import dataclass

import numpy as np

from lidar_weather_sim.scenario.effects import Effect


@dataclass(frozen=True)
class SearchSource:
    measured: str  # absolute path of the recording
    scenario: str  # the scenario as JSON text
    profile: str | None
    topic: str | None
    budgets: tuple[tuple[str, object], ...]  # GapSearch keywords (fit_frames, heldout_frames, families, ...)
    split: str | None = None  # a twin's DataSplit as JSON (its to_dict), or None
    atmosphere_model: str | None = None  # the atmosphere region's model (Resimulator)

    def build(self):
        from lidar_weather_sim.gap.resim import Resimulator
        from lidar_weather_sim.gap.search import GapSearch
        from lidar_weather_sim.gap.split import DataSplit
        from lidar_weather_sim.io.recording import Recording
        from lidar_weather_sim.scenario.schema import Scenario

        resim = Resimulator(Recording.load(self.measured, self.topic), Scenario.model_validate(json.loads(self.scenario)),
                            self.profile, atmosphere_model=self.atmosphere_model)  # fmt: skip
        split = DataSplit.from_dict(json.loads(self.split)) if self.split else None
        return GapSearch(resim, split=split, **dict(self.budgets))


_searches: dict[SearchSource, object] = {}  # this worker's search (one at a time)


def _search(source: SearchSource):
    if source not in _searches:
        _searches.clear()
        _searches[source] = source.build()
    return _searches[source]


def remote_gap(source: SearchSource, job: tuple) -> tuple[float, int]:
    """(gap of ``job``'s effects on its split, with its redraw when it has one, frames cast) on this worker."""
    search = _search(source)
    before = search.resim.casts
    return search.gap(*job), search.resim.casts - before


def remote_fit(source: SearchSource, job: tuple[list[Effect], Effect, np.ndarray, int]) -> tuple[tuple, int]:
    """(:meth:`GapSearch.fit` of ``job``, frames cast) on this worker."""
    search = _search(source)
    before = search.resim.casts
    return search.fit(*job), search.resim.casts - before
