"""Augmented spray runs for the obstacle classifier: a simulated run (:mod:`weather_filter.simdata`) with
paper 4's boxes put in by ``lidar-weather-sim augment`` (1 per frame, the paper's ranges), both cached
(the simulator and the augmentation are deterministic given their seeds)."""

from __future__ import annotations

from pathlib import Path

from weather_filter.obstacle.runs import RUN_DEFAULT_KINDS, parse_run_options
from weather_filter.simdata import SimSpec, default_cache_dir, simulate


def augmented_bag(run: str, cache_dir: str | Path | None = None) -> Path:
    """The bag of ``run`` (``SPEC@AUGMENT_SEED[:EPW_MATCH[:KINDS]]``), augmented now unless already in the cache
    (``SPEC@SEED`` alone keeps its v1 cache name ``<bag>_a<SEED>``; other options add ``_<epw>`` / ``_<kinds>``)."""
    from lidar_weather_sim.augment.obstacles import augment_bag
    from lidar_weather_sim.sensor.profile import load_profile

    text, seed, epw_match, kinds = parse_run_options(run)
    spec = SimSpec.parse(text)
    cache = Path(cache_dir) if cache_dir else default_cache_dir()
    suffix = ("" if epw_match == "none" else f"_{epw_match}") + ("" if kinds == RUN_DEFAULT_KINDS else "_" + "-".join(kinds))
    out = cache / "augmented" / f"{spec.bag_name}_a{seed}{suffix}"
    if (out / "metadata.yaml").exists():
        return out
    bag = simulate(spec, cache)
    name = spec.profile or spec.load_scenario().sensor.profile
    out.parent.mkdir(parents=True, exist_ok=True)
    # ``SPEC@SEED`` alone: the v1 classifier's data, boxes with the sensor model's EPW (``none``); ``:lead`` is the
    # paper's EPW matching to the car ahead's rear (augment's default)
    augment_bag(bag, out, load_profile(name), name, objects=1, seed=seed, overwrite=True, kinds=kinds,
                epw_match=epw_match)
    return out


#: Ego speed of the simulated-box runs' base scenario is taken from it; the box drives at the same speed so
#: it stays where it was placed relative to the sensor, as the paper's held boxes do.
SIM_BOX_BASE = "highway_spray"
SIM_BOX_FRAMES = 3
SIM_BOX_LANES_Y_M = (0.0, -3.75)  # ego lane, right lane (the spraying car drives the left one)


def simulated_box_spec(index: int, seed: int = 500):
    """The scenario of simulated box ``index``: ``SIM_BOX_BASE`` with one box actor (label obstacle) of the
    paper's sides (uniform), placed wholly inside the ROI's x range in the ego or the right lane, driving at
    the ego's speed; the simulation seed is ``seed + index``. Returns (scenario, seed)."""
    import numpy as np

    from lidar_weather_sim.augment.boxes import BoxRanges, Roi
    from lidar_weather_sim.scenario.schema import Actor, load_scenario

    base = load_scenario(SIM_BOX_BASE)
    rng = np.random.default_rng([seed, index, 0x626F78])  # "box"
    roi, ranges = Roi.paper(), BoxRanges.paper()
    length, width, height = rng.uniform(*ranges.size_m, 3)
    gap = rng.uniform(roi.x_min_m, roi.x_max_m - length)
    box = Actor(id=300, type="box", label="obstacle", lead_gap_m=float(gap),
                lead_offset_y_m=float(SIM_BOX_LANES_Y_M[index % len(SIM_BOX_LANES_Y_M)]),
                speed_m_s=base.ego.speed_m_s, size={"length_m": length, "width_m": width, "height_m": height})  # fmt: skip
    return base.model_copy(update={"actors": [*base.actors, box]}), seed + index


def simulated_box_bag(index: int, cache_dir: str | Path | None = None, seed: int = 500) -> Path:
    """The bag of simulated box ``index`` (:func:`simulated_box_spec`), simulated now unless cached."""
    from lidar_weather_sim.sim.offline import run_scenario

    cache = Path(cache_dir) if cache_dir else default_cache_dir()
    out = cache / "simulated_boxes" / f"{SIM_BOX_BASE}_box{index}_s{seed}"
    if (out / "metadata.yaml").exists():
        return out
    scenario, run_seed = simulated_box_spec(index, seed)
    out.parent.mkdir(parents=True, exist_ok=True)
    run_scenario(scenario, out, frames=SIM_BOX_FRAMES, seed=run_seed, overwrite=True)
    return out
