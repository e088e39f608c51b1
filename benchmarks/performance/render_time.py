"""Wall-clock seconds per frame of ``lidar-weather-sim render`` (no --html) for scala4 and OS1-128 x 2048 bags.

For each profile it simulates ``highway_spray`` for ``--frames`` frames into a bag (what
``lidar-weather-sim run highway_spray --frames N --profile P --out DIR`` writes; or give ``--bags``),
then renders it ``--repeats`` times (actor boxes from the scenario) and prints, per profile, the
median over the repeats of: reading and decoding the frames alone, and the whole render (read,
draw both pictures, write both PNGs, then the GIF), each in s per frame, with the points per frame.

    python benchmarks/performance/render_time.py [--frames 20] [--repeats 3] [--keep DIR]
"""

from __future__ import annotations

import argparse
import shutil
import tempfile
import time
from pathlib import Path

import numpy as np

from lidar_weather_sim.scenario.schema import load_scenario
from lidar_weather_sim.sim.offline import run_scenario
from lidar_weather_sim.viz.render import render_run
from lidar_weather_sim.viz.source import FrameSource, scenario_sizes

PROFILES = ("scala4", "os1_128_2048")


def time_profile(bag: Path, out: Path, sizes: dict, repeats: int) -> tuple[float, float, float]:
    """(read s/frame, render s/frame, mean points per frame), medians over ``repeats``."""
    read, render = [], []
    for _ in range(repeats):
        source = FrameSource(bag, sizes=sizes)
        started = time.perf_counter()
        points = [len(frame.points) for frame in source]
        read.append((time.perf_counter() - started) / len(points))
        source = FrameSource(bag, sizes=sizes)
        started = time.perf_counter()
        report = render_run(source, out)
        render.append((time.perf_counter() - started) / len(report.frames))
    return float(np.median(read)), float(np.median(render)), float(np.mean(points))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--frames", type=int, default=20)
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--keep", help="keep bags and pictures in this directory (default: a temporary one)")
    args = parser.parse_args()
    scenario = load_scenario("highway_spray")
    root = Path(args.keep or tempfile.mkdtemp(prefix="render_time_"))
    print(f"highway_spray, {args.frames} frames, median of {args.repeats} renders; s per frame")
    print(f"{'profile':<14} {'points/frame':>12} {'read':>8} {'render':>8}")
    try:
        for profile in PROFILES:
            bag = root / f"highway_spray_{profile}"
            if not bag.exists():
                run_scenario(scenario, bag, frames=args.frames, profile=profile)
            read, render, points = time_profile(bag, root / f"{profile}_render", scenario_sizes(scenario), args.repeats)
            print(f"{profile:<14} {points:>12.0f} {read:>8.3f} {render:>8.3f}")
    finally:
        if not args.keep:
            shutil.rmtree(root, ignore_errors=True)


if __name__ == "__main__":
    main()
