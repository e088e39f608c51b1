"""``lidar-weather-sim gap``: load, diagnose (:mod:`lidar_weather_sim.gap.search`), re-simulate all frames, report."""

from __future__ import annotations

from pathlib import Path
from typing import Callable

import yaml

from lidar_weather_sim.core.engine import Engine
from lidar_weather_sim.gap.effects import apply_effects
from lidar_weather_sim.gap.parallel import SearchSource
from lidar_weather_sim.gap.report import write_gap
from lidar_weather_sim.gap.resim import Resimulator, measured_signature
from lidar_weather_sim.gap.search import GapSearch
from lidar_weather_sim.io.recording import Recording
from lidar_weather_sim.scenario.schema import Scenario


def run_gap(measured: str | Path, scenario: Scenario, out: str | Path, *, profile: str | None = None,
            topic: str | None = None, progress: Callable[[str, int], None] | None = None,
            scheduler: str | None = None, workers: int = 0, **budgets) -> dict:  # fmt: skip
    """Diagnose ``measured`` against ``scenario`` and write the gap files to ``out``; returns gap.json's content.

    ``progress(message, frames cast so far)`` is called as the search goes; ``budgets`` are
    :class:`~lidar_weather_sim.gap.search.GapSearch` keywords (fit_frames, heldout_frames, ...).
    ``workers`` / ``scheduler``: the search's evaluations on N local Dask worker processes or on the
    cluster at ``scheduler`` (:mod:`lidar_weather_sim.gap.parallel`; the result is the same)."""
    recording = Recording.load(measured, topic)
    resim = Resimulator(recording, scenario, profile)
    report = (lambda text: progress(text, resim.casts)) if progress else None
    source = SearchSource(str(Path(measured).resolve()), scenario.model_dump_json(), profile, topic,
                          tuple(sorted(budgets.items())))  # fmt: skip
    with Engine(scheduler, workers) as engine:
        diagnosis = GapSearch(resim, progress=report, engine=engine, source=source, **budgets).run()
    patched = apply_effects(scenario, diagnosis.effects)
    patched = patched.model_copy(update={"name": f"{scenario.name}_patched",
                                         "description": f"{scenario.description} + effects found by gap".strip()})  # fmt: skip
    everything = range(len(recording.frames))
    measured_sig = measured_signature(recording, everything, resim.contexts, resim.channels)
    before = resim.signature([], everything)
    after = resim.signature(diagnosis.effects, everything)
    text = yaml.safe_dump(patched.model_dump(mode="json"), sort_keys=False)
    return write_gap(Path(out), diagnosis, measured_sig, before, after, text, runnable=not scenario.mesh_only)
