#!/usr/bin/env python3
"""How far does the sensor-family held-out gap move when nothing is missing? (the gap search's noise floor)

    python benchmarks/heldout_gap_noise.py [--profile vlp16] [--seeds 6] [--scenario ouster_street]

Each seed re-simulates the real OS1-128 recording's 3 scans in SCENARIO with PROFILE and no hidden effect (as
``sensor_effect_recovery.py`` writes its "measured" bag, seed 1000 + k), then scores the exact model against it on
the held-out scan (budgets 2 / 1 / 1, ``gap --effects sensor``'s terms, not clipped at 0) with the search's own
draw and with each of the confirmation's independent redraws (:data:`~lidar_weather_sim.gap.evaluation.CONFIRM_SEED_OFFSETS`).
Every value would be 0 for a noiseless statistic; their spread is what one held-out frame's gap moves by from draw
to draw, to set against the search's absolute margin (:data:`~lidar_weather_sim.gap.evaluation.MIN_ABS_GAIN`).
"""

from __future__ import annotations

import argparse
import tempfile
from pathlib import Path

import numpy as np
from sensor_effect_recovery import MEASURED_SEED, resimulate


def main() -> None:
    from lidar_weather_sim.core.paths import cache_dir
    from lidar_weather_sim.gap.evaluation import CONFIRM_SEED_OFFSETS, MIN_ABS_GAIN
    from lidar_weather_sim.gap.resim import GapResimulator
    from lidar_weather_sim.gap.search import GapSearch
    from lidar_weather_sim.io.recording import Recording
    from lidar_weather_sim.scenario.schema import load_scenario

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--profile", default="vlp16")
    parser.add_argument("--seeds", type=int, default=6, help="measured draws (seeds 1000 + 1 ... 1000 + N)")
    parser.add_argument("--scenario", default="ouster_street")
    parser.add_argument("--recording", default=str(cache_dir() / "ouster_real" / "os1_128_street"))
    args = parser.parse_args()
    scenario = load_scenario(args.scenario)
    draws = (0, *CONFIRM_SEED_OFFSETS)
    print(f"{args.profile} in {scenario.name}, nothing hidden: unclipped held-out gap of the exact model; columns: the "
          f"search's draw, then the redraws {CONFIRM_SEED_OFFSETS}")  # fmt: skip
    values = []
    with tempfile.TemporaryDirectory(prefix="gap-noise-") as tmp:
        for k in range(1, args.seeds + 1):
            measured = Path(tmp) / f"seed{k}"
            resimulate(Path(args.recording), scenario, args.profile, [], measured, seed=MEASURED_SEED + k)
            resim = GapResimulator(Recording.load(measured), scenario, args.profile)
            search = GapSearch(resim, fit_frames=2, heldout_frames=1, screen_frames=1, families=("sensor",))
            row = [search.gap([], "heldout", redraw, clip=False) for redraw in draws]
            values.append(row)
            print(f"seed {MEASURED_SEED + k}: " + "  ".join(f"{v:+.4f}" for v in row), flush=True)
    values = np.array(values)
    print(f"all {values.size} values: mean {values.mean():+.4f}, standard deviation {values.std(ddof=1):.4f}, "
          f"range {values.min():+.4f} to {values.max():+.4f}; the absolute margin: {MIN_ABS_GAIN}")  # fmt: skip
    print(f"mean of the 3 redraws per seed: standard deviation {values[:, 1:].mean(axis=1).std(ddof=1):.4f}")


if __name__ == "__main__":
    main()
