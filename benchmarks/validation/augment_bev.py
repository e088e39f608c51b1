#!/usr/bin/env python3
"""Bird's-eye PNG of an augmented bag's frame: recorded points grey (by height), inserted obstacle points (label 3)
red, the paper's cone ROI and feature region outlined (sensor frame, m). ``--before BAG``: points of the frame
that the same frame of BAG lacks (e.g. what ``make-measured --on BAG`` put on a real recording: spray and the
car throwing it; real layouts carry no labels) blue.

Usage: python benchmarks/validation/augment_bev.py BAG --out PNG [--frame 0] [--topic /lidar/points] [--before BAG]
"""

from __future__ import annotations

import argparse
import math

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from lidar_weather_sim.core.points import Label  # noqa: E402
from lidar_weather_sim.augment.boxes import Roi, augmentation_table  # noqa: E402
from lidar_weather_sim.io.bags import read_clouds  # noqa: E402


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("bag")
    ap.add_argument("--out", required=True)
    ap.add_argument("--frame", type=int, default=0)
    ap.add_argument("--topic", default="/lidar/points")
    ap.add_argument("--before", help="bag whose frame lacks the points to draw blue")
    args = ap.parse_args()
    frame = list(read_clouds(args.bag, args.topic))[args.frame]
    p = frame.points
    obstacle = p["label"] == Label.OBSTACLE if "label" in p.dtype.names else np.zeros(len(p), bool)
    added = np.zeros(len(p), bool)
    if args.before:
        old = list(read_clouds(args.before, args.topic))[args.frame].points
        xyz = np.stack([p["x"], p["y"], p["z"]], -1)
        seen = {tuple(v) for v in np.stack([old["x"], old["y"], old["z"]], -1).tolist()}
        added = ~obstacle & np.array([tuple(v) not in seen for v in xyz.tolist()], dtype=bool)
    rest = p[~obstacle & ~added]
    fig, ax = plt.subplots(figsize=(8, 8))
    ax.scatter(rest["y"], rest["x"], s=0.3, c=rest["z"], cmap="Greys_r", vmin=-3, vmax=3)
    ax.scatter(p["y"][obstacle], p["x"][obstacle], s=3, c="red", label=f"inserted obstacle points ({obstacle.sum()})")
    if args.before:
        ax.scatter(p["y"][added], p["x"][added], s=3, c="tab:blue", label=f"not in {args.before} ({added.sum()})")
    roi = Roi.paper()
    t = math.tan(roi.half_angle_rad)
    ax.plot([roi.x_min_m * t, roi.x_max_m * t, -roi.x_max_m * t, -roi.x_min_m * t, roi.x_min_m * t],
            [roi.x_min_m, roi.x_max_m, roi.x_max_m, roi.x_min_m, roi.x_min_m], "b--", lw=1, label="cone ROI")  # fmt: skip
    region = augmentation_table()["feature_region_m"]
    ax.plot([region["y"][0], region["y"][1], region["y"][1], region["y"][0], region["y"][0]],
            [region["x"][0], region["x"][0], region["x"][1], region["x"][1], region["x"][0]], "g:", lw=1,
            label="feature region")  # fmt: skip
    ax.set_xlim(15, -15)  # y to the left, as seen from above with x up
    ax.set_ylim(-2, 28)
    ax.set_aspect("equal")
    ax.set_xlabel("y (m, left +)")
    ax.set_ylabel("x (m, forward)")
    ax.set_title(f"{args.bag}, frame {args.frame}")
    ax.legend(loc="lower right")
    fig.savefig(args.out, dpi=120)
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
