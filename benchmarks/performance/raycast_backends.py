"""Ray casting throughput of each available backend, and SceneCaster's cost with moving actors.

Rays: a 128-beam, 2048-column spinning lidar (elevation -25..+15 deg) with 3
sub-rays per beam (1 mrad apart in azimuth), 786,432 rays from 1.9 m above the
road. Scene: ground plane, 2 guard rails with posts every 4 m, 10 box vehicles.
Times are the best of ``--repeats`` after one warm-up cast (Mitsuba JIT-compiles
its kernels on the first one). "same as open3d %": rays whose hit or miss and
distance (within 1e-4 m) match the open3d reference. "Scene" columns time
``SceneCaster.cast`` (static road, vehicles as actors) without and with the 10
vehicles moving; the difference is the hand-instancing cost. On a shared 2-core
machine the numbers vary by up to 2x between runs.

    python benchmarks/performance/raycast_backends.py [--repeats 5]
"""

from __future__ import annotations

import argparse
import importlib.metadata
import os
import platform
import time

import numpy as np

from lidar_weather_sim.scene.mesh import TriangleMesh, box_mesh
from lidar_weather_sim.scene.raycast import SceneCaster, available_backends, make_caster, unavailable_backends

SENSOR_Z = 1.9  # m


def translate(x: float, y: float, z: float = 0.0, yaw: float = 0.0) -> np.ndarray:
    m = np.eye(4)
    m[:3, :3] = [[np.cos(yaw), -np.sin(yaw), 0], [np.sin(yaw), np.cos(yaw), 0], [0, 0, 1]]
    m[:3, 3] = x, y, z
    return m


def road() -> TriangleMesh:
    """Ground (400 m square, top at z = 0) and two guard rails with posts, object ids 1-3."""
    parts = [box_mesh((400.0, 400.0, 0.2), 0, 1, z_bottom=-0.2)]
    for side, oid in ((-8.0, 2), (8.0, 3)):
        parts.append(box_mesh((200.0, 0.05, 0.3), 1, oid, z_bottom=0.45).transformed(translate(0, side)))
        post = box_mesh((0.1, 0.1, 0.75), 1, oid)
        parts += [post.transformed(translate(x, side)) for x in np.arange(-100, 100, 4.0)]
    return TriangleMesh.concatenate(parts)


def vehicle(object_id: int) -> TriangleMesh:
    """Body frame: 4.5 x 1.8 m body on 0.3 m clearance plus a cabin."""
    body, cabin = box_mesh((4.5, 1.8, 0.9), 2, object_id, 0.3), box_mesh((2.4, 1.6, 0.6), 2, object_id, 1.2)
    return TriangleMesh.concatenate([body, cabin])


def vehicle_poses(t: float) -> dict[int, np.ndarray]:
    """10 vehicles in 3 lanes, moving at 10-30 m/s; t in s."""
    rng = np.random.default_rng(0)
    x0, lane, speed = rng.uniform(-60, 60, 10), rng.choice([-3.5, 0.0, 3.5], 10), rng.uniform(10, 30, 10)
    x0[np.abs(x0) < 6] += 12  # keep the ego lane clear around the sensor
    return {100 + i: translate(x0[i] + speed[i] * t, lane[i], 0.0, 0.02 * i) for i in range(10)}


def lidar_rays() -> tuple[np.ndarray, np.ndarray]:
    el = np.deg2rad(np.linspace(-25.0, 15.0, 128))
    az = (np.arange(2048)[:, None] * 2 * np.pi / 2048 + np.array([-1e-3, 0.0, 1e-3])).ravel()
    e, a = np.meshgrid(el, az, indexing="ij")
    d = np.stack([np.cos(e) * np.cos(a), np.cos(e) * np.sin(a), np.sin(e)], -1).reshape(-1, 3).astype(np.float32)
    o = np.tile(np.float32([0.0, 0.0, SENSOR_Z]), (len(d), 1))
    return o, d


def best_of(fn, repeats: int) -> float:
    """Seconds of the fastest of ``repeats`` calls (after one warm-up call)."""
    fn()
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return min(times)


def versions() -> str:
    names = ["numpy", "open3d-cpu", "embreex", "mitsuba", "drjit"]
    found = []
    for n in names:
        try:
            found.append(f"{n} {importlib.metadata.version(n)}")
        except importlib.metadata.PackageNotFoundError:
            found.append(f"{n} -")
    llvm = os.environ.get("DRJIT_LIBLLVM_PATH", "-")
    cpu = platform.processor() or platform.machine()
    return f"{', '.join(found)}; DRJIT_LIBLLVM_PATH={llvm}; {os.cpu_count()} cpus, {cpu}"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--repeats", type=int, default=5)
    args = ap.parse_args()

    static = road()
    actors = {aid: vehicle(aid) for aid in vehicle_poses(0.0)}
    world = TriangleMesh.concatenate([static] + [actors[a].transformed(p) for a, p in vehicle_poses(0.0).items()])
    o, d = lidar_rays()
    n = len(o)
    print(f"{n:,} rays (128 x 2048 x 3), world mesh {len(world.triangles):,} triangles, best of {args.repeats}")

    ref, _ = make_caster("open3d", world.vertices, world.triangles).cast(o, d)
    rows = []
    for name in available_backends():
        t0 = time.perf_counter()
        caster = make_caster(name, world.vertices, world.triangles)
        build = time.perf_counter() - t0
        dist, _ = caster.cast(o, d)
        with np.errstate(invalid="ignore"):
            agree = np.where(np.isfinite(dist), np.abs(dist - ref) <= 1e-4, ~np.isfinite(ref)).mean()
        cast = best_of(lambda: caster.cast(o, d), args.repeats)

        sc = SceneCaster(static, actors, backend=name)
        static_only = best_of(lambda: sc.cast(o, d, {}, 200.0), args.repeats)
        ticks = iter(np.arange(0, 100, 0.1))
        moving = best_of(lambda: sc.cast(o, d, vehicle_poses(next(ticks)), 200.0), args.repeats)
        rows.append((name, build * 1e3, cast * 1e3, n / cast / 1e6, agree * 100, static_only * 1e3, moving * 1e3))

    head = ("backend", "build ms", "cast ms", "Mrays/s", "same as open3d %", "Scene static ms", "Scene +10 actors ms")
    print(" | ".join(f"{h:>{max(len(h), 8)}}" for h in head))
    for name, *values in rows:
        cells = [f"{v:>{max(len(h), 8)}.{2 if h == 'Mrays/s' else 1}f}" for h, v in zip(head[1:], values)]
        print(" | ".join([f"{name:>8}"] + cells))
    print("SceneCaster overhead of 10 moving actors = (Scene +10 actors) - (Scene static) ms per cast")
    for name, reason in unavailable_backends().items():
        print(f"unavailable: {name}: {reason}")
    print(versions())


if __name__ == "__main__":
    main()
