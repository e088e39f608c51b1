"""Frame time of the virtual LiDAR (``LidarSimulator.advance``) per sensor profile and backend.

Scenario ``highway_clear`` (ego at 89 km/h, 2 actors) and a variant with 10
moving vehicles (8 more in the three lanes, ahead and behind, 18-34 m/s). The
ego's player is the pose source, so pose evaluation is part of the frame time.
``advance`` is called ``--steps`` times per frame period, the last time at the
frame's last column (default 1: one call casts a whole frame, in one batch; calls
at multiples of the period would cast all but the first column of a frame and the
first column of the next, two batches). Per row: median ms per frame over
``--frames`` frames after ``--warmup`` frames (numba compilation, Mitsuba JIT) and
the fastest ("min ms": on a shared machine the least disturbed); Mrays/s of the whole pipeline;
"cast ms": time spent inside the backend's mesh casts (static mesh and actors,
the same rays the simulator casts, timed around each backend call); "other ms" =
frame - cast (poses, rotation, culling, echoes, points); overhead = frame / cast;
points per frame. ``--threads`` sets the simulator's kernel threads
(:mod:`lidar_weather_sim.core.workers`; 1 = single-threaded kernels).

    python benchmarks/performance/sim_frame_time.py [--frames N] [--backend B] [--profiles a,b] [--steps K] [--threads T]
"""

from __future__ import annotations

import argparse
import importlib.metadata
import os
import subprocess
import time
from pathlib import Path

import numpy as np

from lidar_weather_sim.scenario.schema import Actor, load_scenario
from lidar_weather_sim.scenario.world import World
from lidar_weather_sim.scene.raycast import available_backends
from lidar_weather_sim.sim.simulator import LidarSimulator

try:
    from lidar_weather_sim.core import workers
except ImportError:  # a revision before the kernels' thread pool: single-threaded
    workers = None

PROFILES = ("scala4", "vlp16", "hdl64e", "os1_128_2048")


def ten_vehicles(scenario):
    """``scenario`` plus 8 vehicles (ids 102-109) in lanes -1..-3 at various s and speeds."""
    extra = [
        Actor(id=102 + i, road="1", lane=lane, s_m=s, speed_m_s=v)
        for i, (lane, s, v) in enumerate([(-1, 30.0, 27.0), (-1, 110.0, 30.0), (-2, 20.0, 26.0), (-2, 95.0, 22.0),
                                          (-3, 40.0, 20.0), (-3, 75.0, 18.0), (-3, 160.0, 23.0), (-1, 150.0, 34.0)])
    ]  # fmt: skip
    return scenario.model_copy(update={"name": scenario.name + "+10", "actors": list(scenario.actors) + extra})


class Timed:
    """Wraps a MeshCaster; accumulates the seconds (of ``timer``) spent in its ``cast``."""

    def __init__(self, inner, clock: list[float], timer=time.perf_counter) -> None:
        self.inner, self.clock, self.timer = inner, clock, timer

    def cast(self, o, d):
        t0 = self.timer()
        out = self.inner.cast(o, d)
        self.clock[0] += self.timer() - t0
        return out


def instrument(sim: LidarSimulator, timer=time.perf_counter) -> list[float]:
    """Time the backend casts of ``sim``'s caster with ``timer``: the returned one-element list accumulates."""
    clock = [0.0]
    sc = sim.caster
    sc._static = type(sc._static)(**{**sc._static.__dict__, "caster": Timed(sc._static.caster, clock, timer)})
    sc._actors = {k: type(p)(**{**p.__dict__, "caster": Timed(p.caster, clock, timer)}) for k, p in sc._actors.items()}
    return clock


def run(world: World, backend: str, frames: int, warmup: int, steps: int) -> dict:
    sim = LidarSimulator(world.profile, world.scene, backend=backend, seed=world.scenario.seed)
    clock = instrument(sim)
    period = world.profile.period_s
    last_column_s = float(sim.pattern.column_time_s[-1]) + 1e-7  # as LidarSimulator.cast_frame
    rows, t, k = [], 0.0, 0
    sim.advance(0.0, world.player)
    while len(rows) < warmup + frames:
        clock[0], spent, done = 0.0, 0.0, []
        for _ in range(steps):
            k += 1
            t = k * period / steps + last_column_s
            t0 = time.perf_counter()
            done += sim.advance(t, world.player)
            spent += time.perf_counter() - t0
        if done:
            rows.append((spent, clock[0], done[-1].rays, len(done[-1].points)))
    timed = np.array(rows[warmup:])
    frame, cast, rays, points = np.median(timed, axis=0)
    return {"ms": frame * 1e3, "min": timed[:, 0].min() * 1e3, "cast": cast * 1e3, "rays": rays, "points": points}


def versions() -> str:
    found = []
    for n in ("numpy", "numba", "open3d-cpu", "open3d", "mitsuba", "drjit", "embreex"):
        try:
            found.append(f"{n} {importlib.metadata.version(n)}")
        except importlib.metadata.PackageNotFoundError:
            pass
    root = Path(__file__).resolve().parents[2]
    try:
        rev = subprocess.run(["git", "-C", str(root), "rev-parse", "--short", "HEAD"], capture_output=True, text=True,
                             check=True).stdout.strip()  # fmt: skip
        dirty = subprocess.run(["git", "-C", str(root), "status", "--porcelain", "--untracked-files=no"],
                               capture_output=True, text=True).stdout.strip()  # fmt: skip
        rev += " (modified)" if dirty else ""
    except (OSError, subprocess.CalledProcessError):
        rev = "unknown"
    return f"{', '.join(found)}; git {rev}; {os.cpu_count()} cpus"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--frames", type=int, default=10, help="timed frames per row (median)")
    ap.add_argument("--warmup", type=int, default=3, help="frames before timing")
    ap.add_argument("--backend", action="append", help="backend(s) to time (default: all available)")
    ap.add_argument("--profiles", default=",".join(PROFILES), help="comma-separated sensor profiles")
    ap.add_argument("--steps", type=int, default=1, help="advance() calls per frame period")
    ap.add_argument("--scenario", default="highway_clear")
    ap.add_argument("--threads", type=int, help="worker threads of the simulator's kernels (default: all CPUs)")
    args = ap.parse_args()
    if args.threads and workers is not None:
        workers.THREADS = args.threads
    backends = args.backend or available_backends()
    base = load_scenario(args.scenario)
    print(versions())
    print(f"{args.scenario}: median of {args.frames} frames after {args.warmup}, {args.steps} advance() per period, "
          f"{workers.THREADS if workers else 1} kernel threads")  # fmt: skip
    cols = [("profile", 13), ("actors", 6), ("backend", 8), ("ms/frame", 9), ("min ms", 7), ("Mrays/s", 8),
            ("cast ms", 8), ("other ms", 9), ("overhead", 8), ("rays", 8), ("points", 8)]  # fmt: skip
    print(" ".join(f"{name:>{width}}" for name, width in cols))
    for scenario in (base, ten_vehicles(base)):
        for profile in args.profiles.split(","):
            world = World.build(scenario, profile)
            for backend in backends:
                r = run(world, backend, args.frames, args.warmup, args.steps)
                values = [profile, len(scenario.actors), backend, f"{r['ms']:.2f}", f"{r['min']:.2f}",
                          f"{r['rays'] / r['ms'] / 1e3:.2f}", f"{r['cast']:.2f}", f"{r['ms'] - r['cast']:.2f}",
                          f"{r['ms'] / max(r['cast'], 1e-9):.2f}", int(r["rays"]), int(r["points"])]  # fmt: skip
                print(" ".join(f"{v:>{width}}" for v, (_, width) in zip(values, cols)), flush=True)


if __name__ == "__main__":
    main()
