"""Spray benchmarks: particle-system step time and ray-sphere time.

1. Step time: a system holding ~N particles (default 20 000, spread over the 10 m behind
   a car at 89 km/h, both populations) advanced by one Scala frame (40 ms = 4 ticks of
   10 ms); median ms per frame and per tick.
2. Ray-sphere: the same N particles against one full frame of a 64 x 2048 grid of rays
   (the os1_128_2048 profile's first 64 channels are not needed: a synthetic grid of
   64 elevations over +-11 deg x 2048 azimuths), median ms.

The spray region's share of a frame (region step and apply, and what its scatterers cost the
echo stages) at 16, 32 and 64 drop packets per wheel per tick, next to the clear frame, is in
``benchmarks/performance/weather_frame_time.py`` (rows ``spray 16`` .. ``spray 64`` and ``target``).

    python benchmarks/performance/spray_step_time.py [--particles N] [--frames K]
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from spray_particles.model.constants import load_constants
from spray_particles.model.emitter import vehicle_emitter
from spray_particles.model.forces import drag_rates
from spray_particles.sensing.raycast import sphere_hits
from spray_particles.model.system import EmittingVehicle, Particles, SprayParams, SpraySystem
from spray_particles.model.water import tyre_dimensions


def filled_system(n: int, seed: int = 0) -> SpraySystem:
    c = load_constants()
    r, w = tyre_dimensions(c.tyre.size)
    v = EmittingVehicle(100, 4.7, 1.85, 1.45, 0.15, vehicle_emitter(4.7, 1.85, 1.45, r, w))
    speed = 24.72

    def poses(t):
        m = np.eye(4)
        m[0, 3] = speed * t
        return {100: m}

    system = SpraySystem([v], poses, SprayParams(water_film_mm=0.7, wind_over_speed=1.0, seed=seed), c)
    rng = np.random.default_rng(seed)
    pos = np.stack([rng.uniform(-12.0, -2.4, n), rng.uniform(-1.5, 1.5, n), rng.uniform(0.05, 1.2, n)], 1)
    vel = np.stack([rng.normal(speed * 0.3, 3, n), rng.normal(0, 1, n), rng.normal(0, 1, n)], 1)
    pop = (rng.random(n) < 0.33).astype(np.uint8)
    k_in, l_in = drag_rates(c.particles.diameter_m, c.physics.drag_coefficient, c.physics.air_density_kg_m3,
                            c.physics.water_density_kg_m3, c.physics.air_viscosity_pa_s)  # fmt: skip
    k_fi, l_fi = drag_rates(1.5e-4, c.physics.drag_coefficient, c.physics.air_density_kg_m3,
                            c.physics.water_density_kg_m3, c.physics.air_viscosity_pa_s)  # fmt: skip
    system.particles = Particles(pos, vel, np.zeros(n), np.full(n, 1e6), np.where(pop, k_fi, k_in),
                                 np.where(pop, l_fi, l_in), np.zeros(n, np.int64), np.sign(pos[:, 1]) + (pos[:, 1] == 0),
                                 pop, rng.integers(0, 4, n), np.where(pop, 1.5e-4, 0.004), np.where(pop, 1e3, 1.0),
                                 np.where(pop, 0.005 * 24.7, 0.0), np.ones(n))  # fmt: skip
    system.tick_index = 0
    return system


def bench_step(n: int, frames: int) -> None:
    system = filled_system(n)
    times = []
    for k in range(frames):
        t0 = time.perf_counter()
        system.advance_to((k + 1) * 0.04)
        times.append(time.perf_counter() - t0)
    print(f"step: {n} particles at start, {len(system.particles)} after {frames} frames; "
          f"median {1e3 * np.median(times):.1f} ms per 40 ms frame ({1e3 * np.median(times) / 4:.2f} ms per 10 ms tick)")


def bench_rays(n: int, repeats: int = 5) -> None:
    system = filled_system(n)
    centres = system.particles.pos + np.array([20.0, 3.6, -0.5])  # seen from a sensor at the origin
    az = np.linspace(-np.pi, np.pi, 2048, endpoint=False)
    el = np.deg2rad(np.linspace(-11, 11, 64))
    A, E = np.meshgrid(az, el, indexing="ij")
    d = np.stack([np.cos(E) * np.cos(A), np.cos(E) * np.sin(A), np.sin(E)], -1).reshape(-1, 3)
    o = np.zeros_like(d)
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        hits = sphere_hits(o, d, np.full(len(d), 200.0), centres, 0.009)
        times.append(time.perf_counter() - t0)
    print(f"ray-sphere: {n} particles x {len(d)} rays (64 x 2048): median {1e3 * np.median(times):.1f} ms, "
          f"{len(hits.ray)} hits")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--particles", type=int, default=20000)
    ap.add_argument("--frames", type=int, default=10)
    args = ap.parse_args()
    bench_step(args.particles, args.frames)
    bench_rays(args.particles)


if __name__ == "__main__":
    main()
