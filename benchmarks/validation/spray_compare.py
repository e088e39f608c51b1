"""Particle model vs droplet reference on the same frames (thesis paper 3 metrics).

For each scenario the simulator runs with the ``spray`` region only (other regions off,
so only spray is compared) and the droplet reference (spray_particles.validation.reference) runs
with the same vehicles, poses, seed and forces. After ``--warmup`` s, for ``--frames``
frames: spray detections in the sensor frame of both; bird's-eye 2D histograms with
0.5 m cells over x 0-40 m, y -10..10 m accumulated over the frames -> Pearson
correlation, Jaccard distance of the binarised histograms (share of non-empty cells
that differ) and Hamming distance (share of all cells that differ); the histogram of
spray detections per frame (mean, std, and the overlap of the two normalised
histograms). Cost per frame: the particle model's time in the region's step + apply,
the reference's time in its step + scene cast + detection; ratio in %.

    python benchmarks/validation/spray_compare.py [--scenarios a,b] [--frames K] [--warmup S]
    python benchmarks/validation/spray_compare.py --fit     # the reference's airborne_fraction that meets the model
    python benchmarks/validation/spray_compare.py --scenarios proving_ground_39,proving_ground_55 --water-film-mm 3
    python benchmarks/validation/spray_compare.py --scenarios proving_ground_55 --water-film-mm 3 --detector-on-packets
    python benchmarks/validation/spray_compare.py --scenarios proving_ground_55 --water-film-mm 3 --seeds 0,1,2,3
    python benchmarks/validation/spray_compare.py --scenarios highway_spray --spray mist_packets_per_wheel_per_tick=32
    python benchmarks/validation/spray_compare.py --scenarios highway_spray --seeds 0,1 --frames 120 --water-along-x
    python benchmarks/validation/spray_compare.py --scenarios highway_spray --seeds 0,1 --spray inertial_scale=0

The reference has drops only; the model also has the thesis' inertial particles (Table III), solid spheres
around the car that throws them, seen in frames where no drop is. ``--spray inertial_scale=0`` compares the
model's drop packets alone with the reference, like for like (the same packets: each population draws from
its own generator).

``--seeds`` runs each scenario once per spray seed (turbulence and emission) and pools the frames:
a few seconds of proving-ground spray hold one or two turbulent episodes, so one seed's bird's-eye
histogram is mostly chance. With two seeds or more the reference's even-numbered seeds are also
compared with its odd-numbered ones: how far the yardstick agrees with itself at that many frames.

``--detector-on-packets`` also runs the reference's detection on the model's own drop packets
(each as one computational drop with the packet's airborne drops, at the reference's kernel
radius) on the same frames: its detections per frame and median position tell whether a gap
lies in where the packets carry the water or in how the region renders them.
"""

from __future__ import annotations

import argparse
import dataclasses
import time

import numpy as np
import yaml
from pydantic import ValidationError

from lidar_weather_sim.core.geometry import quaternion_matrices
from lidar_weather_sim.core.points import Label
from lidar_weather_sim.scenario.schema import load_scenario
from lidar_weather_sim.scenario.world import World
from lidar_weather_sim.sensor.radiometry import overlap_factor, peak_amplitude, surface_reflectance
from lidar_weather_sim.sim.simulator import LidarSimulator
from spray_particles.validation.metrics import bev_histogram as bev
from spray_particles.validation.metrics import compare_histograms as metrics
from spray_particles.validation.metrics import per_frame_overlap
from spray_particles.validation.reference import DropletReference, detect_frame
from spray_particles.region import SprayRegion


class _Timed:
    def __init__(self, region):
        self.region, self.seconds = region, 0.0
        for name in ("step", "apply"):
            inner = getattr(region, name)

            def wrapped(*args, _inner=inner):
                t0 = time.perf_counter()
                out = _inner(*args)
                self.seconds += time.perf_counter() - t0
                return out

            setattr(region, name, wrapped)


def scene_amplitude(world, hits, directions) -> np.ndarray:
    """Peak amplitude (noise units) of each ray's scene hit (the shape of ``directions`` without its last
    axis), the whole beam on the surface."""
    mats = world.scene.materials
    refl = np.append(mats.reflectivity, 0.0)[hits.material]  # the last index: no hit
    retro = np.append(mats.retro_share, 0.0)[hits.material]
    cos_inc = np.abs(np.einsum("nk,nk->n", hits.normal, directions.reshape(-1, 3)))
    optics, dist = world.profile.optics, hits.distance.astype(np.float64)
    amp = peak_amplitude(world.profile.detection.power_constant, 1.0, surface_reflectance(refl, retro, cos_inc),
                         dist, 1.0, overlap_factor(dist, optics.overlap_start_m, optics.overlap_full_m))  # fmt: skip
    return np.where(np.isfinite(dist), amp, 0.0).reshape(directions.shape[:-1])


def _packets_as_drops(system, time_s: float):
    """The model's drop packets at ``time_s`` as reference drops: each one computational drop of its airborne drops."""
    p = system.particles
    keep = p.population == 1
    packets = p.select(keep)
    return dataclasses.replace(packets, pos=system.positions_at(time_s)[keep], weight=packets.weight * packets.airborne)


#: (m) x bins ahead of the sensor of ``--water-along-x``
WATER_X_EDGES_M = (0.0, 0.5, 1.0, 1.5, 2.0, 3.0, 4.0, 5.0, 7.0, 10.0, 15.0, 20.0)


def water_along_x(drops, origin: np.ndarray, rotation: np.ndarray) -> np.ndarray:
    """The airborne ``drops``' (reference drops, or the model's packets as such: :func:`_packets_as_drops`) summed
    cross-section (m^2) in each x bin of :data:`WATER_X_EDGES_M` ahead of the sensor at ``origin`` / ``rotation``
    (sensor to world), within 2 m of its x axis sideways and 0.6 m up or down."""
    local = (drops.pos - origin) @ rotation
    near = (np.abs(local[:, 1]) < 2.0) & (np.abs(local[:, 2]) < 0.6)
    cross_section = drops.weight * np.pi / 4.0 * drops.diameter**2
    return np.histogram(local[near, 0], WATER_X_EDGES_M, weights=cross_section[near])[0]


def run(name: str, frames: int, warmup_s: float, airborne: float | None = None, spray: dict | None = None,
        on_packets: bool = False, seed: int = 0) -> dict:  # fmt: skip
    """Model and reference on the same ``frames`` frames of scenario ``name`` (spray seed ``seed``; ``spray``:
    parameters of the ``spray`` region over the scenario's, the particle system's shared by the reference): the
    detections' sensor-frame x, y and per-frame counts of both, and their costs per frame (s)."""
    world = World.build(load_scenario(name))
    region = dict(world.regions(["spray"], {"spray": {**(spray or {}), "seed": seed}}))["spray"]
    timed = _Timed(region)
    sim = LidarSimulator(world.profile, world.scene, regions=[("spray", region)], seed=0)
    system = region.system
    constants = system.constants
    if airborne is not None:
        constants = constants.model_copy(update={"drops": constants.drops.model_copy(
            update={"airborne_fraction": airborne})})  # fmt: skip
    reference = DropletReference(system.vehicles, system.poses, system.params.model_copy(), constants)
    pattern, player = sim.pattern, world.player

    def sensor_poses(times):
        tr, q = player.sensor_poses(times)
        return np.asarray(tr, dtype=np.float64), quaternion_matrices(np.asarray(q, dtype=np.float64))

    period = world.profile.period_s
    t = 0.0
    sim_counts, ref_counts, sim_xy, ref_xy, pk_counts, pk_xy = [], [], [], [], [], []
    sim_cost, ref_cost = [], []
    water = {"model": np.zeros(len(WATER_X_EDGES_M) - 1), "reference": np.zeros(len(WATER_X_EDGES_M) - 1)}
    reference.advance_to(0.0)
    while len(sim_counts) < frames:
        before = timed.seconds
        t += 0.01
        new = sim.advance(t, player)
        cost = timed.seconds - before
        sim_cost.append(cost)
        for f in new:
            if f.stamp_s < warmup_s:
                continue
            pts = f.points[f.points["label"] == Label.SPRAY]
            sim_counts.append(len(pts))
            sim_xy.append(np.stack([pts["x"], pts["y"]], 1))
            # reference on the same frame
            t0 = time.perf_counter()
            mid = f.stamp_s + 0.5 * pattern.column_time_s[-1]
            reference.advance_to(mid)
            tab = pattern.direction_table(f.index)
            ch = tab.shape[1]
            tr, rot = sensor_poses(f.stamp_s + pattern.column_time_s)
            # every sub-ray's scene hit: the reference sees a drop only in front of the hit of the beam's
            # sub-ray nearest to it; the central sub-ray's hit gives the amplitude for the echo rule
            world_dirs = np.einsum("cij,cbsj->cbsi", rot, tab)
            hits = sim.caster.cast(np.repeat(tr, ch * tab.shape[2], axis=0).astype(np.float32),
                                   world_dirs.reshape(-1, 3).astype(np.float32), player.actor_poses(mid),
                                   world.profile.range.max_m)  # fmt: skip
            scene = (hits.distance.reshape(world_dirs.shape[:3]).astype(np.float64),
                     scene_amplitude(world, hits, world_dirs)[:, :, tab.shape[2] // 2])  # fmt: skip
            det = detect_frame(reference, pattern, f.index, f.stamp_s, sensor_poses, scene[0], sim.threshold().level,
                               world.profile.detection.max_echoes, scene[1])  # fmt: skip
            ref_cost.append(time.perf_counter() - t0)
            (origin,), (rotation,) = sensor_poses(np.array([mid]))
            for who, drops in (("model", _packets_as_drops(system, mid)), ("reference", reference.particles)):
                water[who] += water_along_x(drops, origin, rotation)
            ref_counts.append(len(det.range_m))
            ref_xy.append(det.xyz[:, :2])
            if on_packets:
                drops, reference.particles = reference.particles, _packets_as_drops(system, mid)
                pk = detect_frame(reference, pattern, f.index, f.stamp_s, sensor_poses, scene[0], sim.threshold().level,
                                  world.profile.detection.max_echoes, scene[1])  # fmt: skip
                reference.particles = drops
                pk_counts.append(len(pk.range_m))
                pk_xy.append(pk.xyz[:, :2])
        if len(sim_counts) == 0 and t < warmup_s:
            reference.advance_to(t)  # keep the reference in step during warm-up (timed below only per frame)
    return {"scenario": name, "model_xy": np.concatenate(sim_xy), "reference_xy": np.concatenate(ref_xy),
            "model_counts": sim_counts, "reference_counts": ref_counts, "packets_xy": np.concatenate(pk_xy or [np.zeros((0, 2))]),
            "packets_counts": pk_counts, "model_s": float(np.sum(sim_cost)) / (t / period),
            "reference_s": float(np.median(ref_cost)), "reference_drops": len(reference.particles),
            "model_particles": len(system.particles), "model_water": water["model"], "reference_water": water["reference"]}  # fmt: skip


def summarise(runs: list[dict]) -> dict:
    """The thesis' metrics of model against reference over the frames of all ``runs`` (one scenario, one run
    per seed) pooled; with two runs or more also the reference's own reproducibility: the Pearson of the
    pooled bird's-eye histograms of its even-numbered runs against its odd-numbered ones."""
    pool = {k: np.concatenate([r[k] for r in runs]) for k in ("model_xy", "reference_xy", "packets_xy")}
    counts = {k: np.concatenate([r[k] for r in runs]) for k in ("model_counts", "reference_counts", "packets_counts")}
    out = {"scenario": runs[0]["scenario"], "seeds": len(runs), **metrics(bev(pool["model_xy"]), bev(pool["reference_xy"])),
           "overlap_per_frame_hist": per_frame_overlap(counts["model_counts"], counts["reference_counts"]),
           "model_ms": 1e3 * float(np.median([r["model_s"] for r in runs])),
           "reference_ms": 1e3 * float(np.median([r["reference_s"] for r in runs])),
           "reference_drops": runs[-1]["reference_drops"], "model_particles": runs[-1]["model_particles"], **pool}  # fmt: skip
    for who in ("model", "reference", "packets"):
        c = counts[f"{who}_counts"]
        out[f"{who}_counts_all"] = c
        out[f"{who}_mean"] = float(np.mean(c)) if len(c) else float("nan")
        out[f"{who}_std"] = float(np.std(c)) if len(c) else float("nan")
        xy = pool[f"{who}_xy"]
        out[f"{who}_xy_median"] = np.median(xy, axis=0).round(2).tolist() if len(xy) else None
    out["cost_pct"] = 100.0 * out["model_ms"] / out["reference_ms"]
    for who in ("model", "reference"):  # per frame
        out[f"{who}_water"] = sum(r[f"{who}_water"] for r in runs) / len(counts["model_counts"])
    out["packets_pearson"] = metrics(bev(pool["packets_xy"]), bev(pool["reference_xy"]))["pearson"]
    if len(runs) > 1:
        halves = [bev(np.concatenate([r["reference_xy"] for r in runs[i::2]])) for i in (0, 1)]
        out["reference_split_half_pearson"] = metrics(*halves)["pearson"]
        out["reference_split_half_overlap"] = per_frame_overlap(
            *(np.concatenate([r["reference_counts"] for r in runs[i::2]]) for i in (0, 1)))
    return out


def report(out: dict, on_packets: bool = False, water: bool = False) -> None:
    print(f"{out['scenario']:18s} pearson {out['pearson']:.3f}  jaccard {out['jaccard_pct']:.0f} %  hamming "
          f"{out['hamming_pct']:.1f} %  detections/frame model {out['model_mean']:.1f}+-{out['model_std']:.1f} "
          f"reference {out['reference_mean']:.1f}+-{out['reference_std']:.1f} (hist overlap "
          f"{out['overlap_per_frame_hist']:.2f})  cost model {out['model_ms']:.2f} ms / reference "
          f"{out['reference_ms']:.0f} ms = {out['cost_pct']:.2f} %  ({out['model_particles']} particles, "
          f"{out['reference_drops']} drops); median x, y model {out['model_xy_median']} reference "
          f"{out['reference_xy_median']}", flush=True)  # fmt: skip
    counts = {who: np.asarray(out[f"{who}_counts_all"]) for who in ("model", "reference")}
    print(f"{'':18s} frames without a spray detection: model {np.mean(counts['model'] == 0):.0%}, reference "
          f"{np.mean(counts['reference'] == 0):.0%}; median / 90th percentile per frame: model "
          f"{np.median(counts['model']):g} / {np.percentile(counts['model'], 90):.0f}, reference "
          f"{np.median(counts['reference']):g} / {np.percentile(counts['reference'], 90):.0f}", flush=True)  # fmt: skip
    if "reference_split_half_pearson" in out:
        print(f"{'':18s} {out['seeds']} seeds pooled; the reference's even seeds against its odd ones: pearson "
              f"{out['reference_split_half_pearson']:.3f}, hist overlap {out['reference_split_half_overlap']:.2f}",
              flush=True)  # fmt: skip
    if water:
        edges = WATER_X_EDGES_M
        print(f"{'':18s} airborne drop cross-section per frame (mm^2) at x {edges[0]:g}-{edges[-1]:g} m ahead "
              f"(bins {', '.join(f'{e:g}' for e in edges[1:-1])} m), |y| < 2 m, |z| < 0.6 m:", flush=True)  # fmt: skip
        for who in ("model", "reference"):
            print(f"{'':18s} {who:9s} " + " ".join(f"{1e6 * v:7.2f}" for v in out[f"{who}_water"]), flush=True)
        edges_x = np.asarray(edges)
        for who in ("model", "reference"):
            xy = out[f"{who}_xy"]
            n = len(out[f"{who}_counts_all"])
            print(f"{'':18s} {who:9s} detections per frame in those bins: "
                  + " ".join(f"{v / n:6.2f}" for v in np.histogram(xy[:, 0], edges_x)[0]), flush=True)  # fmt: skip
    if on_packets:
        print(f"{'':18s} the reference's detector on the model's packets: {out['packets_mean']:.1f} "
              f"detections/frame, median x, y {out['packets_xy_median']}, pearson against the reference "
              f"{out['packets_pearson']:.3f}", flush=True)  # fmt: skip


def plot(out: dict, directory: str) -> None:
    """Bird's-eye histograms of the model and the reference side by side (PNG)."""
    import pathlib

    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 2, figsize=(10, 6), sharey=True)
    for ax, key, title in zip(axes, ("model_xy", "reference_xy"), ("particle model", "droplet reference")):
        h = bev(out[key])
        ax.imshow(np.log1p(h), origin="lower", extent=(-10, 10, 0, 40), aspect="auto", cmap="magma")
        ax.set(title=f"{title}: {len(out[key])} detections", xlabel="y (m)")
        ax.invert_xaxis()  # y left
    axes[0].set_ylabel("x (m)")
    fig.suptitle(f"{out['scenario']}: Pearson {out['pearson']:.2f}, log(1 + count) per 0.5 m cell")
    path = pathlib.Path(directory)
    path.mkdir(parents=True, exist_ok=True)
    fig.savefig(path / f"{out['scenario']}.png", dpi=80)
    plt.close(fig)


def _spray_params(items: list[str], parser: argparse.ArgumentParser) -> dict:
    """``KEY=VALUE`` strings as spray region parameters (values parsed as YAML), checked against the region's
    parameter model; a bad one ends the program with a one-line reason."""
    out = {}
    for item in items:
        key, sep, value = item.partition("=")
        if not sep or key not in SprayRegion.Params.model_fields:
            parser.error(f"--spray {item!r}: expected KEY=VALUE with KEY a spray region parameter "
                         f"({', '.join(sorted(SprayRegion.Params.model_fields))})")  # fmt: skip
        out[key] = yaml.safe_load(value)
    try:
        SprayRegion.Params(**out)
    except ValidationError as exc:
        err = exc.errors()[0]
        parser.error(f"--spray {err['loc'][0]}={err['input']!r}: {err['msg']}")
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--scenarios", default="proving_ground_39,proving_ground_55,proving_ground_60,highway_spray")
    ap.add_argument("--frames", type=int, default=50)
    ap.add_argument("--warmup", type=float, default=2.0)
    ap.add_argument("--fit", action="store_true",
                    help="the airborne_fraction at which the reference's detections meet the model's on "
                         "proving_ground_55 (only the reference's water varies; the model keeps config/spray.yaml's)")
    ap.add_argument("--water-film-mm", type=float, help="override the scenarios' water film (mm)")
    ap.add_argument("--fit-steps", type=int, default=8)
    ap.add_argument("--detector-on-packets", action="store_true",
                    help="also the reference's detection on the model's drop packets (where a gap lies)")
    ap.add_argument("--seeds", default="0", help="spray seeds (comma-separated): frames of all pooled")
    ap.add_argument("--water-along-x", action="store_true",
                    help="also the airborne drops' cross-section and the detections per x bin ahead of the sensor, "
                         "model packets against reference drops (where the water is against where it is seen)")
    ap.add_argument("--plot", metavar="DIR", help="write bird's-eye histograms of both as DIR/SCENARIO.png")
    ap.add_argument("--spray", action="append", default=[], metavar="KEY=VALUE",
                    help="a spray region parameter (repeatable), e.g. mist_packets_per_wheel_per_tick=32; the "
                         "particle system's parameters (forces, turbulence) apply to the reference too")  # fmt: skip
    args = ap.parse_args()
    spray = _spray_params(args.spray, ap)
    if args.water_film_mm is not None:
        spray["water_film_mm"] = args.water_film_mm
    if args.fit:
        lo, hi = 1e-4, 0.1  # log-bisection: detections grow steeply once drops cross the threshold
        for _ in range(args.fit_steps):
            f = float(np.sqrt(lo * hi))
            r = summarise([run("proving_ground_55", args.frames, args.warmup, f, spray)])
            print(f"airborne_fraction {f:.4g}: model {r['model_mean']:.2f}, reference {r['reference_mean']:.2f}",
                  flush=True)  # fmt: skip
            lo, hi = (f, hi) if r["reference_mean"] < r["model_mean"] else (lo, f)
        print(f"airborne_fraction: {np.sqrt(lo * hi):.3g}")
        return
    seeds = [int(k) for k in args.seeds.split(",")]
    for name in args.scenarios.split(","):
        out = summarise([run(name, args.frames, args.warmup, spray=spray, on_packets=args.detector_on_packets,
                             seed=k) for k in seeds])  # fmt: skip
        report(out, args.detector_on_packets, args.water_along_x)
        if args.plot:
            plot(out, args.plot)


if __name__ == "__main__":
    main()
