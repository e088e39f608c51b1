"""Frame time with weather: every region on its own and all together, next to the clear frame, per stage.

The scene is ``highway_clear`` with 10 vehicles (``sim_frame_time.ten_vehicles``); the car ahead
(actor 100, 17.5 m ahead in the left lane) throws spray when a row has spray. The rows of one
profile run interleaved in one invocation: after a warm-up of ``--warmup-s`` simulated seconds each
(spray builds up, numba compiles), round k advances every row by one frame, so host load falls on all
rows alike. ``advance`` is called every ``--step-s`` of simulated time, as ``lidar-weather-sim run``
does (10 ms), so region stepping (particles) is part of the frame.

Rows: clear; cover (dirt sample ``--dirt``); fog 50 m; rain 2 / 10 / 50 mm/h; fog 50 m + rain 10 mm/h; snow 1 / 5 mm/h;
spray at 16 / 32 / 64 drop packets per wheel per tick (water film 0.7 mm, dry air); ``target``
(every region on: rain 10 mm/h + spray 32 + dirty cover, the speed target of the weather path). Per row: median ms per frame and its ratio to the clear row of the same run; the
median ms of each stage (region step, region apply, cast, candidates, occlusion, echoes, points;
``other``: poses, rays, false alarms, bookkeeping); scatterers the regions returned per frame and
points per frame. Stages are timed on the thread that runs them: where the simulator applies regions side
by side and detects a batch behind the next one's cast (large batches, ``PARALLEL_MIN_RAYS``) they overlap,
their sum exceeds the frame and ``other`` comes out negative. Per profile, a least-squares line of each stage's ms over the scatterers per
frame (all weather rows): how each grows with what is in the air.

    python benchmarks/performance/weather_frame_time.py [--profiles scala4,vlp16,hdl64e,os1_128_2048] [--frames N]
        [--backend B] [--rows clear,target,...] [--step-s S] [--warmup-s S] [--hard-echoes-only]

``--hard-echoes-only`` is a floor, not the product: in the rows with an atmosphere (a volume) the echo stage gets
the scene's hard returns alone (no scatterers, no volume), so such a row costs its regions, casts, candidates and
occlusion but no more echo work than a clear frame: what the echo stage's weather work could save at most.
"""

from __future__ import annotations

import argparse
import time
from collections import defaultdict

import numpy as np
from sim_frame_time import PROFILES, ten_vehicles, versions

from lidar_weather_sim.core import workers
from lidar_weather_sim.core.points import Label
from lidar_weather_sim.scenario.schema import load_scenario
from lidar_weather_sim.scenario.world import World
from lidar_weather_sim.scene.raycast import available_backends
from lidar_weather_sim.sim import simulator
from lidar_weather_sim.sim.kernels import compact_candidates
from lidar_weather_sim.sim.simulator import LidarSimulator

STAGES = ("step", "apply", "cast", "candidates", "occlusion", "echoes", "points")
LEAD = 100  # the car ahead in highway_clear
DRY = {"fog": {"visual_range_m": 100000.0}, "precipitation": {"type": "dry", "intensity_mm_h": 0.0}}


def row_specs(dirt: str) -> dict[str, dict]:
    """Row name -> (weather, regions, region_params, spray packets) of the scenario variant."""
    film = {"water_film_mm": 0.7}

    def spray(packets: float) -> dict:
        return {"spray": {"mist_packets_per_wheel_per_tick": packets, "wind_over_speed": 1.0}}

    rain10 = {"precipitation": {"type": "rain", "intensity_mm_h": 10.0}}
    cover = {"cover": {"texture": dirt}}
    return {
        "clear": dict(weather=DRY, regions=[]),
        "cover": dict(weather=DRY, regions=["cover"], params=cover),
        "fog 50m": dict(weather={**DRY, "fog": {"visual_range_m": 50.0}}, regions=["atmosphere"]),
        **{f"rain {r:g}": dict(weather={**DRY, "precipitation": {"type": "rain", "intensity_mm_h": r}},
                               regions=["atmosphere"]) for r in (2.0, 10.0, 50.0)},
        "fog 50m + rain 10": dict(weather={**DRY, "fog": {"visual_range_m": 50.0}, **rain10}, regions=["atmosphere"]),
        **{f"snow {r:g}": dict(weather={**DRY, "precipitation": {"type": "snow", "intensity_mm_h": r}},
                               regions=["atmosphere"]) for r in (1.0, 5.0)},
        **{f"spray {k}": dict(weather={**DRY, "road": film}, regions=["spray"], params=spray(k), emits=True)
           for k in (16, 32, 64)},
        "target": dict(weather={**DRY, **rain10, "road": film}, regions=["cover", "atmosphere", "spray"],
                       params={**cover, **spray(32)}, emits=True),
    }  # fmt: skip


def variant(base, spec: dict):
    """``base`` (highway_clear + 10 vehicles) with the row's weather, regions and spray emitter."""
    data = base.model_dump()
    for key, value in spec["weather"].items():
        data["weather"][key] = {**data["weather"].get(key, {}), **value}
    data["regions"] = spec["regions"]
    data["region_params"] = dict(spec.get("params", {}))
    for actor in data["actors"]:
        actor["emits_spray"] = bool(spec.get("emits")) and actor["id"] == LEAD
    return type(base).model_validate(data)


class StageClock:
    """Wraps the simulator's stage methods and its regions' step/apply on the instance; seconds per
    stage and scatterers returned accumulate until :meth:`take`."""

    def __init__(self, sim: LidarSimulator) -> None:
        self.spent: dict[str, float] = defaultdict(float)
        self.scatterers = 0
        for stage, method in (("cast", "_cast_rays"), ("candidates", "_candidates"), ("occlusion", "_occlusion"),
                              ("echoes", "_echoes"), ("points", "_points")):  # fmt: skip
            setattr(sim, method, self._timed(stage, getattr(sim, method)))
        for _, region in sim.regions:
            region.step = self._timed("step", region.step)
            region.apply = self._timed("apply", region.apply, count=True)

    def _timed(self, stage: str, fn, count: bool = False):
        def wrapper(*args, **kwargs):
            t0 = time.perf_counter()
            out = fn(*args, **kwargs)
            self.spent[stage] += time.perf_counter() - t0
            if count and out.scatterers is not None:
                self.scatterers += len(out.scatterers.beam)
            return out

        return wrapper

    def take(self) -> tuple[dict[str, float], int]:
        spent, scatterers = dict(self.spent), self.scatterers
        spent["candidates"] = spent.get("candidates", 0.0) - spent.get("occlusion", 0.0)  # occlusion runs inside
        self.spent.clear()
        self.scatterers = 0
        return spent, scatterers


class Row:
    """One row's simulator, advanced frame by frame on its own clock."""

    def __init__(self, name: str, world: World, backend: str, step_s: float) -> None:
        self.name, self.world, self.step_s = name, world, step_s
        self.sim = LidarSimulator.of_world(world, backend=backend)
        self.clock = StageClock(self.sim)
        self.t = 0.0
        self.samples: list[tuple[float, dict, int, int]] = []  # (s, stage s, scatterers, points)

    def frame(self, record: bool) -> None:
        """Advance until one frame completes; record its wall time and stages if ``record``."""
        done, t0 = [], time.perf_counter()
        while not done:
            self.t = round(self.t + self.step_s, 9)
            done = self.sim.advance(self.t, self.world.player)
        spent = time.perf_counter() - t0
        stages, scatterers = self.clock.take()
        if record:
            self.samples.append((spent, stages, scatterers, len(done[-1].points)))

    def summary(self) -> dict:
        s = self.samples
        out = {"ms": 1e3 * np.median([x[0] for x in s]), "min": 1e3 * min(x[0] for x in s),
               "scatterers": np.mean([x[2] for x in s]), "n_points": np.mean([x[3] for x in s])}  # fmt: skip
        for stage in STAGES:
            out[stage] = 1e3 * np.median([x[1].get(stage, 0.0) for x in s])
        out["other"] = out["ms"] - sum(out[stage] for stage in STAGES)
        return out


def bench_profile(profile: str, rows: list[str], specs: dict, backend: str, frames: int, warmup_s: float,
                  step_s: float) -> None:  # fmt: skip
    base = ten_vehicles(load_scenario("highway_clear"))
    clear_world = World.build(variant(base, specs["clear"]), profile)
    live = []
    for name in rows:
        world = clear_world if name == "clear" else World.build(variant(base, specs[name]), profile)
        world._casters = getattr(clear_world, "_casters", {})  # one scene cast for all rows
        live.append(Row(name, world, backend, step_s))
    period = clear_world.profile.period_s
    for row in live:
        while row.t < warmup_s:
            row.frame(record=False)
    for _ in range(frames):
        for row in live:
            row.frame(record=True)
    results = {row.name: row.summary() for row in live}
    clear_ms = results["clear"]["ms"] if "clear" in results else float("nan")
    cols = [("profile", 13), ("row", 17), ("ms/frame", 9), ("min ms", 7), ("x clear", 7)] + \
           [(s, 10 if s == "candidates" else 9) for s in (*STAGES, "other")] + [("scatterers", 10), ("n points", 8)]  # fmt: skip
    print(f"\n{profile}: {backend}, {1e3 * period:.0f} ms period, advance every {1e3 * step_s:.0f} ms, "
          f"median of {frames} frames after {warmup_s:g} s, {workers.THREADS} kernel threads")  # fmt: skip
    print(" ".join(f"{name:>{width}}" for name, width in cols))
    for name, r in results.items():
        values = [profile, name, f"{r['ms']:.2f}", f"{r['min']:.2f}", f"{r['ms'] / clear_ms:.2f}",
                  *(f"{r[s]:.2f}" for s in (*STAGES, "other")), f"{r['scatterers']:.0f}", f"{r['n_points']:.0f}"]  # fmt: skip
        print(" ".join(f"{v:>{width}}" for v, (_, width) in zip(values, cols)), flush=True)
    weather = [r for name, r in results.items() if name != "clear"]
    if len(weather) >= 3:
        x = np.array([r["scatterers"] for r in weather])
        slopes = []
        for stage in ("apply", "candidates", "occlusion", "echoes", "points"):
            slope, _ = np.polyfit(x, [r[stage] for r in weather], 1)
            slopes.append(f"{stage} {1e3 * slope:.3f}")
        print(f"{profile}: ms per 1000 scatterers per frame (least squares over the weather rows): {', '.join(slopes)}")


def _hard_echoes_only(detect):
    """``detect`` (:func:`~lidar_weather_sim.sensor.echo.detect_echoes`) on the candidates labelled static or
    vehicle alone and without the volume, for the batches that carry a volume (the atmosphere's rows, ``target``):
    what a frame costs when the weather adds nothing to the echo stage. Other batches (clear, cover, spray) as
    they are."""

    def hard(beam, range_m, amplitude, label, object_id, **kwargs):
        if kwargs.pop("volume", None) is None:
            return detect(beam, range_m, amplitude, label, object_id, **kwargs)
        segments = kwargs.pop("segments", None)
        arrays = (beam, range_m, amplitude, label, object_id)
        if segments is not None:
            arrays = compact_candidates(arrays, segments)
        keep = (arrays[3] == Label.STATIC) | (arrays[3] == Label.VEHICLE)
        return detect(*(x[keep] for x in arrays), **kwargs)

    return hard


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--profiles", default=",".join(PROFILES))
    ap.add_argument("--frames", type=int, default=10, help="timed frames per row (median)")
    ap.add_argument("--warmup-s", type=float, default=1.0, help="simulated seconds per row before timing")
    ap.add_argument("--step-s", type=float, default=0.01, help="simulated seconds between advance() calls")
    ap.add_argument("--backend", help="raycast backend (default: the first available, the fastest)")
    ap.add_argument("--dirt", default="3l", help="cover sample of the dirty cover (config/cover/samples.yaml)")
    ap.add_argument("--rows", help="comma-separated rows (default: all)")
    ap.add_argument("--hard-echoes-only", action="store_true",
                    help="a floor, not the product: in rows with an atmosphere the echo stage gets the scene's hard "
                         "returns alone, without scatterers or volume; the regions drawn as usual")  # fmt: skip
    args = ap.parse_args()
    if args.hard_echoes_only:
        simulator.detect_echoes = _hard_echoes_only(simulator.detect_echoes)
    specs = row_specs(args.dirt)
    rows = args.rows.split(",") if args.rows else list(specs)
    unknown = sorted(set(rows) - set(specs))
    if unknown:
        ap.error(f"--rows: unknown {unknown}; choose from {list(specs)}")
    backend = args.backend or available_backends()[0]
    print(versions())
    if args.hard_echoes_only:
        print("--hard-echoes-only: the echo stage sees the hard returns alone (a floor, not the product's clouds)")
    for profile in args.profiles.split(","):
        bench_profile(profile, rows, specs, backend, args.frames, args.warmup_s, args.step_s)


if __name__ == "__main__":
    main()
