"""The ``eval`` metrics of ``lidar-weather-sim sweep`` (entry point ``lidar_weather_sim.sweep_metrics``):
``weather-filter eval`` of a run's bag with the default method, its numbers flattened.

Wall-clock figures (``ms_per_frame_*``) are left out: they depend on the machine and its
load, and a sweep's rows must be the same wherever they ran."""

from __future__ import annotations

from pathlib import Path

from lidar_weather_sim.core.names import TOPIC_POINTS


def evaluate(bag: Path, run) -> dict[str, float]:  # noqa: ARG001 (the sweep metric interface)
    from weather_filter.evaluate import evaluate_bag
    from weather_filter.filter_methods import DEFAULT_METHOD

    result = evaluate_bag(str(bag), DEFAULT_METHOD, TOPIC_POINTS)
    out = {k: float(v) for k, v in result.items()
           if isinstance(v, (int, float)) and not isinstance(v, bool) and not k.startswith("ms_per_frame")}  # fmt: skip
    for entry in result.get("per_label", {}).values():
        out[f"{entry['name']}_removed_fraction"] = float(entry["removed_fraction"])
    return out
