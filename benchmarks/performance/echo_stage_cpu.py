"""CPU time of the echo stage alone on the inputs of one simulated frame per weather row, with the volume's echoes
shared per group of beams (the default) and with every beam sampled on its own (``shared_prefix=False``).

Each row of ``weather_frame_time.py`` (highway_clear + 10 vehicles) is simulated for ``--warmup-s`` plus one
frame; the last frame's calls of :func:`~lidar_weather_sim.sensor.echo.detect_echoes` that carry volume tables are
kept and run again ``--repeats`` times on one thread (``LWS_SIM_THREADS=1`` is set here), CPU time (process time),
the fastest repeat printed, with the beams of the frame split by where their hard target is (none: sky; in front of
``--near-m``; behind it). Both paths give the same echoes (``test_volume_prefix.py``); this prints what the sharing
saves.

    python benchmarks/performance/echo_stage_cpu.py [--profile os1_128_2048] [--rows "fog 50m,rain 10,snow 5,target"]
"""

from __future__ import annotations

import argparse
import os

os.environ["LWS_SIM_THREADS"] = "1"  # before the simulator's thread pool is sized

import time  # noqa: E402

import numpy as np  # noqa: E402
from sim_frame_time import ten_vehicles  # noqa: E402
from weather_frame_time import row_specs, variant  # noqa: E402

from lidar_weather_sim.scenario.schema import load_scenario  # noqa: E402
from lidar_weather_sim.scenario.world import World  # noqa: E402
from lidar_weather_sim.sensor import echo  # noqa: E402
from lidar_weather_sim.sim import simulator  # noqa: E402
from lidar_weather_sim.sim.simulator import LidarSimulator  # noqa: E402


def frame_calls(row: str, profile: str, warmup_s: float) -> list[tuple[tuple, dict]]:
    """The (arguments, keywords) of one whole frame's echo-stage calls with volume tables, segments applied."""
    world = World.build(variant(ten_vehicles(load_scenario("highway_clear")), row_specs("3l")[row]), profile)
    sim = LidarSimulator.of_world(world)
    calls: list[tuple[tuple, dict]] = []
    detect = simulator.detect_echoes

    def keep(*args, **kwargs):
        if kwargs.get("volume") is not None:
            starts, counts = kwargs["segments"]
            take = np.concatenate([np.arange(a, a + c) for a, c in zip(starts, counts)] + [np.zeros(0, np.int64)])
            calls.append((tuple(np.asarray(x)[take] for x in args),
                          {k: v for k, v in kwargs.items() if k not in ("scratch", "segments")}))  # fmt: skip
        return detect(*args, **kwargs)

    simulator.detect_echoes = keep
    try:
        t = 0.0
        while t < warmup_s:
            t = round(t + 0.01, 9)
            sim.advance(t, world.player)
        for frame in range(2):  # the end of the frame under way, then a whole frame
            calls.clear()
            done = []
            while not done:
                t = round(t + 0.01, 9)
                done = sim.advance(t, world.player)
    finally:
        simulator.detect_echoes = detect
    return calls


def cpu_ms(calls, repeats: int, shared: bool) -> float:
    """The fastest of ``repeats`` runs of ``calls`` (ms of process time)."""
    for args, kwargs in calls:  # compile, warm the caches
        echo.detect_echoes(*args, shared_prefix=shared, **kwargs)
    best = np.inf
    for _ in range(repeats):
        t0 = time.process_time()
        for args, kwargs in calls:
            echo.detect_echoes(*args, shared_prefix=shared, **kwargs)
        best = min(best, time.process_time() - t0)
    return 1e3 * best


def only(calls, beams_of) -> list[tuple[tuple, dict]]:
    """``calls`` with the volume layers and candidates of the beams ``beams_of(volume)`` (bool per beam) only."""
    out = []
    for args, kwargs in calls:
        volume = kwargs["volume"]
        keep = beams_of(volume)
        rows = keep[args[0]]
        table = np.where(keep[:, None], volume.table, -1)
        out.append((tuple(x[rows] for x in args), {**kwargs, "volume": volume._replace(table=table)}))
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--profile", default="os1_128_2048")
    parser.add_argument("--rows", default="fog 50m,rain 10,snow 5,target")
    parser.add_argument("--warmup-s", type=float, default=0.3)
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--near-m", type=float, default=13.7, help="split of the beams by hard target range (m)")
    args = parser.parse_args()
    print(f"{args.profile}: echo stage CPU ms per frame, one thread, fastest of {args.repeats}")
    print(f"{'row':>12} {'part':>10} {'beams':>8} {'shared ms':>10} {'alone ms':>9} {'us/beam':>8}")
    for row in [r.strip() for r in args.rows.split(",") if r.strip()]:
        calls = frame_calls(row, args.profile, args.warmup_s)
        hit = lambda v: v.hit_m.min(axis=1)  # noqa: E731
        parts = {"all": lambda v: np.ones(len(v.table), bool), "sky": lambda v: ~np.isfinite(hit(v)),
                 "near": lambda v: np.isfinite(hit(v)) & (hit(v) < args.near_m),
                 "far": lambda v: np.isfinite(hit(v)) & (hit(v) >= args.near_m)}  # fmt: skip
        for name, beams_of in parts.items():
            part = calls if name == "all" else only(calls, beams_of)
            beams = sum(int(beams_of(k["volume"]).sum()) for _, k in calls)
            shared, alone = cpu_ms(part, args.repeats, True), cpu_ms(part, args.repeats, False)
            per = 1e3 * shared / max(beams, 1)
            print(f"{row:>12} {name:>10} {beams:>8} {shared:>10.1f} {alone:>9.1f} {per:>8.2f}", flush=True)


if __name__ == "__main__":
    main()
