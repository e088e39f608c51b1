"""The gap search's evaluations on Dask workers (``lidar-weather-sim gap --workers N | --scheduler ADDR``).

Each worker process builds the search once from a :class:`SearchSource` (the recording's path,
the scenario as data, the profile, topic and budgets: a few hundred bytes per task) and keeps it
for the next task of the same search; the driver sends only effect lists (:class:`Workers`). Re-simulation
uses common random numbers (:mod:`lidar_weather_sim.replay`), so a gap computed on a worker is the
gap the driver would compute: the diagnosis does not depend on where it ran. The recording must
be readable at the same path on every worker.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from functools import partial
from typing import Callable

import numpy as np

from lidar_weather_sim.core.engine import Engine
from lidar_weather_sim.gap.signatures import GapResimulator
from lidar_weather_sim.gap.search import GapSearch
from lidar_weather_sim.gap.split import DataSplit
from lidar_weather_sim.io.recording import Recording
from lidar_weather_sim.scenario.effects import Effect
from lidar_weather_sim.scenario.schema import Scenario


@dataclass(frozen=True)
class SearchSource:
    measured: str  # absolute path of the recording
    scenario: str  # the scenario as JSON text
    profile: str | None
    topic: str | None
    budgets: tuple[tuple[str, object], ...]  # GapSearch keywords (fit_frames, heldout_frames, families, ...)
    split: str | None = None  # a twin's DataSplit as JSON (its to_dict), or None

    def build(self) -> GapSearch:
        resim = GapResimulator(Recording.load(self.measured, self.topic),
                               Scenario.model_validate(json.loads(self.scenario)), self.profile)  # fmt: skip
        split = DataSplit.from_dict(json.loads(self.split)) if self.split else None
        return GapSearch(resim, split=split, **dict(self.budgets))


_searches: dict[SearchSource, GapSearch] = {}  # this worker's search (one at a time)


def _search(source: SearchSource) -> GapSearch:
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


class Workers:
    """An engine's workers evaluating one search's jobs (each worker builds the search from ``source``); the
    ``workers`` of :class:`~lidar_weather_sim.gap.evaluation.GapEvaluator`."""

    def __init__(self, engine: Engine, source: SearchSource) -> None:
        self.engine = engine
        self.source = source

    def gaps(self, jobs: list[tuple]) -> tuple[list[float], int]:
        """:func:`remote_gap` of every job: the gaps in job order and the frames cast."""
        return self._map(remote_gap, jobs)

    def fits(self, jobs: list[tuple]) -> tuple[list[tuple], int]:
        """:func:`remote_fit` of every job: the fits in job order and the frames cast."""
        return self._map(remote_fit, jobs)

    def _map(self, task: Callable[[SearchSource, tuple], tuple], jobs: list[tuple]) -> tuple[list, int]:
        out, casts = [None] * len(jobs), 0
        for outcome in self.engine.map(partial(task, self.source), jobs):
            if outcome.error:
                raise RuntimeError(f"gap search: an evaluation failed on a worker: {outcome.error}")
            out[outcome.index], cast = outcome.result
            casts += cast
        return out, casts
