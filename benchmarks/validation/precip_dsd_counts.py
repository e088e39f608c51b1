"""How many drop echoes the fixed `precip_dsd` generator makes against the simulator at the same rate (issue 52).

    python benchmarks/validation/precip_dsd_counts.py [--only 3,23] [--profiles scala4] [--frames 8]

For each `precip_dsd` case of config/generator_draw.yaml: the case's "measured" bag by its generator (seed and
hidden effects of the case, a dirty cover where it has one, ground truth kept), and the simulator's own bags
(generator `fast`) at the case's rate and at 1/2, 1/4 and 1/8 of it, the rest alike. Per bag, the rain or snow
echoes per frame (points labelled RAIN / SNOW). Printed per case: those counts, the simulator's rate that gives
the generator's count (log-log interpolation between the two rates around it; "<" below the lowest), and the
two-way loss the simulator's medium puts on a return at 50 m at the case's rate and at that rate (physics
alpha_beta).

What it shows: the rate a gap search can read from the drop echoes of a generator whose drops scatter back less
light than the simulator's. `precip_dsd` gives a drop the specular reflection of its front surface alone
(``F d^2 / 16``, F = 0.020 for water); the simulator's geometric optics adds the axial ray reflected at the back
(Q_back 0.094 for water, 0.076 for ice: lidar_weather_sim.physics.mie.geometric_backscatter), 4-5x brighter.
"""

from __future__ import annotations

import argparse
import tempfile
from pathlib import Path

import numpy as np
import yaml

from lidar_weather_sim.core.paths import config_dir
from lidar_weather_sim.core.points import Label
from lidar_weather_sim.io.recording import Recording
from lidar_weather_sim.physics.coefficients import alpha_beta
from lidar_weather_sim.references.measured import make_measured
from lidar_weather_sim.scenario.effects import EFFECTS, parse_effect
from lidar_weather_sim.scenario.schema import load_scenario

FRACTIONS = (1.0, 0.5, 0.25, 0.125)  # the simulator's rates, as shares of the case's
LABELS = {"atmosphere.rain": Label.RAIN, "atmosphere.snow": Label.SNOW}
WAVELENGTH_NM = 905.0
LOSS_RANGE_M = 50.0


def echoes_per_frame(bag: Path, label: int) -> float:
    """Mean number of points labelled ``label`` per frame of ``bag``."""
    frames = Recording.load(bag).frames
    return float(np.mean([np.count_nonzero(f.points["label"] == label) for f in frames]))


def matching_rate(rates: list[float], counts: list[float], target: float) -> str:
    """The rate (log-log interpolated between ``rates``, any order) whose count is ``target``, as text."""
    order = np.argsort(rates)
    r, c = np.log(np.asarray(rates)[order]), np.log(np.maximum(np.asarray(counts)[order], 1e-9))
    if target < np.exp(c[0]):
        return f"< {np.exp(r[0]):.3g}"
    if target > np.exp(c[-1]):
        return f"> {np.exp(r[-1]):.3g}"
    return f"{np.exp(np.interp(np.log(target), c, r)):.3g}"


def two_way_loss(effect: str, rate: float) -> float:
    """Share of a return's power at LOSS_RANGE_M that the simulator's medium of ``effect`` at ``rate`` takes."""
    alpha, _ = alpha_beta(effect.split(".")[1], rate, WAVELENGTH_NM)
    return 1.0 - float(np.exp(-2.0 * alpha * LOSS_RANGE_M))


def run_case(case: dict, work: Path, frames: int) -> None:
    effect, value = case["effect"], float(case["value"])
    others = [parse_effect(t) for t in case["hide"] if not t.startswith(effect)]
    scenario = load_scenario(case["scenario"])
    key = EFFECTS[effect].main

    def bag_of(generator: str, rate: float) -> float:
        out = work / f"case_{case['index']:02d}_{generator}_{rate:.4g}"
        effects = [parse_effect(f"{effect}:{key}={rate:.6g}"), *others]
        make_measured(scenario, effects, out, frames=frames, seed=case["seed"], profile=case["profile"],
                      generator=generator, ground_truth=True, overwrite=True)  # fmt: skip
        return echoes_per_frame(out, LABELS[effect])

    measured = bag_of("precip_dsd", value)
    rates = [value * f for f in FRACTIONS if value * f >= EFFECTS[effect].bounds[0]]
    counts = [bag_of("fast", r) for r in rates]
    match = matching_rate(rates, counts, measured)
    cover = f" behind {', '.join(case['hide'][1:])}" if len(case["hide"]) > 1 else ""
    print(f"case {case['index']:2d} {case['profile']} {effect} {value:g}{cover}: precip_dsd {measured:.1f} echoes per "
          f"frame; simulator " + ", ".join(f"{c:.1f} at {r:.3g}" for r, c in zip(rates, counts))
          + f"; the simulator's rate with the generator's count {match}; two-way loss at {LOSS_RANGE_M:.0f} m "
          f"{two_way_loss(effect, value):.3f} at {value:g}" + (
              f", {two_way_loss(effect, float(match)):.3f} at {match}" if match[0].isdigit() else ""), flush=True)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--only", default="", help="comma-separated case indices (default: every precip_dsd case)")
    parser.add_argument("--profiles", default="scala4", help="comma-separated profiles (default %(default)s)")
    parser.add_argument("--frames", type=int, default=8, help="frames per bag (default %(default)s)")
    args = parser.parse_args()
    draw = yaml.safe_load((config_dir() / "generator_draw.yaml").read_text())
    only = {int(i) for i in args.only.split(",") if i}
    profiles = set(args.profiles.split(","))
    cases = [c for c in draw["cases"] if c["generator"] == "precip_dsd" and c["profile"] in profiles
             and (not only or c["index"] in only)]  # fmt: skip
    with tempfile.TemporaryDirectory() as tmp:
        for case in cases:
            run_case(case, Path(tmp), args.frames)


if __name__ == "__main__":
    main()
