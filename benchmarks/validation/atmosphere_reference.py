"""The atmosphere region vs the independent reference, per weather, on one profile.

    python benchmarks/validation/atmosphere_reference.py [--frames 10] [--profile scala4] [--weathers fog:30,rain:10]
        [--columns N]

For each weather, highway_clear is recorded twice with the same seed and no measurement nuisance:
by the simulator's own atmosphere (make-measured, generator fast) and by the reference
(make-measured --reference). Printed per weather: detections per frame in 0-5 m and in total (fast /
reference), the Pearson correlation of the mean per-frame range histograms in 0-5 m (5 cm bins, as the
thesis' paper 2) and 0-100 m (1 m bins), and the EPW distribution (median and 10-90 % of 0-5 m echoes,
and of all echoes). The reference simulates every beam of a profile with at most 4096 beams per frame and
samples the beams of larger ones, which this comparison does not support: ``--columns N`` runs the profile
with N columns instead (e.g. OS1-128 with 32: 4096 beams, every beam sampled; its beams, optics, pulse and
threshold unchanged, each beam a beam of the full profile's physics).
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

import numpy as np
import yaml

from lidar_weather_sim.scenario.effects import parse_effect
from lidar_weather_sim.references.measured import Nuisance, make_measured
from lidar_weather_sim.io.recording import Recording
from lidar_weather_sim.scenario.schema import load_scenario
from lidar_weather_sim.sensor.profile import load_profile

WEATHERS = "fog:30,fog:100,fog:500,rain:1,rain:10,rain:50,snow:0.5,snow:5"
MAIN = {"fog": "visual_range", "rain": "intensity", "snow": "intensity"}


def frames_of(path: Path) -> list[np.ndarray]:
    return [f.points for f in Recording.load(path).frames]


def histogram(frames: list[np.ndarray], lo: float, hi: float, width: float) -> np.ndarray:
    edges = np.arange(lo, hi + width / 2, width)
    return np.mean([np.histogram(f["distance"], edges)[0] for f in frames], axis=0)


def pearson(a: np.ndarray, b: np.ndarray) -> float:
    if a.std() == 0 or b.std() == 0:
        return float("nan")
    return float(np.corrcoef(a, b)[0, 1])


def epw_text(frames: list[np.ndarray], near: bool) -> str:
    epw = np.concatenate([f["epw"][f["distance"] < 5.0] if near else f["epw"] for f in frames])
    if not len(epw):
        return "-"
    p10, p50, p90 = np.percentile(epw, [10, 50, 90])
    return f"{p50:.2f} ({p10:.2f}-{p90:.2f})"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--frames", type=int, default=10)
    parser.add_argument("--profile", default="scala4")
    parser.add_argument("--weathers", default=WEATHERS, help=f"kind:value,... (default {WEATHERS})")
    parser.add_argument("--seed", type=int, default=7)
    parser.add_argument("--columns", type=int, help="run the profile with this many columns (every beam sampled)")
    args = parser.parse_args()
    workdir = tempfile.TemporaryDirectory()
    profile = args.profile
    if args.columns:
        data = load_profile(args.profile).model_dump(mode="json")
        data["name"] = f"{data['name']}_{args.columns}_columns"
        data["scan"]["columns"] = args.columns
        profile = Path(workdir.name) / f"{data['name']}.yaml"
        profile.write_text(yaml.safe_dump(data, sort_keys=False))
        profile = str(profile)
    scenario = load_scenario("highway_clear")
    quiet = Nuisance(extra_range_noise_m=0.0, drop_fraction=0.0)
    print("| weather | 0-5 m per frame fast / ref | all per frame fast / ref | Pearson 0-5 m | Pearson 0-100 m "
          "| EPW 0-5 m fast | EPW 0-5 m ref | EPW all fast | EPW all ref | s ref |\n"
          "|---|---|---|---:|---:|---|---|---|---|---:|")  # fmt: skip
    for item in args.weathers.split(","):
        kind, value = item.split(":")
        effect = parse_effect(f"atmosphere.{kind}:{MAIN[kind]}={value}")
        with tempfile.TemporaryDirectory() as tmp:
            fast, ref = Path(tmp) / "fast", Path(tmp) / "ref"
            make_measured(scenario, [effect], fast, frames=args.frames, seed=args.seed, profile=profile,
                          nuisance=quiet)  # fmt: skip
            start = time.perf_counter()
            make_measured(scenario, [effect], ref, frames=args.frames, seed=args.seed, profile=profile,
                          nuisance=quiet, generator="reference")  # fmt: skip
            seconds = time.perf_counter() - start
            f, r = frames_of(fast), frames_of(ref)
        near_f = np.mean([np.sum(x["distance"] < 5.0) for x in f])
        near_r = np.mean([np.sum(x["distance"] < 5.0) for x in r])
        all_f, all_r = np.mean([len(x) for x in f]), np.mean([len(x) for x in r])
        p5 = pearson(histogram(f, 0.0, 5.0, 0.05), histogram(r, 0.0, 5.0, 0.05))
        p100 = pearson(histogram(f, 0.0, 100.0, 1.0), histogram(r, 0.0, 100.0, 1.0))
        print(f"| {kind} {value} | {near_f:.0f} / {near_r:.0f} | {all_f:.0f} / {all_r:.0f} | {p5:.2f} | {p100:.2f} | "
              f"{epw_text(f, True)} | {epw_text(r, True)} | {epw_text(f, False)} | {epw_text(r, False)} | "
              f"{seconds:.0f} |", flush=True)  # fmt: skip


if __name__ == "__main__":
    main()
