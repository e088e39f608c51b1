"""Run the project's property-based fuzzing with any number of cases per property.

The properties live in the test modules of each input boundary (CI runs them with a few dozen to a
few hundred cases each):

- ``clouds``: ``src/weather_filter/test/test_filter_inputs.py`` - garbage points and corrupted fields
  (through the PointCloud2 encoder and decoder) into every filter method;
- ``bags``: ``src/lidar_weather_sim/test/test_bag_damage.py`` - flipped bytes in a recorded MCAP read back
  through ``bag_info`` and ``read_messages``;
- ``scenarios``: ``src/lidar_weather_sim/test/test_scenario_bounds.py`` - any value at any numeric key of
  a scenario.

The node's share (clouds the decoder accepts but no filter can use, in a seeded malformed stream over
DDS) is ``test/test_malformed_streams.py``. Hypothesis draws cases from ``--seed``: the same seed
gives the same cases. Exit status: pytest's (0 when every case held).

    python scripts/fuzz.py --cases N [--only clouds,bags,scenarios] [--seed S]
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
TARGETS = {
    "clouds": "src/weather_filter/test/test_filter_inputs.py",
    "bags": "src/lidar_weather_sim/test/test_bag_damage.py",
    "scenarios": "src/lidar_weather_sim/test/test_scenario_bounds.py",
}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--cases", type=int, default=1000, help="cases per property (default 1000)")
    ap.add_argument("--only", default=",".join(TARGETS), help=f"comma-separated boundaries of {', '.join(TARGETS)}")
    ap.add_argument("--seed", type=int, default=0, help="hypothesis seed")
    args = ap.parse_args()
    chosen = args.only.split(",")
    unknown = sorted(set(chosen) - set(TARGETS))
    if unknown or args.cases < 1:
        ap.error(f"--only: unknown {unknown}" if unknown else "--cases must be 1 or more")
    env = {**os.environ, "FUZZ_CASES": str(args.cases)}
    cmd = [sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider", "-k", "fuzz",
           f"--hypothesis-seed={args.seed}", *(TARGETS[c] for c in chosen)]  # fmt: skip
    return subprocess.run(cmd, cwd=ROOT, env=env).returncode


if __name__ == "__main__":
    sys.exit(main())
