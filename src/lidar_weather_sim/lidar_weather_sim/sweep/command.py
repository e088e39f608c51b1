"""``lidar-weather-sim sweep``: expand SWEEP.yaml, skip the runs already in DIR, run the rest on the engine.

Nothing is written before the sweep file, every run's scenario, the compute entries and the
engine (a reachable scheduler) have been checked: a bad sweep exits with one line and an
untouched DIR."""

from __future__ import annotations

import shutil
import time
from dataclasses import dataclass
from functools import partial
from pathlib import Path
from typing import Callable

from lidar_weather_sim.core.engine import Engine
from lidar_weather_sim.sweep.metrics import check_available
from lidar_weather_sim.sweep.report import write_report
from lidar_weather_sim.sweep.results import ResultStore
from lidar_weather_sim.sweep.run_spec import code_version
from lidar_weather_sim.sweep.runs import base_row, execute, warm_up
from lidar_weather_sim.sweep.spec import expand, load_sweep


@dataclass(frozen=True)
class SweepReport:
    runs: int
    ran: int
    skipped: int
    failed: int
    wall_s: float
    results: Path
    report: Path


def run_sweep(sweep: str | Path, out: str | Path, *, scheduler: str | None = None, workers: int | None = None,
              progress: Callable[[int, int], None] | None = None) -> SweepReport:  # fmt: skip
    """Run the sweep of ``sweep`` into ``out``. ``workers``: local worker processes (None: one per CPU,
    0: in this process, one run after another); ``scheduler``: a Dask scheduler's address instead.
    ``progress(done, total)`` after each run. Raises ConfigError / LookupError / EngineError before
    writing anything."""
    spec = load_sweep(sweep)
    runs = expand(spec, source=str(sweep))
    check_available(spec.compute)
    version = code_version()
    ids = [run.identity(version) for run in runs]
    out = Path(out)
    store = ResultStore(out)
    finished = store.finished()
    todo = [i for i, run_id in enumerate(ids) if run_id not in finished]
    start = time.perf_counter()
    with Engine(scheduler, workers) if todo else Engine() as engine:  # nothing to run: no cluster to start
        out.mkdir(parents=True, exist_ok=True)
        shutil.copyfile(sweep, out / "sweep.yaml")
        if todo:
            engine.warm(warm_up, runs[todo[0]])
        task = partial(execute, out=str(out.resolve()), version=version)
        for done, outcome in enumerate(engine.map(task, [runs[i] for i in todo]), start=1):
            i = todo[outcome.index]
            row = outcome.result
            if outcome.error is not None:  # the worker died (or the task could not run) every time it was tried
                row = {**base_row(runs[i], ids[i]), "status": "error", "error": outcome.error}
            store.add(row)
            if progress:
                progress(done, len(todo))
        described = engine.describe()
    wall = time.perf_counter() - start
    latest = store.rows()
    rows = [latest[run_id] for run_id in ids]
    results = store.write_csv(rows, spec.swept_keys)
    report = write_report(out, rows, spec.swept_keys, grid=spec.random is None, engine=described, wall_s=wall,
                          skipped=len(runs) - len(todo))  # fmt: skip
    failed = sum(r.get("status") != "ok" for r in rows)
    return SweepReport(len(runs), len(todo), len(runs) - len(todo), failed, wall, results, report)
