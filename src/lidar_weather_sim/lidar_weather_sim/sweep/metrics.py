"""What a sweep computes on each run's bag: one flat ``name -> number`` dict per entry of ``compute``.

- ``stats``: points per frame (mean, sd, min) and points per frame of every label present;
- ``eval``: the weather filter's evaluation of the bag (``weather-filter eval`` with its
  default method), from the plugin registered under :data:`METRICS_GROUP` (the simulator
  does not import the filter package);
- ``{compare: BAG}``: ``lidar-weather-sim compare`` of the run (simulated) against the reference
  BAG (measured): the gap, its bird's-eye Pearson, Jaccard and Hamming distances, and the
  detections per frame of each zone on both sides;
- ``module:function``: ``function(bag, run) -> dict`` of numbers (``bag``: the run's bag
  directory, ``run``: its :class:`~lidar_weather_sim.sweep.run_spec.RunSpec`), columns
  prefixed with the function's name.
"""

from __future__ import annotations

import importlib
import math
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from lidar_weather_sim.core.names import TOPIC_POINTS
from lidar_weather_sim.core.points import Label
from lidar_weather_sim.sweep.run_spec import RunSpec
from lidar_weather_sim.sweep.spec import compute_kind

#: Entry-point group of packages that add metrics by name (weather_filter adds ``eval``).
METRICS_GROUP = "lidar_weather_sim.sweep_metrics"


def stats(bag: Path, run: RunSpec) -> dict[str, float]:
    from lidar_weather_sim.io.bags import read_clouds

    counts, labels = [], []
    for frame in read_clouds(bag, TOPIC_POINTS):
        counts.append(len(frame.points))
        if "label" in (frame.points.dtype.names or ()):
            codes, n = np.unique(frame.points["label"], return_counts=True)
            labels.append(dict(zip(codes.tolist(), n.tolist())))
    if not counts:
        return {"frames": 0}
    out = {"frames": len(counts), "points_per_frame_mean": float(np.mean(counts)),
           "points_per_frame_sd": float(np.std(counts)), "points_per_frame_min": float(np.min(counts))}  # fmt: skip
    for code in sorted(set().union(*labels)):
        name = Label(code).name.lower() if code in Label._value2member_map_ else f"label{code}"
        out[f"{name}_per_frame"] = float(np.mean([frame.get(code, 0) for frame in labels]))
    return out


def compare(bag: Path, run: RunSpec, reference: str) -> dict[str, float]:
    from lidar_weather_sim.gap.compare import build_comparison, metrics
    from lidar_weather_sim.io.recording import Recording
    from lidar_weather_sim.scenario.schema import Scenario

    m = metrics(build_comparison(Recording.load(reference), Recording.load(bag), Scenario.model_validate(run.scenario)))
    out = {"gap": m["gap"], **{f"bev_{k}": v for k, v in m["bev"].items()}}
    for zone, entry in m["zones"].items():
        measured, simulated = entry["detections_per_frame"]["measured"][0], entry["detections_per_frame"]["simulated"][0]
        out[f"{zone}_detections_measured"] = measured
        out[f"{zone}_detections_simulated"] = simulated
    return out


def _plugin(name: str) -> Callable[..., dict]:
    from importlib.metadata import entry_points

    found = [ep for ep in entry_points(group=METRICS_GROUP) if ep.name == name]
    if not found:
        raise LookupError(f"compute '{name}': no package registers it (entry points {METRICS_GROUP}); "
                          "is weather_filter installed?")  # fmt: skip
    return found[0].load()


def user_function(text: str) -> Callable[..., dict]:
    module, _, function = text.partition(":")
    try:
        return getattr(importlib.import_module(module), function)
    except (ImportError, AttributeError) as exc:
        raise LookupError(f"compute '{text}': {exc}") from None


def check_available(items: list[Any]) -> None:
    """LookupError naming the first compute entry this process cannot load (checked before a sweep starts)."""
    for item in items:
        kind = compute_kind(item)
        if kind == "eval":
            _plugin("eval")
        elif kind == "function":
            user_function(item)
        elif kind == "compare" and not Path(item["compare"]).exists():
            raise LookupError(f"compute compare: reference bag {item['compare']} does not exist")


def compute_all(bag: Path, run: RunSpec) -> dict[str, float]:
    """Every entry of ``run.compute`` on ``bag``, prefixed by entry (``stats`` unprefixed)."""
    out: dict[str, float] = {}
    for item in run.compute:
        kind = compute_kind(item)
        if kind == "stats":
            values, prefix = stats(bag, run), ""
        elif kind == "eval":
            values, prefix = _plugin("eval")(bag, run), "eval_"
        elif kind == "compare":
            values, prefix = compare(bag, run, item["compare"]), "compare_"
        else:
            values, prefix = user_function(item)(bag, run), f"{item.partition(':')[2]}_"
        out.update({prefix + k: _number(v) for k, v in values.items()})
    return out


def _number(value: Any) -> float | str:
    if isinstance(value, (bool, np.bool_)):
        return float(value)
    if isinstance(value, (int, float, np.integer, np.floating)):
        return float(value) if math.isfinite(float(value)) else float("nan")
    return str(value)
