"""DROR and DSOR on a dense frame with and without as many (0, 0, 0) placeholders as real points.

Organised clouds write (0, 0, 0) for beams without a return (here one after every return, the returns
in their scan order); the filters set them aside
(weather_filter.points.cloud_check) instead of searching neighbours among thousands of duplicates. The
frame is the first cloud of BAG (default: a fresh 1-frame OS1-128 x 2048 run of highway_clear);
prints the fastest of ``--repeats`` runs of each and their ratio.

    python benchmarks/filter_placeholders.py [BAG] [--repeats 3]
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

import numpy as np

from lidar_weather_sim.io.bags import read_clouds
from lidar_weather_sim.scenario.schema import load_scenario
from lidar_weather_sim.sim.offline import run_scenario
from weather_filter.filter_methods import make_filter


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("bag", nargs="?", type=Path)
    ap.add_argument("--repeats", type=int, default=3)
    args = ap.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        bag = args.bag
        if bag is None:
            bag = Path(tmp) / "os1"
            run_scenario(load_scenario("highway_clear"), bag, frames=1, profile="os1_128_2048")
        points = next(iter(read_clouds(bag))).points
    padded = np.zeros(2 * len(points), points.dtype)  # as an organised cloud: a placeholder after every return,
    padded[0::2] = points  # the returns in their scan order
    for method in ("dror", "dsor"):
        filt = make_filter(method)
        filt(points)
        best = {}
        for name, cloud in (("without", points), ("with", padded)) * args.repeats:
            t0 = time.perf_counter()
            filt(cloud)
            best[name] = min(best.get(name, np.inf), time.perf_counter() - t0)
        print(f"{method}: {len(points)} points {best['without']:.3f} s; with {len(points)} placeholders "
              f"{best['with']:.3f} s ({best['with'] / best['without']:.2f}x)")


if __name__ == "__main__":
    main()
