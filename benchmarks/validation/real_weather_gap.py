#!/usr/bin/env python3
"""`gap` on the real OS1-128 recording with weather put on by the independent reference, through its twin
(issue 51, item 4), every case reported.

    python benchmarks/validation/real_weather_gap.py [--only 0,3] [--bag B] [--beams-per-frame N] [--out DIR]
        [--json F] [--reuse-measured]

Per case, each step through the project's own command line:

1. ``make-measured ouster_street --on BAG --reference --intensity-scale reflectivity --beams-per-frame ALL
   --hide EFFECT`` puts the weather on the real recording's frames: the drop-by-drop reference
   (references/droplets.py) on every beam, at the scenario's seed, each real return at the signal its
   recorded reflectivity and range give in the profile's LIDAR equation (import-ouster writes Ouster's
   calibrated reflectivity as the intensity);
2. ``twin`` builds the scene from that weathered recording (even / odd frame split; the weather filter runs on
   every frame before meshing), not from Ouster's mesh;
3. ``gap --scenario TWIN/scenario.yaml`` fits on the calibration frames and scores the held-out one.

``--reuse-measured`` skips step 1 for a case whose weathered recording ``--out`` already holds (the reference takes
~1 min a frame on every OS1 beam): a change to the twin or the search re-runs on the same weather.

One row per case: what was hidden, what gap named, what it fitted and did not name, the zones it left
unexplained, the verdict (generator_draw.py's: right = exactly the hidden effect named, its main parameter
within 25 %), the held-out gap before -> after, the held-out bird's-eye Pearson after, seconds. The nine cases
are the issue's, fixed before any run: fog at visual range 50, 150 and 400 m, rain 2, 10 and 40 mm/h, snow 0.5,
2 and 5 mm/h.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from generator_draw import append_row, effects_text, judged, verdict

from lidar_weather_sim.scenario.effects import parse_effect
from lidar_weather_sim.scenario.schema import load_scenario
from lidar_weather_sim.sensor.profile import load_profile

ROOT = Path(__file__).resolve().parents[2]
BAG = ROOT / ".venv" / "cache" / "ouster_real" / "os1_128_street"
CASES = ["atmosphere.fog:visual_range=50", "atmosphere.fog:visual_range=150", "atmosphere.fog:visual_range=400",
         "atmosphere.rain:intensity=2", "atmosphere.rain:intensity=10", "atmosphere.rain:intensity=40",
         "atmosphere.snow:intensity=0.5", "atmosphere.snow:intensity=2", "atmosphere.snow:intensity=5"]  # fmt: skip


def cli(*args: str) -> None:
    """Run ``lidar-weather-sim ARGS``; exit with its reason when it fails."""
    done = subprocess.run([sys.executable, "-m", "lidar_weather_sim.cli", *args], capture_output=True, text=True)
    if done.returncode != 0:
        sys.exit(f"lidar-weather-sim {' '.join(args)} exited {done.returncode}: {done.stderr.strip()[-400:]}")


def run_case(index: int, hide: str, bag: Path, work: Path, beams: int, reuse: bool = False) -> dict:
    """Weather on the recording (unless ``reuse`` finds it made), its twin, and the search on the twin; the case's
    row."""
    start = time.perf_counter()
    measured, twin, gap = (work / f"{name}_{index}" for name in ("measured", "twin", "gap"))
    if not (reuse and (measured / "metadata.yaml").is_file()):
        cli("make-measured", "ouster_street", "--on", str(bag), "--reference", "--intensity-scale", "reflectivity",
            "--hide", hide, "--out", str(measured), "--overwrite", "--beams-per-frame", str(beams))  # fmt: skip
    cli("twin", str(measured), "--split", "frames", "--out", str(twin), "--overwrite")
    cli("gap", str(measured), "--scenario", str(twin / "scenario.yaml"), "--out", str(gap))
    result = json.loads((gap / "gap.json").read_text())
    effect = parse_effect(hide)
    hidden = {effect.name: effect.value}
    named, fitted, unexplained = judged(result)
    bev = result.get("heldout_bev", {}).get("after", {})
    return {"index": index, "hidden": hidden, "named": named, "fitted_not_named": fitted, "unexplained": unexplained,
            "verdict": verdict(hidden, named, unexplained), "gap_before": result["gap_before"],
            "gap_after": result["gap_after"], "bev_pearson": bev.get("pearson"),
            "seconds": time.perf_counter() - start}  # fmt: skip


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--only", help="comma-separated case indices (0-8) to run")
    parser.add_argument("--bag", default=str(BAG), help="the real recording (default: %(default)s, from make setup)")
    parser.add_argument("--beams-per-frame", type=int, help="beams the reference simulates per frame (default: "
                        "every beam of the scenario's profile)")
    parser.add_argument("--out", help="keep bags, twins and gap reports here (default: a temporary directory)")
    parser.add_argument("--json", help="append each case's row to this JSON-lines file")
    parser.add_argument("--reuse-measured", action="store_true", help="keep a case's weathered recording when --out "
                        "holds it (module doc)")
    args = parser.parse_args()
    if not Path(args.bag).is_dir():
        sys.exit(f"{args.bag}: no such recording (make setup imports it)")
    keep = {int(i) for i in args.only.split(",")} if args.only else set(range(len(CASES)))
    profile = load_profile(load_scenario("ouster_street").sensor.profile)
    beams = args.beams_per_frame or profile.scan.columns * len(profile.beams)
    print("| # | hidden | named | fitted, not named | unexplained | verdict | held-out gap before -> after | "
          "held-out BEV Pearson | s |\n|---:|---|---|---|---|---|---|---:|---:|", flush=True)  # fmt: skip
    with tempfile.TemporaryDirectory() as tmp:
        work = Path(args.out or tmp)
        work.mkdir(parents=True, exist_ok=True)
        for index in sorted(keep):
            row = run_case(index, CASES[index], Path(args.bag), work, beams, args.reuse_measured)
            text = effects_text
            pearson = "-" if row["bev_pearson"] is None else f"{row['bev_pearson']:.3f}"
            print(f"| {index} | {text(row['hidden'])} | {text(row['named'])} | {text(row['fitted_not_named'])} | "
                  f"{'; '.join(row['unexplained']) or '-'} | {row['verdict']} | {row['gap_before']:.4f} -> "
                  f"{row['gap_after']:.4f} | {pearson} | {row['seconds']:.0f} |", flush=True)  # fmt: skip
            append_row(args.json, row)


if __name__ == "__main__":
    main()
