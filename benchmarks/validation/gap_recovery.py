"""Reality-gap recovery: hide effects with make-measured, run gap, print what it found.

    python benchmarks/validation/gap_recovery.py [--frames 60] [--fit-frames 30] [--heldout-frames 30]

One row per case (each effect alone and two pairs, as test/test_gap.py): the hidden
parameters, the effects gap names with their fitted main parameter and error, the held-out
gap before and after, and the wall time of the diagnosis (scala4, highway_clear; the road
case pitches the sensor 3 deg down so that the road is in view).
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

from lidar_weather_sim.gap.command import run_gap
from lidar_weather_sim.scenario.effects import parse_effect
from lidar_weather_sim.references.measured import RECOVERY_CASES, case_scenario, make_measured
from lidar_weather_sim.scenario.schema import load_scenario


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--frames", type=int, default=60)
    parser.add_argument("--fit-frames", type=int, default=30)
    parser.add_argument("--heldout-frames", type=int, default=30)
    args = parser.parse_args()
    base = load_scenario("highway_clear")
    print("| hidden | found (error) | held-out gap before -> after | s |\n|---|---|---|---:|")
    for hidden in RECOVERY_CASES:
        scenario = case_scenario(base, hidden)
        effects = [parse_effect(h) for h in hidden]
        with tempfile.TemporaryDirectory() as tmp:
            make_measured(scenario, effects, Path(tmp) / "m", frames=args.frames)
            start = time.perf_counter()
            r = run_gap(Path(tmp) / "m", scenario, Path(tmp) / "gap", fit_frames=args.fit_frames,
                        heldout_frames=args.heldout_frames)  # fmt: skip
            seconds = time.perf_counter() - start
        truth = {e.name: e for e in effects}
        found = []
        for e in r["effects"]:
            spec_main = next(iter(e["params"]))
            value = e["params"][spec_main]
            err = f"{100 * (value / truth[e['name']].value - 1):+.1f} %" if e["name"] in truth else "not hidden"
            found.append(f"{e['name']} {spec_main}={value:.4g} ({err})")
        print(f"| {', '.join(hidden)} | {'; '.join(found) or 'none'} | {r['gap_before']:.4f} -> {r['gap_after']:.4f} "
              f"| {seconds:.0f} |", flush=True)  # fmt: skip


if __name__ == "__main__":
    main()
