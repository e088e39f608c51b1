#!/usr/bin/env python3
"""How much of a recording's weather a twin's mesh holds: the share of weather-labelled and of object-labelled
points (static, vehicle, obstacle) within 0.1 m of each twin's mesh, calibration (even) and held-out (odd) frames,
for twins of one simulated bag built with and without the weather filter (``twin --weather-filter``).

Usage: python benchmarks/validation/twin_weather_mesh.py BAG TWIN_DIR [TWIN_DIR ...]
(BAG: a bag written by ``lidar-weather-sim run``, with labels; each TWIN_DIR: ``lidar-weather-sim twin BAG --split
frames --out TWIN_DIR``.)
"""

from __future__ import annotations

import argparse

import numpy as np

from lidar_weather_sim.core.points import WEATHER_LABELS, Label
from lidar_weather_sim.io.recording import Recording
from lidar_weather_sim.twin.poses import points_in_map, twin_poses
from lidar_weather_sim.twin.reconstruct import distances_to_mesh

WITHIN_M = 0.1
OBJECTS = [int(Label.STATIC), int(Label.VEHICLE), int(Label.OBSTACLE)]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("bag")
    ap.add_argument("twins", nargs="+")
    args = ap.parse_args()
    import trimesh

    rec = Recording.load(args.bag)
    poses = twin_poses(rec)
    weather = [int(x) for x in WEATHER_LABELS]
    parts = {"calibration": range(0, len(rec.frames), 2), "held-out": range(1, len(rec.frames), 2)}
    print(f"| twin | triangles | {' | '.join(f'{p}: weather / objects within {WITHIN_M} m' for p in parts)} |")
    print("|---|---:|" + "---|" * len(parts))
    for twin in args.twins:
        mesh = trimesh.load(f"{twin}/mesh.ply", force="mesh", process=False)
        cells = []
        for frames in parts.values():
            xyz = np.concatenate([points_in_map(rec, i, poses)[0] for i in frames])
            label = np.concatenate([rec.frames[i].points["label"] for i in frames])
            d = distances_to_mesh(np.asarray(mesh.vertices), np.asarray(mesh.faces), xyz)
            w, o = np.isin(label, weather), np.isin(label, OBJECTS)
            cells.append(f"{np.mean(d[w] <= WITHIN_M):.3f} of {w.sum()} / {np.mean(d[o] <= WITHIN_M):.3f} of {o.sum()}")
        print(f"| {twin} | {len(mesh.faces)} | {' | '.join(cells)} |")


if __name__ == "__main__":
    main()
