"""Two source trees timed against each other: a layout change must not slow the hot paths.

Each round runs one child process per tree, alternating (old, new, old, new, ...), pinned to one CPU with
``taskset`` so both trees meet the same host. A child imports the packages of its tree only (``PYTHONPATH``
and ``LWS_WORKSPACE`` point at it) and times, after a warm-up:

- ``clear scala4``, ``clear os1_128_2048``: ``LidarSimulator.advance`` per frame on highway_clear (2 actors);
- ``highway_spray os1_128_1024``: a frame with rain and spray (region steps included), after 1 s of spray;
- ``spray step``: the particle system's step of one 40 ms frame, starting from 20 000 particles;
- ``filter``: the default weather filter on one os1_128_1024 highway_spray cloud.

It prints the fastest time of each row over its frames and, per row, the minimum over the rounds for each tree
and new / old. ``--compile`` adds a row: the wall time of ``lidar-weather-sim run highway_spray --frames 1`` on
an empty numba cache (compilation included). The trees must hold the same public entry points (World,
LidarSimulator, the spray system and the filter factory are looked up under both layouts).

    python benchmarks/performance/tree_timing.py OLD_TREE NEW_TREE [--rounds 5] [--cpu 1] [--compile]
"""

from __future__ import annotations

import argparse
import importlib
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

PACKAGES = ("lidar_weather_sim", "spray_particles", "weather_filter")


def _first(*paths: str):
    """The first ``module:attribute`` of ``paths`` that imports (the same object under two layouts)."""
    for path in paths:
        module, _, name = path.partition(":")
        try:
            return getattr(importlib.import_module(module), name)
        except (ImportError, AttributeError):
            continue
    raise ImportError(f"none of {paths} imports")


def _frames_ms(scenario: str, profile: str, frames: int, warmup_s: float) -> tuple[float, np.ndarray]:
    """Fastest ms per frame of ``frames`` frames after ``warmup_s`` simulated seconds; the last cloud."""
    from lidar_weather_sim.scenario.schema import load_scenario
    from lidar_weather_sim.scenario.world import World
    from lidar_weather_sim.sim.simulator import LidarSimulator

    world = World.build(load_scenario(scenario), profile)
    sim = LidarSimulator.of_world(world, seed=3)
    t, done, times, cloud = 0.0, -1, [], None
    start = time.perf_counter()
    while done < frames:
        t = round(t + 0.01, 9)
        produced = sim.advance(t, world.player)
        now = time.perf_counter()
        if produced:
            cloud = produced[-1].points
            if t > warmup_s:
                if done >= 0:
                    times.append((now - start) * 1e3)
                done += 1
            start = now
    return min(times), cloud


def _spray_step_ms(repeats: int, frames: int = 6) -> float:
    """Mean ms per 40 ms frame over the first ``frames`` frames of a spray system filled with 20 000 particles
    (each frame index's fastest of ``repeats`` fresh systems: the particles leave, so frames are not alike)."""
    filled_system = importlib.import_module("spray_step_time").filled_system
    best = np.full(frames, np.inf)
    for _ in range(repeats):
        system = filled_system(20000)
        for k in range(frames):
            start = time.perf_counter()
            system.advance_to((k + 1) * 0.04)
            best[k] = min(best[k], (time.perf_counter() - start) * 1e3)
    return float(best.mean())


def _filter_ms(cloud: np.ndarray, frames: int) -> float:
    make_filter = _first("weather_filter.filter_methods:make_filter", "weather_filter.filters:make_filter")
    method = _first("weather_filter.filter_methods:DEFAULT_METHOD", "weather_filter.filters:DEFAULT_METHOD")
    filt = make_filter(method)
    filt(cloud)
    times = []
    for _ in range(frames):
        start = time.perf_counter()
        filt(cloud)
        times.append((time.perf_counter() - start) * 1e3)
    return min(times)


def child(frames: int) -> dict[str, float]:
    rows = {"clear scala4": _frames_ms("highway_clear", "scala4", frames, 0.2)[0],
            "clear os1_128_2048": _frames_ms("highway_clear", "os1_128_2048", frames, 0.2)[0]}  # fmt: skip
    rows["highway_spray os1_128_1024"], cloud = _frames_ms("highway_spray", "os1_128_1024", frames, 1.0)
    rows["spray step"] = _spray_step_ms(frames)
    rows["filter"] = _filter_ms(cloud, frames)
    return rows


def _env(tree: Path) -> dict[str, str]:
    paths = [str(tree / "src" / p) for p in PACKAGES]
    env = {**os.environ, "LWS_WORKSPACE": str(tree)}
    env["PYTHONPATH"] = os.pathsep.join([*paths, env.get("PYTHONPATH", "")])
    return env


def _spray_bench_dir(tree: Path) -> Path:
    found = sorted(tree.glob("benchmarks/**/spray_step_time.py"))
    if not found:
        raise SystemExit(f"{tree}: no benchmarks/**/spray_step_time.py")
    return found[0].parent


def _run_child(tree: Path, cpu: int, frames: int) -> dict[str, float]:
    env = _env(tree)
    env["TREE_BENCHMARKS"] = str(_spray_bench_dir(tree))
    out = subprocess.run(["taskset", "-c", str(cpu), sys.executable, __file__, "--child", "--frames", str(frames)],
                         env=env, cwd=tree, capture_output=True, text=True)  # fmt: skip
    if out.returncode != 0:
        raise SystemExit(f"{tree}: the timing child failed:\n{out.stderr[-3000:]}")
    return json.loads(out.stdout.strip().splitlines()[-1])


def _compile_s(tree: Path, cpu: int) -> float:
    with tempfile.TemporaryDirectory() as cache, tempfile.TemporaryDirectory() as out:
        env = {**_env(tree), "NUMBA_CACHE_DIR": cache}
        start = time.perf_counter()
        subprocess.run(["taskset", "-c", str(cpu), sys.executable, "-m", "lidar_weather_sim.cli", "run", "highway_spray",
                        "--frames", "1", "--out", f"{out}/bag"], env=env, cwd=tree, capture_output=True, check=True)  # fmt: skip
        return time.perf_counter() - start


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("trees", nargs="*", type=Path, help="OLD_TREE NEW_TREE (repository roots)")
    ap.add_argument("--rounds", type=int, default=5)
    ap.add_argument("--frames", type=int, default=8, help="timed frames per row and child")
    ap.add_argument("--cpu", type=int, default=1, help="the CPU both trees are pinned to")
    ap.add_argument("--compile", action="store_true", help="also time a first run on an empty numba cache")
    ap.add_argument("--child", action="store_true", help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.child:  # the tree's own benchmark folder first: this script's folder may be the other tree's
        sys.path.insert(0, os.environ["TREE_BENCHMARKS"])
        print(json.dumps(child(args.frames)))
        return 0
    if len(args.trees) != 2:
        ap.error("give two trees: OLD_TREE NEW_TREE")
    old, new = (t.resolve() for t in args.trees)
    best: dict[Path, dict[str, float]] = {old: {}, new: {}}
    for k in range(args.rounds):
        for tree in (old, new) if k % 2 == 0 else (new, old):
            rows = _run_child(tree, args.cpu, args.frames)
            if args.compile:
                rows["first run, empty numba cache (s)"] = _compile_s(tree, args.cpu)
            for name, value in rows.items():
                best[tree][name] = min(best[tree].get(name, np.inf), value)
            print(f"round {k + 1} {tree.name}: " + ", ".join(f"{n} {v:.1f}" for n, v in rows.items()), flush=True)
    print(f"\n| row (ms unless stated; min of {args.rounds} rounds, CPU {args.cpu}) | {old.name} | {new.name} | new / old |")
    print("|---|---|---|---|")
    for name, value in best[old].items():
        print(f"| {name} | {value:.2f} | {best[new][name]:.2f} | {best[new][name] / value:.3f} |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
