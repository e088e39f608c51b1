#!/usr/bin/env python3
"""The Dask engine against one-after-another loops of the same work, on this machine.

    python benchmarks/performance/sweep_engine.py sweep [--runs 40 --frames 10]   # lidar-weather-sim sweep: serial, 1, 2 workers
    python benchmarks/performance/sweep_engine.py train-data [--specs 8]          # weather-filter training runs: serial vs 2 workers
    python benchmarks/performance/sweep_engine.py gap [--frames 200 --hide EFFECT]  # gap search on a 200-frame recording: serial vs 2

``sweep`` runs the same runs (highway_spray, scala4, fog visual ranges x seeds, ``compute: [stats]``)
three times into fresh directories: ``--workers 0`` (the serial loop in one process, the simulator on
all cores: what a loop of ``lidar-weather-sim run`` does today, without its start-ups), then a
LocalCluster of 1 and of 2 single-threaded workers. The engine's overhead per run is the wall time
of the 1-worker sweep less the runs' own time (measured inside each run), over the runs: cluster
start, warm-up, dispatch, result transfer and row writing. From it and the mean single-threaded run
time it estimates a 1000-run sweep on 32 workers (no measurement: a paper estimate, stated as such).
Prints the machine's load average: the figures mean little on a busy machine.
"""

from __future__ import annotations

import argparse
import csv
import os
import shutil
import tempfile
import time
from pathlib import Path

import yaml


def _load() -> str:
    return " ".join(f"{v:.2f}" for v in os.getloadavg())


def bench_sweep(args: argparse.Namespace) -> None:
    from lidar_weather_sim.sweep.command import run_sweep

    seeds = 4
    values = [round(30 * (500 / 30) ** (k / (args.runs // seeds - 1)), 1) for k in range(args.runs // seeds)]
    tmp = Path(tempfile.mkdtemp(prefix="sweep-bench-"))
    spec = tmp / "sweep.yaml"
    spec.write_text(yaml.safe_dump({"scenario": "highway_spray", "frames": args.frames, "profile": "scala4",
                                    "seeds": list(range(1, seeds + 1)), "grid": {"weather.fog.visual_range_m": values},
                                    "compute": ["stats"]}))  # fmt: skip
    print(f"{len(values) * seeds} runs of {args.frames} scala4 frames (highway_spray, fog {values[0]}-{values[-1]} m "
          f"x {seeds} seeds), {os.cpu_count()} CPUs, load {_load()}")  # fmt: skip
    results = {}
    for label, workers in (("serial loop (--workers 0, 2 threads)", 0), ("engine, 1 worker", 1), ("engine, 2 workers", 2)):
        out = tmp / f"w{workers}"
        report = run_sweep(spec, out, workers=workers)
        with open(report.results, newline="") as f:
            rows = list(csv.DictReader(f))
        run_time = sum(float(r["elapsed_s"]) for r in rows)
        results[workers] = (report.wall_s, run_time, rows)
        print(f"  {label:38s} wall {report.wall_s:7.1f} s   runs' own time {run_time:7.1f} s   "
              f"({report.failed} failed; load {_load()})")  # fmt: skip
    (w0, _, rows0), (w1, t1, rows1), (w2, _, rows2) = results[0], results[1], results[2]
    same = all([{k: v for k, v in r.items() if k != "elapsed_s"} for r in rows] ==
               [{k: v for k, v in r.items() if k != "elapsed_s"} for r in rows0] for rows in (rows1, rows2))  # fmt: skip
    n = len(rows0)
    overhead = (w1 - t1) / n
    mean_run = t1 / n
    print(f"  rows identical in all three: {same}")
    print(f"  speed-up of 2 workers over the serial loop: {w0 / w2:.2f}x; over 1 worker: {w1 / w2:.2f}x")
    print(f"  engine overhead per run (1 worker: wall - runs' own time, / runs): {overhead:.3f} s")
    estimate = 10.0 + 1000 * (mean_run + overhead) / 32
    print(f"  paper estimate, 1000 such runs on 32 single-threaded workers: 10 s start + 1000 x ({mean_run:.2f} s + "
          f"{overhead:.2f} s) / 32 = {estimate:.0f} s (serial loop here: {1000 * w0 / n:.0f} s)")  # fmt: skip
    shutil.rmtree(tmp)


def bench_train_data(args: argparse.Namespace) -> None:
    from weather_filter.simdata import TRAIN_SPECS, simulate_all

    specs = list(TRAIN_SPECS[: args.specs])
    print(f"weather-filter training runs: the first {len(specs)} of TRAIN_SPECS ({', '.join(specs)}), load {_load()}")
    for label, workers in (("before: one after another (today's train)", 0), ("after: --workers 2", 2)):
        cache = Path(tempfile.mkdtemp(prefix="wf-bench-"))
        start = time.perf_counter()
        simulate_all(specs, cache, workers=workers)
        wall = time.perf_counter() - start
        print(f"  {label:44s} {wall:7.1f} s   (load {_load()})")
        shutil.rmtree(cache)


def bench_gap(args: argparse.Namespace) -> None:
    from lidar_weather_sim.gap.command import run_gap
    from lidar_weather_sim.scenario.effects import parse_effect
    from lidar_weather_sim.references.measured import case_scenario, make_measured
    from lidar_weather_sim.scenario.schema import load_scenario

    hidden = args.hide or ["atmosphere.rain:intensity=10", "cover.dirt:transmission=0.75"]
    scenario = case_scenario(load_scenario("highway_clear"), hidden)
    tmp = Path(tempfile.mkdtemp(prefix="gap-bench-"))
    make_measured(scenario, [parse_effect(h) for h in hidden], tmp / "measured", frames=args.frames)
    print(f"gap on {args.frames} scala4 frames of highway_clear with {' + '.join(hidden)} hidden (default budgets), "
          f"load {_load()}")  # fmt: skip
    found = {}
    for label, workers in (("in this process (--workers 0)", 0), ("2 forked copies (the default here)", 2)):
        start = time.perf_counter()
        result = run_gap(tmp / "measured", scenario, tmp / f"gap{workers}", workers=workers)
        wall = time.perf_counter() - start
        found[workers] = result
        effects = ", ".join(f"{e['name']} {e['params']}{'' if e['named'] else ' (not named)'}"
                            for e in result["effects"]) or "nothing"  # fmt: skip
        print(f"  {label:40s} {wall:7.1f} s   gap {result['gap_before']:.4f} -> {result['gap_after']:.4f}: {effects} "
              f"(load {_load()})")  # fmt: skip
    print(f"  same diagnosis: {found[0] == found[2]}")
    shutil.rmtree(tmp)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    jobs = parser.add_subparsers(dest="job", required=True)
    sweep = jobs.add_parser("sweep")
    sweep.add_argument("--runs", type=int, default=40, help="runs (a multiple of the 4 seeds)")
    sweep.add_argument("--frames", type=int, default=10)
    sweep.set_defaults(func=bench_sweep)
    train = jobs.add_parser("train-data")
    train.add_argument("--specs", type=int, default=8, help="the first N runs of weather_filter.simdata.TRAIN_SPECS")
    train.set_defaults(func=bench_train_data)
    gap = jobs.add_parser("gap")
    gap.add_argument("--frames", type=int, default=200)
    gap.add_argument("--hide", action="append", help="an effect to hide (repeatable; default: issue 50's speed case, "
                     "rain 10 mm/h behind dirt 0.75)")  # fmt: skip
    gap.set_defaults(func=bench_gap)
    args = parser.parse_args()
    args.func(args)


if __name__ == "__main__":  # the engine's workers are spawned: they import this file without running it
    main()
