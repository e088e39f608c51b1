"""The gap package's entry points, as the command line calls them: ``lidar-weather-sim compare``
(:func:`compare`) and ``lidar-weather-sim gap`` (:func:`run_gap`: load, diagnose with
:mod:`lidar_weather_sim.gap.search`, judge what it accepted and what is left unexplained
(:mod:`lidar_weather_sim.gap.unexplained`), re-simulate all frames, report)."""

from __future__ import annotations

import json
import time
from pathlib import Path
from typing import Callable

import yaml

from lidar_weather_sim.core.engine import Engine
from lidar_weather_sim.core.workers import usable_cpus
from lidar_weather_sim.gap.compare import bev_metrics, build_comparison
from lidar_weather_sim.gap.parallel import ForkedWorkers, SearchSource, Workers
from lidar_weather_sim.gap.report import write_compare, write_gap
from lidar_weather_sim.gap.signatures import GapResimulator, measured_signature
from lidar_weather_sim.gap.search import GapSearch
from lidar_weather_sim.gap.split import SPLIT_FILE, DataSplit, split_beside
from lidar_weather_sim.io.recording import Recording
from lidar_weather_sim.scenario.effects import apply_effects
from lidar_weather_sim.scenario.schema import Scenario, load_scenario, scenario_path


def compare(measured: str | Path, simulated: str | Path, out: str | Path, scenario: Scenario | None = None,
            topic: str | None = None) -> dict:  # fmt: skip
    """Compare the ``simulated`` recording with the ``measured`` one (:mod:`lidar_weather_sim.gap.compare`) and write
    metrics.json, report.md and the plots to ``out``; returns metrics.json's content."""
    comparison = build_comparison(Recording.load(measured, topic), Recording.load(simulated, topic), scenario)
    return write_compare(Path(out), comparison, str(measured), str(simulated))


def scenario_and_split(scenario: Scenario | str | Path, split: DataSplit | None) -> tuple[Scenario, DataSplit | None, Path | None]:
    """The scenario (loaded if given by name or YAML path) and the split to use: ``split`` if given, else the
    split.yaml beside a scenario file (a twin's directory), with that file's path (None otherwise)."""
    if isinstance(scenario, Scenario):
        return scenario, split, None
    path = scenario_path(scenario)
    beside = split_beside(path) if split is None else None
    return load_scenario(scenario), beside or split, path.parent / SPLIT_FILE if beside else None


class SearchLog:
    """The search's steps: every progress message, with the seconds since the start and the frames cast, passed on
    to ``progress`` (None: none) and written to ``out``/search.log when the search ends, also when it fails (the
    steps up to the failure)."""

    FILE = "search.log"

    def __init__(self, out: str | Path, progress: Callable[[str, int], None] | None) -> None:
        self.out, self.progress = Path(out), progress
        self.lines: list[str] = []
        self.start = time.perf_counter()

    def __call__(self, message: str, casts: int) -> None:
        self.lines.append(f"{time.perf_counter() - self.start:9.1f} s {casts:8d} frames cast  {message}")
        if self.progress is not None:
            self.progress(message, casts)

    def __enter__(self) -> "SearchLog":
        return self

    def __exit__(self, *exc) -> None:
        self.out.mkdir(parents=True, exist_ok=True)
        (self.out / self.FILE).write_text("".join(f"{line}\n" for line in self.lines))


def run_gap(measured: str | Path, scenario: Scenario | str | Path, out: str | Path, *, profile: str | None = None,
            topic: str | None = None, progress: Callable[[str, int], None] | None = None,
            scheduler: str | None = None, workers: int | None = 0, split: DataSplit | None = None, **budgets) -> dict:  # fmt: skip
    """Diagnose ``measured`` against ``scenario`` and write the gap files to ``out``; returns gap.json's content.

    ``scenario``: a scenario, or its name or YAML path; given by name or path and without ``split``, a twin
    directory's split.yaml beside it decides the calibration and held-out parts (gap.json's ``split`` then names
    the file).

    ``progress(message, frames cast so far)`` is called as the search goes (every message also goes to
    ``out``/search.log: :class:`SearchLog`); ``budgets`` are
    :class:`~lidar_weather_sim.gap.search.GapSearch` keywords (fit_frames, heldout_frames, families, ...);
    ``split`` (a twin's split.yaml) decides the calibration and held-out parts, and gap.json then also holds
    the bird's-eye metrics of the held-out part before and after the effects (``heldout_bev``).
    ``workers``: the search's evaluations on N forked copies of this process (None: one per CPU; 0 or 1: in this
    process); ``scheduler``: on the Dask cluster at that address instead (:mod:`lidar_weather_sim.gap.parallel`;
    the result is the same either way)."""
    scenario, split, split_file = scenario_and_split(scenario, split)
    recording = Recording.load(measured, topic)
    resim = GapResimulator(recording, scenario, profile)
    with SearchLog(out, progress) as logged, Engine(scheduler) as engine:
        remote = None
        if scheduler:  # each worker builds the search again from this
            source = SearchSource(str(Path(measured).resolve()), scenario.model_dump_json(), profile, topic,
                                  tuple(sorted(budgets.items())), json.dumps(split.to_dict()) if split else None)  # fmt: skip
            remote = Workers(engine, source)
        elif workers is None or workers > 1:
            remote = ForkedWorkers(usable_cpus() if workers is None else workers)
        search = GapSearch(resim, progress=logged, workers=remote, split=split, **budgets)
        if isinstance(remote, ForkedWorkers):
            remote.search = search
        diagnosis = search.run()
        judgement = search.judge(diagnosis)
    patched = apply_effects(scenario, diagnosis.effects)
    patched = patched.model_copy(update={"name": f"{scenario.name}_patched",
                                         "description": f"{scenario.description} + effects found by gap".strip()})  # fmt: skip
    everything = range(len(recording.frames))
    measured_sig = measured_signature(recording, everything, resim.contexts, resim.channels)
    before = resim.signature([], everything)
    after = resim.signature(diagnosis.effects, everything)
    text = yaml.safe_dump(patched.model_dump(mode="json"), sort_keys=False)
    result = write_gap(Path(out), diagnosis, measured_sig, before, after, text,
                       runnable=not scenario.mesh_only or bool(scenario.trajectory), judgement=judgement)  # fmt: skip
    if split is not None:
        held, keep = diagnosis.heldout_indices, search.point_mask("heldout")
        measured_held = measured_signature(recording, held, resim.contexts, resim.channels, keep)
        result["split"]["kind"] = split.kind
        result["split"]["file"] = str(split_file) if split_file else None
        result["heldout_bev"] = {"before": bev_metrics(measured_held, resim.signature([], held, keep)),
                                 "after": bev_metrics(measured_held, resim.signature(diagnosis.effects, held, keep))}  # fmt: skip
        (Path(out) / "gap.json").write_text(json.dumps(result, indent=1))
    return result

