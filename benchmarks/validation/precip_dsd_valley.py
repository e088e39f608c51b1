"""Can any rain or snow of the simulator name a `precip_dsd` case's rate, once its drops' brightness is free too?
(issue 52)

    python benchmarks/validation/precip_dsd_valley.py [--only 3,4] [--profiles scala4] [--frames 24] [--out DIR]

`precip_dsd` (fixed before use, never changed) gives a drop only the specular reflection of its front surface;
the simulator's geometric optics also returns the axial ray reflected at the back, 4-5x brighter
(benchmarks/validation/precip_dsd_counts.py). A search could fit a drop backscatter gain beside the rate, as it
fits the fog's. This probe asks whether that could name the rate: for each `precip_dsd` case of
config/generator_draw.yaml, the case's "measured" bag by its generator (the case's seed, and again at the seed +
1), and the simulator's bags on a grid of rates (FACTORS x the hidden rate) and drop gains (GAINS: every placed
drop's reflectance times the gain; a probe of this script, not a parameter of the model), each with the case's
dirty cover as the generator makes it (`cover.dirt` at the hidden transmission, uniform, absorbing only: no
cover returns, no forward scatter; the search would have to find it). Per cell the gap of the comparison
(`lidar-weather-sim compare`: lidar_weather_sim.gap.compare), against both generator bags.

Printed per case and generator seed: the valley, the best gap over the gains at each rate (with that gain and the
near field's range term, which the search's shape rule wants <= 0.05), the rate of the lowest, and the verdict:
"identified" where both seeds' lowest rates lie within 25 % of the hidden one and every rate outside lies above
the lowest by more than the spread between the seeds (the largest difference of a rate's best gap from one
generator seed to the other, less their mean offset); "misread" where both lie outside; else "not identified".
"""

from __future__ import annotations

import argparse
import tempfile
from contextlib import contextmanager
from pathlib import Path

import numpy as np
import yaml

from lidar_weather_sim.core.paths import config_dir
from lidar_weather_sim.gap.compare import build_comparison
from lidar_weather_sim.gap.signatures import gap_terms, gap_value
from lidar_weather_sim.io.recording import Recording
from lidar_weather_sim.references.measured import make_measured
from lidar_weather_sim.regions.physical_air import PhysicalAir
from lidar_weather_sim.scenario.effects import parse_effect
from lidar_weather_sim.scenario.schema import load_scenario

FACTORS = (0.25, 0.4, 0.55, 0.75, 1.0, 1.25, 1.6, 2.0)  # the simulator's rates, as shares of the hidden one
GAINS = (1.0, 0.6, 0.35, 0.2, 0.12, 0.07)  # the drops' backscatter, as shares of the simulator's
WITHIN = 0.25  # a rate within this share of the hidden one is right (the bar)
SEEDS_APART = 1000  # the simulator's bags: the case's seed + this (the generator's: the case's seed and + 1)


@contextmanager
def drop_gain(gain: float):
    """Within the block, every drop :class:`PhysicalAir` places scatters ``gain`` times its backscatter."""
    original = PhysicalAir._drops

    def dimmer(self, hit, w, rng):
        drops = original(self, hit, w, rng)
        if drops is not None:
            drops.reflectance = drops.reflectance * gain
        return drops

    PhysicalAir._drops = dimmer
    try:
        yield
    finally:
        PhysicalAir._drops = original


def gap_of(measured: Recording, simulated: Path, scenario) -> tuple[float, float]:
    """(gap, near field's range term) of ``simulated`` against ``measured``."""
    c = build_comparison(measured, Recording.load(simulated), scenario)
    return gap_value(c.measured, c.simulated), gap_terms(c.measured, c.simulated).get("near/range", 0.0)


def valley(gaps: dict[tuple[float, float], tuple[float, float]]) -> dict[float, tuple[float, float, float]]:
    """Per rate factor: (its best gap over the gains, that gain, that cell's near-field range term)."""
    out = {}
    for f in FACTORS:
        g = min(GAINS, key=lambda gain: gaps[f, gain][0])
        out[f] = (gaps[f, g][0], g, gaps[f, g][1])
    return out


def verdict(valleys: list[dict[float, tuple[float, float, float]]]) -> tuple[str, float]:
    """(verdict, spread between the generator seeds) of the valleys of the two generator bags (module doc)."""
    best = [min(v, key=lambda f: v[f][0]) for v in valleys]
    diff = np.array([valleys[0][f][0] - valleys[1][f][0] for f in FACTORS])
    spread = float(np.max(np.abs(diff - diff.mean())))
    inside = [abs(f - 1.0) <= WITHIN for f in best]
    if not any(inside):
        return "misread", spread
    apart = all(v[f][0] > v[b][0] + spread for v, b in zip(valleys, best) for f in FACTORS if abs(f - 1.0) > WITHIN)
    return ("identified" if all(inside) and apart else "not identified"), spread


def run_case(case: dict, work: Path, frames: int) -> None:
    scenario = load_scenario(case["scenario"])
    effects = [parse_effect(text) for text in case["hide"]]
    weather = effects[0]
    cover = [parse_effect(f"{e.name}:transmission={e.value:.6g},gain=0,forward=0,contrast=0") for e in effects[1:]]
    generated = []
    for k in range(2):
        bag = work / f"case_{case['index']:02d}_generator_{k}"
        make_measured(scenario, effects, bag, frames=frames, seed=case["seed"] + k, profile=case["profile"],
                      generator="precip_dsd", overwrite=True)  # fmt: skip
        generated.append(Recording.load(bag))
    gaps: list[dict] = [{}, {}]
    for f in FACTORS:
        rate = f * case["value"]
        hidden = [parse_effect(f"{weather.name}:intensity={rate:.6g}")] + cover
        for gain in GAINS:
            bag = work / f"case_{case['index']:02d}_{f:g}_{gain:g}"
            with drop_gain(gain):
                make_measured(scenario, hidden, bag, frames=frames, seed=case["seed"] + SEEDS_APART,
                              profile=case["profile"], overwrite=True)  # fmt: skip
            for k in range(2):
                gaps[k][f, gain] = gap_of(generated[k], bag, scenario)
    valleys = [valley(g) for g in gaps]
    result, spread = verdict(valleys)
    dirt = f", dirt {case['cover']}" if case["cover"] else ""
    print(f"\ncase {case['index']}: {case['profile']}, {weather.name} {case['value']}{dirt}; {result} (spread between "
          f"the generator's seeds {spread:.4f})")
    print("| rate factor | rate | best gap, seed 0 (gain, near/range) | best gap, seed 1 (gain, near/range) |\n"
          "|---:|---:|---|---|")
    for f in FACTORS:
        cells = [f"{v[f][0]:.4f} ({v[f][1]:g}, {v[f][2]:.3f})" for v in valleys]
        mark = [" **min**" if f == min(v, key=lambda x: v[x][0]) else "" for v in valleys]
        print(f"| {f:g} | {f * case['value']:.4g} | {cells[0]}{mark[0]} | {cells[1]}{mark[1]} |", flush=True)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--only", help="comma-separated case indices to run")
    parser.add_argument("--profiles", default="scala4,os1_128_1024", help="run only the cases of these profiles")
    parser.add_argument("--frames", type=int, default=24, help="frames per bag (default %(default)s, the draw's)")
    parser.add_argument("--out", help="keep the bags here (default: a temporary directory)")
    args = parser.parse_args()
    cases = yaml.safe_load((config_dir() / "generator_draw.yaml").read_text())["cases"]
    cases = [c for c in cases if c["generator"] == "precip_dsd" and c["profile"] in set(args.profiles.split(","))]
    if args.only:
        cases = [c for c in cases if c["index"] in {int(i) for i in args.only.split(",")}]
    with tempfile.TemporaryDirectory() as tmp:
        work = Path(args.out or tmp)
        work.mkdir(parents=True, exist_ok=True)
        for case in cases:
            run_case(case, work, args.frames)


if __name__ == "__main__":
    main()
