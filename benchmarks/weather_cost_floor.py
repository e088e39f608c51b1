"""What the weather path costs before the echo stage sees a scatterer: CPU time on one thread.

Rows of ``weather_frame_time.py`` (highway_clear with 10 vehicles, advance every 10 ms) on one thread
(kernel threads 1, regions one after the other, no background detection), in CPU ms per frame
(``time.process_time``, so a busy host inflates them less than wall time):

- ``clear``: no region;
- the weather row as it is (default ``target``: rain 10 mm/h + spray 32 + dirty cover);
- the same with the cover multipath dropped: every scatterer labelled COVER that a region returns is
  removed before candidates, occlusion and echoes see it (the regions still draw it);
- the same with every scatterer dropped: the regions' own cost (stepping, drawing, ray tests) on top of the
  clear pipeline; the floor no change downstream of the regions can go below.

Per row also the CPU ms in each region's ``step`` + ``apply``. The clouds of the dropped rows are not
the simulator's: they only bound what the stages after the regions cost.

    python benchmarks/weather_cost_floor.py [--profile os1_128_2048] [--row target] [--frames 4]
        [--atmosphere-model fitted|physical]
"""

from __future__ import annotations

import argparse
import time
from collections import defaultdict

from sim_frame_time import ten_vehicles
from weather_frame_time import row_specs, variant

import lidar_weather_sim.sim.simulator as simulator
from lidar_weather_sim.core import workers
from lidar_weather_sim.core.points import Label
from lidar_weather_sim.regions.base import Scatterers
from lidar_weather_sim.scenario.schema import load_scenario
from lidar_weather_sim.scenario.world import World

DROPS = {"as is": None, "cover multipath dropped": "cover", "every scatterer dropped": "all"}


def dropping(scatterers: Scatterers | None, drop: str | None) -> Scatterers | None:
    """``scatterers`` with ``drop`` removed: ``cover`` the COVER-labelled ones, ``all`` every one; None keeps all."""
    if scatterers is None or drop is None:
        return scatterers
    if drop == "all":
        return None
    keep = scatterers.label != Label.COVER
    return Scatterers(*(None if getattr(scatterers, f) is None else getattr(scatterers, f)[keep]
                        for f in Scatterers.__dataclass_fields__))  # fmt: skip


def run(world: World, drop: str | None, frames: int, warmup_s: float) -> tuple[float, dict[str, float]]:
    """CPU ms per frame and each region's CPU ms per frame (step + apply)."""
    sim = simulator.LidarSimulator.of_world(world)
    spent: dict[str, float] = defaultdict(float)
    for name, region in sim.regions:
        def timed(fn, name=name, keep=False):
            def call(*args):
                t0 = time.process_time()
                out = fn(*args)
                spent[name] += time.process_time() - t0
                if keep:
                    out.scatterers = dropping(out.scatterers, drop)
                return out
            return call
        region.step, region.apply = timed(region.step), timed(region.apply, keep=True)
    t = 0.0

    def advance(n: int) -> None:
        nonlocal t
        got = 0
        while got < n:
            t = round(t + 0.01, 9)
            got += len(sim.advance(t, world.player))

    while t < warmup_s:
        advance(1)
    spent.clear()
    c0 = time.process_time()
    advance(frames)
    return 1e3 * (time.process_time() - c0) / frames, {k: 1e3 * v / frames for k, v in spent.items()}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--profile", default="os1_128_2048")
    ap.add_argument("--row", default="target", help="a weather row of weather_frame_time.py")
    ap.add_argument("--frames", type=int, default=4)
    ap.add_argument("--warmup-s", type=float, default=1.0, help="simulated seconds before timing")
    ap.add_argument("--dirt", default="3l")
    ap.add_argument("--atmosphere-model", choices=("fitted", "physical"), default="fitted")
    args = ap.parse_args()
    specs = row_specs(args.dirt)
    if args.row not in specs or args.row == "clear":
        ap.error(f"--row: one of {[r for r in specs if r != 'clear']}")
    workers.THREADS = 1
    simulator.PARALLEL_MIN_RAYS = 1 << 62  # regions one after the other, detection on the calling thread
    base = ten_vehicles(load_scenario("highway_clear"))
    clear_ms, _ = run(World.build(variant(base, specs["clear"]), args.profile), None, args.frames, args.warmup_s)
    world = World.build(variant(base, specs[args.row], args.atmosphere_model), args.profile)
    print(f"{args.profile}, {args.row} ({args.atmosphere_model} atmosphere): CPU ms per frame on one thread, "
          f"{args.frames} frames after {args.warmup_s:g} s")
    print(f"{'clear':>26} {clear_ms:8.1f}   x clear 1.00")
    for label, drop in DROPS.items():
        ms, regions = run(world, drop, args.frames, args.warmup_s)
        per_region = ", ".join(f"{k} {v:.1f}" for k, v in regions.items())
        print(f"{label:>26} {ms:8.1f}   x clear {ms / clear_ms:4.2f}   regions (step + apply): {per_region}", flush=True)


if __name__ == "__main__":
    main()
