"""The gap search's evaluations in parallel: in forked copies of this process, or on Dask workers.

:class:`ForkedWorkers` (``lidar-weather-sim gap``'s default: one per CPU, ``--workers N``) forks the process for
each batch of independent evaluations (a round's screening, its fits, its held-out scores): every copy starts from
the search as it stands, with the scene hits, spray particles and gaps it has kept, so nothing is rebuilt or sent but
the effect lists and the results; the gaps a copy computes are handed back and remembered. The copies run the
simulator on one thread each.

:class:`Workers` (``--scheduler ADDR``) runs them on a Dask cluster: each worker process builds the search once from
a :class:`SearchSource` (the recording's path, the scenario as data, the profile, topic and budgets: a few hundred
bytes per task) and keeps it for the next task of the same search; the driver sends only effect lists. The
recording must be readable at the same path on every worker.

Re-simulation uses common random numbers (:mod:`lidar_weather_sim.replay`), so a gap computed in a copy or on a
worker is the gap the driver would compute: the diagnosis does not depend on where it ran.
"""

from __future__ import annotations

import gc
import json
import multiprocessing
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass
from functools import partial
from typing import Callable

import numpy as np

from lidar_weather_sim.core import workers as sim_threads
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


_forked_search: GapSearch | None = None  # the search the forked copies evaluate (set in the parent before they fork)


def _forked_task(kind: str, job: tuple) -> tuple[object, int, dict]:
    """In a forked copy: :meth:`GapSearch.gap` (``kind`` "gap") or :meth:`GapSearch.fit` of ``job``, the frames it
    cast and the gaps it computed that the search did not know."""
    search = _forked_search
    known, casts = set(search.known_gaps), search.resim.casts
    result = search.gap(*job) if kind == "gap" else search.fit(*job)
    return result, search.resim.casts - casts, {k: v for k, v in search.known_gaps.items() if k not in known}


def _one_thread() -> None:
    """A forked copy runs the simulator on one thread: its siblings hold the other cores."""
    sim_threads.THREADS = 1


def fork_is_safe() -> bool:
    """Whether this process can fork evaluation copies: the platform forks, and numba has not started its OpenMP
    threading layer (GNU OpenMP aborts a forked child). Before numba starts one, its fork-safe ``workqueue``
    layer is chosen (the spray's parallel kernels, from 50 000 particles, give the same particles on any layer)."""
    if "fork" not in multiprocessing.get_all_start_methods():
        return False
    import numba
    from numba.np.ufunc import parallel

    if not parallel._is_initialized:
        numba.config.THREADING_LAYER = "workqueue"
        return True
    return numba.threading_layer() != "omp"


class ForkedWorkers:
    """Each batch of a search's evaluations on ``n`` forked copies of this process (module doc); a batch of one,
    or where forking is not safe (:func:`fork_is_safe`), in this process. ``search``: the search, set once it is
    built."""

    def __init__(self, n: int) -> None:
        self.n = int(n)
        self.search: GapSearch | None = None
        self._cast: set[str] = set()  # the splits whose scene hits this process keeps (MemoCaster)

    def gaps(self, jobs: list[tuple]) -> tuple[list[float], int]:
        """:meth:`GapSearch.gap` of every job: the gaps in job order and the frames the copies cast."""
        return self._map("gap", jobs)

    def fits(self, jobs: list[tuple]) -> tuple[list[tuple], int]:
        """:meth:`GapSearch.fit` of every job: the fits in job order and the frames the copies cast."""
        return self._map("fit", jobs)

    def _map(self, kind: str, jobs: list[tuple]) -> tuple[list, int]:
        global _forked_search
        search = self.search
        if len(jobs) < 2 or self.n < 2 or not fork_is_safe():  # here: its casts are counted as it goes
            return [search.gap(*job) if kind == "gap" else search.fit(*job) for job in jobs], 0
        for job in jobs:  # each split's scene hits, kept here before the fork: the copies cast none
            effects, split = job[:2] if kind == "gap" else (job[0] + [search.at_value(job[1], job[2][job[3]])], "fit")
            if split not in self._cast:
                search.gap(effects, split)  # a gap the search needs (a job's, or a fit's first): remembered
                search.gap([], split)  # without regions the simulator casts other rays (no attributes gathered)
                self._cast.add(split)
        gc.freeze()  # the objects so far stay out of the copies' garbage collection, which would copy their pages
        _forked_search = search
        try:
            # fits are chains of evaluations of unequal length: up to two a CPU, so that the last ones share the
            # CPUs rather than one of them running alone (3 fits on 2 CPUs: 1.5 fits' time, not 2)
            copies = min(len(jobs), self.n if kind == "gap" else 2 * self.n)
            with ProcessPoolExecutor(copies, mp_context=multiprocessing.get_context("fork"),
                                     initializer=_one_thread) as pool:  # fmt: skip
                done = list(pool.map(partial(_forked_task, kind), jobs))
        finally:
            _forked_search = None
            gc.unfreeze()
        for _, _, gaps in done:
            search.learn(gaps)
        return [result for result, _, _ in done], sum(casts for _, casts, _ in done)
