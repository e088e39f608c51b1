#!/usr/bin/env python3
"""Where a twin's re-simulation disagrees with its recording, by range: returns per range band of every frame,
recorded and re-simulated, with effects.

    python benchmarks/validation/twin_range_counts.py BAG TWIN_DIR [EFFECT ...] [--own-reflectivity]

``EFFECT`` as gap writes them (``atmosphere.fog:visual_range=150``). The twin's reflectivity is read as measured
through the effects' air, as ``gap`` reads it (``--own-reflectivity``: as the surfaces' own, as ``run`` does; see
docs/twin.md, Limits). One row per frame and band edge set ``BANDS`` (m); the split's held-out frames are marked.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from lidar_weather_sim.gap.split import SPLIT_FILE, DataSplit
from lidar_weather_sim.io.recording import Recording
from lidar_weather_sim.replay import Resimulator
from lidar_weather_sim.scenario.effects import parse_effect
from lidar_weather_sim.scenario.schema import load_scenario

BANDS = (0.0, 0.5, 5.0, 10.0, 20.0, 40.0, 80.0, 200.0)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("bag")
    parser.add_argument("twin", help="the twin's directory (scenario.yaml, split.yaml)")
    parser.add_argument("effects", nargs="*")
    parser.add_argument("--own-reflectivity", action="store_true", help="do not give the effects' loss back")
    args = parser.parse_args()
    twin = Path(args.twin)
    recording = Recording.load(args.bag)
    effects = [parse_effect(e) for e in args.effects]
    resim = Resimulator(recording, load_scenario(twin / "scenario.yaml"), through_air=not args.own_reflectivity)
    split_file = twin / SPLIT_FILE
    heldout = set(DataSplit.load(split_file).heldout_frames) if split_file.is_file() else set()
    bands = " | ".join(f"{a:g}-{b:g} m" for a, b in zip(BANDS, BANDS[1:]))
    print(f"effects: {', '.join(args.effects) or 'none'}; reflectivity "
          f"{'own' if args.own_reflectivity else 'measured through the effects'}\n\n"
          f"| frame | | {bands} |\n|---|---|{'---:|' * (len(BANDS) - 1)}")  # fmt: skip
    for i in range(len(recording.frames)):
        simulated = resim.frames(effects, [i])[0]
        tag = f"{i}{' (held out)' if i in heldout else ''}"
        for name, points in (("recorded", recording.frames[i].points), ("re-simulated", simulated)):
            counts = np.histogram(points["distance"], BANDS)[0]
            print(f"| {tag} | {name} | {' | '.join(str(int(c)) for c in counts)} |")
            tag = ""


if __name__ == "__main__":
    main()
