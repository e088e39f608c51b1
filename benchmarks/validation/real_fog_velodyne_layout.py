#!/usr/bin/env python3
"""The real OS1-128 recording with the reference's fog, rewritten as a Velodyne driver writes it, through `twin`
and `gap` (issue 51, must show).

    python benchmarks/validation/real_fog_velodyne_layout.py [--visual-range 60] [--out DIR] [--bag B]

1. ``make-measured ouster_street --on BAG --reference --intensity-scale reflectivity --beams-per-frame ALL --hide
   atmosphere.fog:visual_range=V`` (the drop-by-drop reference on every beam);
2. each frame rewritten in velodyne_pointcloud's PointXYZIR layout (x, y, z, intensity float32, ring; no per-point
   time, no EPW, no echo number) with one echo a beam, the strongest (a Velodyne in single, strongest return mode),
   and no /tf (``lidar_weather_sim.testing.driver_layouts``);
3. ``twin`` on that bag (KISS-ICP poses, nothing deskewed: the points have no time), ``gap`` on its twin.

Prints what gap named and fitted, and the returns per held-out frame at 0.25-0.45 m (the cover zone a Velodyne's
fit put there before the twin read the cover zone off the recording) recorded and re-simulated with the gap's
effects (its patched scenario).
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

from lidar_weather_sim.gap.split import SPLIT_FILE, DataSplit
from lidar_weather_sim.io.recording import Recording
from lidar_weather_sim.replay import Resimulator
from lidar_weather_sim.scenario.schema import load_scenario
from lidar_weather_sim.sensor.profile import load_profile
from lidar_weather_sim.sensor.scan import ScanPattern
from lidar_weather_sim.testing.driver_layouts import write_driver_bag

ROOT = Path(__file__).resolve().parents[2]
BAG = ROOT / ".venv" / "cache" / "ouster_real" / "os1_128_street"
COVER_BAND_M = (0.25, 0.45)


def cli(*args: str) -> None:
    done = subprocess.run([sys.executable, "-m", "lidar_weather_sim.cli", *args], capture_output=True, text=True)
    if done.returncode != 0:
        sys.exit(f"lidar-weather-sim {' '.join(args)} exited {done.returncode}: {done.stderr.strip()[-400:]}")
    print(done.stdout.strip().splitlines()[-1] if done.stdout.strip() else "", flush=True)


def strongest_echo(points: np.ndarray, column_ns: float) -> np.ndarray:
    """One point a beam (a channel's firing: its channel and the column its time stamp falls on, ``column_ns`` apart;
    the reference's echoes carry the column's time, the recorded return its own): the brightest."""
    column = np.rint(points["time_stamp"].astype(np.float64) / column_ns).astype(np.int64)
    beam = column * 1024 + points["channel"].astype(np.int64)
    order = np.lexsort((-points["intensity"].astype(np.float64), beam))
    first = np.ones(len(order), bool)
    first[1:] = beam[order][1:] != beam[order][:-1]
    return points[np.sort(order[first])]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--visual-range", type=float, default=60.0, help="the fog's visual range (m)")
    parser.add_argument("--bag", default=str(BAG), help="the real recording (default: %(default)s)")
    parser.add_argument("--out", help="keep the bags, twin and gap report here (default: a temporary directory)")
    args = parser.parse_args()
    profile = load_profile(load_scenario("ouster_street").sensor.profile)
    with tempfile.TemporaryDirectory() as tmp:
        work = Path(args.out or tmp)
        work.mkdir(parents=True, exist_ok=True)
        measured, velodyne, twin, gap = (work / n for n in ("measured", "velodyne", "twin", "gap"))
        if not (measured / "metadata.yaml").is_file():
            cli("make-measured", "ouster_street", "--on", args.bag, "--reference", "--intensity-scale", "reflectivity",
                "--hide", f"atmosphere.fog:visual_range={args.visual_range:g}", "--out", str(measured), "--overwrite",
                "--beams-per-frame", str(profile.scan.columns * len(profile.beams)))  # fmt: skip
        pattern = ScanPattern(profile)
        column_ns = 1e9 * pattern.sweep_s / pattern.n_columns
        frames = [(f.stamp_ns, strongest_echo(f.points, column_ns)) for f in Recording.load(measured).frames]
        if velodyne.exists():
            import shutil

            shutil.rmtree(velodyne)
        write_driver_bag(velodyne, frames, "velodyne_no_time")
        print(f"velodyne XYZIR bag: {len(frames)} frames, {sum(len(p) for _, p in frames)} points", flush=True)
        cli("twin", str(velodyne), "--split", "frames", "--out", str(twin), "--overwrite")
        cli("gap", str(velodyne), "--scenario", str(twin / "scenario.yaml"), "--out", str(gap))
        result = json.loads((gap / "gap.json").read_text())
        named = [e for e in result["effects"] if e.get("named", True)]
        print("named:", ", ".join(f"{e['name']} {e['params']}" for e in named) or "nothing")
        print("fitted, not named:", ", ".join(f"{e['name']} {e['params']} ({e['refused']})" for e in result["effects"]
                                              if not e.get("named", True)) or "nothing")  # fmt: skip
        print(f"held-out gap {result['gap_before']:.4f} -> {result['gap_after']:.4f}")
        recording = Recording.load(velodyne)
        resim = Resimulator(recording, load_scenario(gap / "patched_scenario.yaml"), through_air=True)
        lo, hi = COVER_BAND_M
        for i in DataSplit.load(twin / SPLIT_FILE).heldout_frames:
            rec = recording.frames[i].points["distance"]
            sim = resim.frames([], [i])[0]["distance"]
            print(f"held-out frame {i}: returns at {lo}-{hi} m recorded {int(((rec >= lo) & (rec < hi)).sum())}, "
                  f"re-simulated {int(((sim >= lo) & (sim < hi)).sum())}")


if __name__ == "__main__":
    main()
