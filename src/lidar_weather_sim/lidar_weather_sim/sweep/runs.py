"""One sweep run, as a worker executes it: simulate the run's scenario into its bag, compute its metrics.

Everything a run needs travels with it (the validated scenario as data, the seed, what to
compute); files it names (maps, meshes, sensor profiles, reference bags) are read where the
worker runs. Its bag is ``OUT/runs/<run_id>``; a run killed half-way is simulated again from
the start (its bag is overwritten)."""

from __future__ import annotations

import tempfile
import time
from pathlib import Path
from typing import Any

from lidar_weather_sim.sweep.metrics import compute_all
from lidar_weather_sim.sweep.run_spec import RunSpec

RUNS_DIR = "runs"


def base_row(run: RunSpec, run_id: str) -> dict[str, Any]:
    return {"run_id": run_id, "seed": run.seed, **run.point, "status": "ok", "note": "", "error": ""}


def execute(run: RunSpec, out: str, version: str) -> dict[str, Any]:
    """The run's row: its keys, seed, metrics, status (``ok`` / ``error``), error text and time (s)."""
    from lidar_weather_sim.scenario.schema import Scenario
    from lidar_weather_sim.sim.offline import run_scenario

    start = time.perf_counter()
    run_id = run.identity(version)
    row = base_row(run, run_id)
    bag = Path(out) / RUNS_DIR / run_id
    try:
        report = run_scenario(Scenario.model_validate(run.scenario), bag, frames=run.frames, seed=run.seed,
                              profile=run.profile, return_mode=run.return_mode, overwrite=True)  # fmt: skip
        row["note"] = report.stopped or ""
        row.update(compute_all(bag, run))
    except Exception as exc:  # noqa: BLE001 - a failed run is a row; the sweep goes on
        row.update(status="error", error=f"{type(exc).__name__}: {exc}")
    row["elapsed_s"] = round(time.perf_counter() - start, 3)
    return row


def warm_up(run: RunSpec) -> None:
    """One frame of ``run`` into a temporary directory: imports the simulator and compiles (or loads) numba's
    cached kernels, once per machine before the runs start (:meth:`~lidar_weather_sim.core.engine.Engine.warm`)."""
    from lidar_weather_sim.scenario.schema import Scenario
    from lidar_weather_sim.sim.offline import run_scenario

    with tempfile.TemporaryDirectory(prefix="lws-warm-") as tmp:
        run_scenario(Scenario.model_validate(run.scenario), Path(tmp) / "bag", frames=1, seed=run.seed,
                     profile=run.profile, return_mode=run.return_mode)  # fmt: skip
