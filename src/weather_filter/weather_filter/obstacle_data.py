"""Augmented spray runs for the obstacle classifier: a simulated run (:mod:`weather_filter.simdata`) with
paper 4's boxes put in by ``lidar-weather-sim augment`` (1 per frame, the paper's ranges), both cached
(the simulator and the augmentation are deterministic given their seeds)."""

from __future__ import annotations

from pathlib import Path

from weather_filter.obstacle import parse_run
from weather_filter.simdata import SimSpec, default_cache_dir, simulate


def augmented_bag(run: str, cache_dir: str | Path | None = None) -> Path:
    """The bag of ``run`` (``SPEC@AUGMENT_SEED``), augmented now unless already in the cache."""
    from lidar_weather_sim.gap.augment_obstacles import augment_bag
    from lidar_weather_sim.sensor.profile import load_profile

    text, seed = parse_run(run)
    spec = SimSpec.parse(text)
    cache = Path(cache_dir) if cache_dir else default_cache_dir()
    out = cache / "augmented" / f"{spec.bag_name}_a{seed}"
    if (out / "metadata.yaml").exists():
        return out
    bag = simulate(spec, cache)
    name = spec.profile or spec.load_scenario().sensor.profile
    out.parent.mkdir(parents=True, exist_ok=True)
    augment_bag(bag, out, load_profile(name), name, objects=1, seed=seed, overwrite=True)
    return out
