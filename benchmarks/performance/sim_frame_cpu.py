"""CPU time per frame of ``LidarSimulator.advance`` over many frames, for A/B comparisons on a busy machine.

Like ``sim_frame_time.py`` (scenario ``highway_clear`` with 2 actors or its 10-vehicle
variant, one ``advance`` per frame period, the player as pose source), but the simulator
restarts every ``--sequence`` frames (the same first frames of the scenario again and
again, so every frame is a realistic one) and times each call with ``time.process_time``
(CPU seconds of all threads, ms): the least disturbed frames of many ("min") are a stable
figure on a shared machine, medians need interleaved runs. "other" = frame - the CPU time
inside the backend's mesh casts. Cases are ``profile:backend:actors``; compare two trees by
running it alternately with each on PYTHONPATH (pin both to one core: ``taskset -c 1``).

    python benchmarks/performance/sim_frame_cpu.py [--frames N] [--sequence K] scala4:mitsuba:2 os1_128_2048:open3d:10 ...
"""

from __future__ import annotations

import argparse
import time

import numpy as np
from sim_frame_time import instrument, ten_vehicles

from lidar_weather_sim.scenario.schema import load_scenario
from lidar_weather_sim.scenario.world import World
from lidar_weather_sim.sim.simulator import LidarSimulator


def run(case: str, frames: int, sequence: int) -> np.ndarray:
    """(frames, 2) CPU ms of each timed frame and of its part outside the backend casts."""
    profile, backend, actors = case.split(":")
    scenario = load_scenario("highway_clear")
    world = World.build(ten_vehicles(scenario) if actors == "10" else scenario, profile)
    sim = LidarSimulator(world.profile, world.scene, backend=backend, seed=world.scenario.seed)
    clock = instrument(sim, time.process_time)
    period, last = world.profile.period_s, float(sim.pattern.column_time_s[-1]) + 1e-7
    rows = []
    for k in range(-sequence, frames):  # the first sequence warms up (numba, Dr.Jit kernels)
        if k % sequence == 0 or k == -sequence:
            sim.restart()
            sim.advance(0.0, world.player)
        clock[0] = 0.0
        t0 = time.process_time()
        sim.advance((k % sequence + 1) * period + last, world.player)
        spent = time.process_time() - t0
        if k >= 0:
            rows.append((spent * 1e3, (spent - clock[0]) * 1e3))
    return np.array(rows)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("cases", nargs="+", help="profile:backend:actors (actors 2 or 10)")
    ap.add_argument("--frames", type=int, default=600, help="timed frames per case")
    ap.add_argument("--sequence", type=int, default=30, help="frames between restarts")
    args = ap.parse_args()
    for case in args.cases:
        a = run(case, args.frames, args.sequence)
        print(f"{case:24s} frame min {a[:, 0].min():7.3f} med {np.median(a[:, 0]):7.3f} | "
              f"other min {a[:, 1].min():7.3f} med {np.median(a[:, 1]):7.3f} ms", flush=True)  # fmt: skip


if __name__ == "__main__":
    main()
