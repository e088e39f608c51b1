"""Hashes of the clouds of the weather rows, to show a change left them bit-identical.

Each row of ``weather_frame_time.py`` (highway_clear with 10 vehicles) on ``--profile``, simulated for ``--frames`` frames at ``--seed`` on the Open3D backend: the row's point count and the
first 16 hex digits of the SHA-256 of its clouds' bytes. Run it before and after a change and diff the output.

    python benchmarks/performance/cloud_hashes.py [--profile scala4] [--rows "clear,fog 50m,rain 10,snow 5,target"]
        [--frames 4] [--seed 3]
"""

from __future__ import annotations

import argparse
import hashlib

from sim_frame_time import ten_vehicles
from weather_frame_time import row_specs, variant

from lidar_weather_sim.scenario.schema import load_scenario
from lidar_weather_sim.scenario.world import World
from lidar_weather_sim.sim.simulator import LidarSimulator


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--profile", default="scala4")
    parser.add_argument("--rows", default="clear,fog 50m,rain 10,snow 5,target")
    parser.add_argument("--frames", type=int, default=4)
    parser.add_argument("--seed", type=int, default=3)
    args = parser.parse_args()
    specs = row_specs("3l")
    base = ten_vehicles(load_scenario("highway_clear"))
    for name in args.rows.split(","):
        world = World.build(variant(base, specs[name]), args.profile)
        sim = LidarSimulator.of_world(world, backend="open3d", seed=args.seed)
        digest, t, frames, points = hashlib.sha256(), 0.0, 0, 0
        while frames < args.frames:
            t = round(t + 0.01, 9)
            for frame in sim.advance(t, world.player):
                frames += 1
                points += len(frame.points)
                digest.update(frame.points.tobytes())
        print(f"{args.profile} {name}: {points} points {digest.hexdigest()[:16]}", flush=True)


if __name__ == "__main__":
    main()
