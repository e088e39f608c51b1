"""``lidar-weather-sim twin``: a digital twin of a recording, built only from its calibration split.

Steps (each in its own module): the split (:func:`lidar_weather_sim.gap.split.split_recording`: even /
odd frames, or alternating 30 deg azimuth sectors below 4 frames); the profile
(:mod:`~lidar_weather_sim.twin.profile_match`); the poses (:mod:`~lidar_weather_sim.twin.poses`); what the
weather filter calls weather removed from each frame (:mod:`~lidar_weather_sim.twin.point_filter`: a filter
registered by entry point, weather_filter's when installed); the sensor's own near-field structure set apart
as a fixed ego part (:mod:`~lidar_weather_sim.twin.ego_part`); the calibration points in the map frame, moving
ones left out, and the trimmed Poisson mesh (:mod:`~lidar_weather_sim.twin.reconstruct`); reflectivity per
triangle (:mod:`~lidar_weather_sim.twin.reflectivity`). At most ``max_frames`` calibration frames (evenly
spaced) build the mesh, so the cost does not grow with the recording.

DIR gets ``mesh.ply`` (map frame, m; reflectivity per face, :mod:`lidar_weather_sim.scene.surveyed`),
``split.yaml``, ``scenario.yaml`` (mesh-only, the recording's sensor poses as its ``trajectory``: runnable
by ``lidar-weather-sim run``, and ``gap BAG --scenario DIR/scenario.yaml`` fits and scores on the split),
``ego_part.ply`` (sensor frame; the scenario's ``sensor.fixed_parts``) when there is an ego part,
``profile.yaml`` when the profile was derived, and ``report.json`` / ``report.md``: weather removed, ego part,
the cover zone the recording shows, coverage (share of
calibration and held-out points within :data:`COVERAGE_M` of the mesh), point-to-mesh and
mesh-to-points distances (median, p95), triangle count, time per step.
"""

from __future__ import annotations

import json
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import yaml
from scipy.spatial import cKDTree

from lidar_weather_sim.gap.split import thin_evenly
from lidar_weather_sim.gap.split import SECTOR_DEG, SPLIT_FILE, DataSplit, split_recording
from lidar_weather_sim.io.bags import BagError
from lidar_weather_sim.io.recording import Recording
from lidar_weather_sim.scene.surveyed import write_surveyed_ply
from lidar_weather_sim.sensor.profile import SensorProfile
from lidar_weather_sim.sensor.scan import ScanPattern
from lidar_weather_sim.twin.carve import CalibrationScan, carve_mesh, cell_centres
from lidar_weather_sim.twin.ego_part import detect_ego_part, ego_part_mesh, voxel_reflectivity
from lidar_weather_sim.twin.point_filter import AUTO, FilterChoice, choose_filter, filter_frames
from lidar_weather_sim.twin.poses import TwinPoses, points_in_map, twin_poses
from lidar_weather_sim.twin.profile_match import choose_profile, cover_zone
from lidar_weather_sim.twin.reconstruct import (
    FrameCloud,
    ReconstructionSettings,
    closest_triangles,
    distances_to_mesh,
    gap_fill_points,
    moving_points,
    reconstruct_mesh,
)
from lidar_weather_sim.twin.reflectivity import point_reflectivity, triangle_reflectivity

COVERAGE_M = 0.1
MAX_FRAMES = 20  # calibration frames that build the mesh (evenly spaced)
GAP_FILL_MAX_DEG = 5.0  # held-out sectors up to this wide are spanned channel by channel (reconstruct step 3)
MAX_REPORT_POINTS = 400_000  # points per part whose distance to the mesh is measured (seeded subset)
EGO_PART_FILE = "ego_part.ply"  # the fixed ego part, sensor frame (scenario sensor.fixed_parts)


@dataclass
class TwinInput:
    """A recording checked for a twin: frames to use, the profile and the split."""

    recording: Recording
    frames: int
    profile_name: str
    profile: SensorProfile
    profile_how: str
    split: DataSplit
    timings: dict[str, float] = field(default_factory=dict)
    point_filter: FilterChoice = field(default_factory=lambda: FilterChoice(None, "none", "no weather filter"))
    cover_zone: dict = field(default_factory=dict)


def load_input(bag: str | Path, topic: str | None = None, profile: str | None = None,
               frames: int | None = None, split: str = "auto", sector_deg: float = SECTOR_DEG,
               weather_filter: str = AUTO) -> TwinInput:  # fmt: skip
    """Everything checked before anything is written: the bag, its topic, non-empty clouds, the profile, the
    split (``split``: auto, frames or sectors, of ``sector_deg`` sectors,
    :func:`~lidar_weather_sim.gap.split.split_recording`) and the frame filter (``weather_filter``: auto, none or
    a registered name, :func:`~lidar_weather_sim.twin.point_filter.choose_filter`)."""
    t0 = time.perf_counter()
    if not Path(bag).exists():
        raise FileNotFoundError(f"no bag at {bag}")
    recording = Recording.load(bag, topic)
    n = len(recording.frames) if frames is None else min(frames, len(recording.frames))
    empty = [i for i in range(n) if not len(recording.frames[i].points)]
    if empty:
        raise BagError(f"bag {bag}: topic {recording.topic}: frame {empty[0]} holds no points (empty cloud)")
    stamps = np.array([f.stamp_ns for f in recording.frames[:n]], dtype=np.float64)
    rate = 1e9 / float(np.median(np.diff(stamps))) if n > 1 and np.median(np.diff(stamps)) > 0 else None
    data_split = split_recording(n, split, sector_deg)
    calibration = [recording.frames[i].points[data_split.keep(recording.frames[i].points, "calibration")]
                   for i in data_split.calibration_frames]  # fmt: skip
    name, prof, how = choose_profile(recording.frames[0].points, profile, rate, calibration)
    out = TwinInput(recording, n, name, prof, how, data_split, point_filter=choose_filter(weather_filter),
                    cover_zone=cover_zone(calibration, prof))  # fmt: skip
    out.timings["load_s"] = time.perf_counter() - t0
    return out


def _frame_cloud(recording: Recording, index: int, poses: TwinPoses, part_mask: np.ndarray) -> FrameCloud:
    xyz, origins = points_in_map(recording, index, poses)
    frame = recording.frames[index]
    mid = recording.time_s(frame.stamp_ns) + 0.5 * float(frame.points["time_stamp"].max()) * 1e-9
    channel = frame.points["channel"]
    return FrameCloud(xyz[part_mask], origins[part_mask], poses.frame_pose(mid), channel[part_mask])


def _calibration_scan(recording: Recording, index: int, split: DataSplit, keep: np.ndarray, poses: TwinPoses,
                      profile: SensorProfile, pattern: ScanPattern) -> CalibrationScan:  # fmt: skip
    """Frame ``index``'s calibration points, every one (weather and vehicles too; ``keep``: the frame's points the
    weather filter kept), for the carve (:mod:`~lidar_weather_sim.twin.carve`)."""
    frame = recording.frames[index]
    part = split.keep(frame.points, "calibration")
    p = frame.points[part]
    start = recording.time_s(frame.stamp_ns)
    first, mid, last = (poses.frame_pose(start + k * profile.period_s) for k in (0.0, 0.5, 1.0))
    az = cell_centres(pattern.n_columns)
    centres = np.zeros(len(az), dtype=[("x", np.float64), ("y", np.float64)])
    centres["x"], centres["y"] = np.cos(az), np.sin(az)
    scan = recording.scan_index(frame, profile.period_s)
    return CalibrationScan(np.stack([p["x"], p["y"], p["z"]], axis=-1).astype(np.float64), p["channel"], ~keep[part], mid,
                           0.5 * float(np.linalg.norm(last[:3, 3] - first[:3, 3])), split.keep(centres, "calibration"),
                           pattern.direction_table(scan), pattern.active_channels(scan))


def _subset(cloud: FrameCloud, keep: np.ndarray) -> FrameCloud:
    return FrameCloud(cloud.xyz[keep], cloud.origins[keep], cloud.pose, cloud.channel[keep])


def weather_masks(inp: TwinInput, used: list[int]) -> tuple[list[np.ndarray], dict]:
    """Per frame of ``used`` the calibration points the frame filter keeps (all of them without a filter), and
    report.json's ``weather_filter``. The filter sees only calibration points: each frame after the frame before
    it in the recording when that is a calibration frame (a filter with previous-frame features)."""
    rec, split, choice = inp.recording, inp.split, inp.point_filter
    parts = [split.keep(rec.frames[i].points, "calibration") for i in used]
    total = int(sum(int(k.sum()) for k in parts))
    if choice.filter is None:
        return parts, {"requested": choice.requested, "ran": None, "points_removed": 0, "calibration_points": total,
                       "note": choice.note}  # fmt: skip
    calibration = set(split.calibration_frames)

    def part(i: int) -> np.ndarray:
        return rec.frames[i].points[split.keep(rec.frames[i].points, "calibration")]

    frames = [rec.frames[i].points[k] for i, k in zip(used, parts)]
    previous = [part(i - 1) if i - 1 in calibration else None for i in used]
    masks, names = filter_frames(choice.filter, frames, previous)
    out = []
    for k, m in zip(parts, masks):
        keep = k.copy()
        keep[np.flatnonzero(k)] = m
        out.append(keep)
    removed = total - int(sum(int(k.sum()) for k in out))
    ran = ", ".join(f"{n} ({names.count(n)} frames)" for n in dict.fromkeys(names))
    return out, {"requested": choice.requested, "ran": ran, "points_removed": removed, "calibration_points": total,
                 "note": f"{ran} removed {removed} of {total} calibration points ({100 * removed / max(total, 1):.1f} %) "
                         "as weather before meshing"}  # fmt: skip


def build_twin(inp: TwinInput, out: str | Path, settings: ReconstructionSettings = ReconstructionSettings(),
               max_frames: int = MAX_FRAMES) -> dict:  # fmt: skip
    """Build the twin of ``inp`` into ``out`` (module doc); returns report.json's content."""
    rec, split, profile, timings = inp.recording, inp.split, inp.profile, inp.timings
    t = time.perf_counter()
    poses = twin_poses(_first_frames(rec, inp.frames), max_range_m=min(profile.range.max_m, 100.0))
    timings["poses_s"] = time.perf_counter() - t

    t = time.perf_counter()
    pattern = ScanPattern(profile)
    used = thin_evenly(split.calibration_frames, max_frames)
    keeps, weather_report = weather_masks(inp, used)
    timings["weather_filter_s"] = time.perf_counter() - t

    t = time.perf_counter()
    clouds, intensity, local = [], [], []
    for i, keep in zip(used, keeps):
        clouds.append(_frame_cloud(rec, i, poses, keep))
        p = rec.frames[i].points[keep]
        intensity.append(p["intensity"])
        local.append(np.stack([p["x"], p["y"], p["z"]], axis=-1).astype(np.float64))
    step = max(2 * np.pi / pattern.n_columns, float(np.median(np.diff(np.sort(pattern.elevation)))) if pattern.n_channels > 1 else 0.0)
    ego = detect_ego_part(local, [c.xyz for c in clouds], np.array([c.pose[:3, 3] for c in clouds]),
                          [c.pose for c in clouds], bin_deg=float(np.degrees(step)))  # fmt: skip
    ego_local = np.concatenate([x[m] for x, m in zip(local, ego.masks)]) if ego.points else np.zeros((0, 3))
    ego_intensity = np.concatenate([v[m] for v, m in zip(intensity, ego.masks)]) if ego.points else np.zeros(0)
    clouds = [_subset(c, ~m) for c, m in zip(clouds, ego.masks)]
    intensity = [v[~m] for v, m in zip(intensity, ego.masks)]
    timings["ego_part_s"] = time.perf_counter() - t

    t = time.perf_counter()
    moving = moving_points(clouds, pattern.elevation, pattern.n_columns)
    static_xyz = np.concatenate([c.xyz[~m] for c, m in zip(clouds, moving)])
    static_origin = np.concatenate([c.origins[~m] for c, m in zip(clouds, moving)])
    static_intensity = np.concatenate([v[~m] for v, m in zip(intensity, moving)])
    timings["moving_s"] = time.perf_counter() - t

    t = time.perf_counter()
    fill_xyz, fill_origin = _gap_fill(split, clouds, moving, pattern.n_columns)
    vertices, triangles = reconstruct_mesh(np.concatenate([static_xyz, fill_xyz]),
                                           np.concatenate([static_origin, fill_origin]), step, settings,
                                           _sector_bridge(split, clouds[0].pose) if split.kind == "sectors" else None)  # fmt: skip
    timings["mesh_s"] = time.perf_counter() - t

    t = time.perf_counter()
    nearest = closest_triangles(vertices, triangles, static_xyz)
    v = vertices[triangles]
    normals = np.cross(v[:, 1] - v[:, 0], v[:, 2] - v[:, 0])
    normals /= np.maximum(np.linalg.norm(normals, axis=1, keepdims=True), 1e-12)
    ray = static_xyz - static_origin
    rng = np.linalg.norm(ray, axis=1)
    cos = np.einsum("ij,ij->i", ray / np.maximum(rng, 1e-9)[:, None], normals[nearest])
    rho = point_reflectivity(static_intensity, rng, cos, profile)
    reflectivity, recorded_range, refl_summary = triangle_reflectivity(nearest, rho, len(triangles), v.mean(axis=1), rng)
    timings["reflectivity_s"] = time.perf_counter() - t

    t = time.perf_counter()
    scans = [_calibration_scan(rec, i, split, keep, poses, profile, pattern) for i, keep in zip(used, keeps)]
    carved = carve_mesh(vertices, triangles, reflectivity, recorded_range, scans, pattern.n_channels,
                        profile.detection.max_echoes, profile.range.max_m)  # fmt: skip
    vertices, triangles, reflectivity, recorded_range = carved.vertices, carved.triangles, carved.reflectivity, carved.recorded_range
    timings["carve_s"] = time.perf_counter() - t

    t = time.perf_counter()
    coverage = _coverage(rec, split, poses, vertices, triangles, static_xyz, settings.seed)
    timings["report_s"] = time.perf_counter() - t

    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    mesh_path = write_surveyed_ply(out / "mesh.ply", vertices, triangles, reflectivity, recorded_range)
    split.write(out / SPLIT_FILE)
    profile_ref = inp.profile_name
    if inp.profile_how == "derived":
        (out / "profile.yaml").write_text("# derived from the recording by lidar-weather-sim twin\n"
                                          + yaml.safe_dump(profile.model_dump(mode="json"), sort_keys=False))  # fmt: skip
        profile_ref = str((out / "profile.yaml").resolve())
    fixed_parts = []
    if len(ego.voxels):
        rho = point_reflectivity(ego_intensity, np.linalg.norm(ego_local, axis=1), np.ones(len(ego_local)), profile)
        part_v, part_t, part_r = ego_part_mesh(ego.voxels, voxel_reflectivity(ego.voxels, ego_local, rho))
        part_path = write_surveyed_ply(out / EGO_PART_FILE, part_v, part_t, part_r)
        fixed_parts.append({"mesh": str(part_path.resolve())})
    scenario = twin_scenario(rec, inp.frames, poses, mesh_path.resolve(), profile_ref, profile, fixed_parts)
    (out / "scenario.yaml").write_text(yaml.safe_dump(scenario, sort_keys=False))
    removed = int(sum(int(m.sum()) for m in moving))
    report = {
        "bag": str(rec.path), "topic": rec.topic, "frames": inp.frames,
        "profile": {"name": inp.profile_name, "how": inp.profile_how},
        "poses": poses.source,
        "deskewed": poses.deskewed,
        "split": {"kind": split.kind, "calibration_frames": len(split.calibration_frames),
                  "heldout_frames": len(split.heldout_frames), "frames_used_for_mesh": used},
        "moving_points_removed": removed,
        "moving_note": ("a single frame: nothing to compare it with, no moving points removed" if len(used) < 2
                        else f"{removed} of {removed + len(static_xyz)} calibration points seen through by a "
                             "neighbouring frame"),
        "weather_filter": weather_report,
        "ego_part": {"points": ego.points, "voxels": int(len(ego.voxels)), "sensor_travel_m": round(ego.travel_m, 3),
                     "file": EGO_PART_FILE if fixed_parts else None, "note": ego.note},
        "cover_zone": inp.cover_zone,
        "mesh": {"vertices": int(len(vertices)), "triangles": int(len(triangles)), "file": "mesh.ply"},
        "carve": carved.summary,
        "coverage_within_m": COVERAGE_M,
        **coverage,
        "reflectivity": refl_summary,
        "time_s": {k: round(v, 3) for k, v in timings.items()},
    }  # fmt: skip
    report["time_s"]["total_s"] = round(sum(timings.values()), 3)
    (out / "report.json").write_text(json.dumps(report, indent=1))
    (out / "report.md").write_text(_markdown(report))
    return report


def _gap_fill(split: DataSplit, clouds: list[FrameCloud], moving: list[np.ndarray], columns: int):
    """Points (and their sensor origins) spanning each frame's held-out sectors channel by channel, for a sector
    split of at most :data:`GAP_FILL_MAX_DEG` sectors (reconstruct step 3); none otherwise."""
    empty = (np.zeros((0, 3)), np.zeros((0, 3)))
    if split.kind != "sectors":
        return empty
    width = max(b - a for a, b in split.heldout_sectors_deg)
    if width > GAP_FILL_MAX_DEG:
        return empty
    max_gap = np.radians(width) + 2.5 * 2 * np.pi / columns
    xyz, origins = [], []
    for cloud, m in zip(clouds, moving):
        static = FrameCloud(cloud.xyz[~m], cloud.origins[~m], cloud.pose, cloud.channel[~m])
        filled = gap_fill_points(static, columns, max_gap)
        local = (filled - cloud.pose[:3, 3]) @ cloud.pose[:3, :3]
        as_points = np.zeros(len(local), dtype=[("x", np.float64), ("y", np.float64)])
        as_points["x"], as_points["y"] = local[:, 0], local[:, 1]
        filled = filled[split.keep(as_points, "heldout")]
        xyz.append(filled)
        origins.append(np.broadcast_to(cloud.pose[:3, 3], filled.shape))
    return (np.concatenate(xyz), np.concatenate(origins)) if xyz else empty


def _sector_bridge(split: DataSplit, pose: np.ndarray):
    """For a sector split: the extra trim distance (m) of each vertex, its horizontal range from the sensor
    (first calibration frame's pose) times its angle to the nearest calibration sector (0 inside one): the
    arc over which Poisson's surface may continue into a held-out sector."""
    sectors = np.radians(np.asarray(split.calibration_sectors_deg, dtype=np.float64))

    def bridge(vertices: np.ndarray) -> np.ndarray:
        local = (vertices - pose[:3, 3]) @ pose[:3, :3]
        az = np.arctan2(local[:, 1], local[:, 0])[:, None]
        to_lo = np.abs(np.angle(np.exp(1j * (az - sectors[None, :, 0]))))
        to_hi = np.abs(np.angle(np.exp(1j * (az - sectors[None, :, 1]))))
        inside = (az >= sectors[None, :, 0]) & (az < sectors[None, :, 1])
        angle = np.where(inside, 0.0, np.minimum(to_lo, to_hi)).min(axis=1)
        return np.hypot(local[:, 0], local[:, 1]) * angle

    return bridge


def _first_frames(rec: Recording, n: int) -> Recording:
    """``rec`` limited to its first ``n`` frames (the poses of KISS-ICP need no more)."""
    if n == len(rec.frames):
        return rec
    from dataclasses import replace

    return replace(rec, frames=rec.frames[:n])


def _part_points(rec: Recording, split: DataSplit, poses: TwinPoses, part: str, rng: np.random.Generator) -> np.ndarray:
    xyz = []
    for i in split.frames(part):
        keep = split.keep(rec.frames[i].points, part)
        xyz.append(points_in_map(rec, i, poses)[0][keep])
    xyz = np.concatenate(xyz) if xyz else np.zeros((0, 3))
    if len(xyz) > MAX_REPORT_POINTS:
        xyz = xyz[np.sort(rng.choice(len(xyz), MAX_REPORT_POINTS, replace=False))]
    return xyz


def _coverage(rec, split, poses, vertices, triangles, static_xyz, seed: int) -> dict:
    """Coverage and distances of the calibration and held-out points, and mesh-to-points distances."""
    rng = np.random.default_rng(seed)
    out = {"coverage": {}, "point_to_mesh_m": {}}
    for part in ("calibration", "heldout"):
        d = distances_to_mesh(vertices, triangles, _part_points(rec, split, poses, part, rng))
        out["coverage"][part] = float(np.mean(d <= COVERAGE_M)) if len(d) else float("nan")
        out["point_to_mesh_m"][part] = _stats(d)
    centroids = vertices[triangles].mean(axis=1)
    out["mesh_to_points_m"] = _stats(cKDTree(static_xyz).query(centroids, workers=2)[0])
    return out


def _stats(d: np.ndarray) -> dict:
    if not len(d):
        return {"median": float("nan"), "p95": float("nan"), "points": 0}
    return {"median": float(np.median(d)), "p95": float(np.percentile(d, 95)), "points": int(len(d))}


def twin_scenario(rec: Recording, frames: int, poses: TwinPoses, mesh: Path, profile_ref: str,
                  profile: SensorProfile, fixed_parts: list[dict] | None = None) -> dict:  # fmt: skip
    """The twin as a mesh-only scenario whose ``trajectory`` is the sensor's poses (base_link = sensor), with
    ``fixed_parts`` (the ego part) on the sensor."""
    starts = np.array([rec.time_s(f.stamp_ns) for f in rec.frames[:frames]])
    # to the microsecond the trajectory is written with: a frame's end and the next frame's start are one time
    times = np.unique(np.round(np.concatenate([starts, starts + profile.period_s]), 6))
    translation, quaternion = poses.track.sensor_poses(times)
    trajectory = [{"t_s": float(t), "x_m": float(p[0]), "y_m": float(p[1]), "z_m": float(p[2]),
                   "qx": float(q[0]), "qy": float(q[1]), "qz": float(q[2]), "qw": float(q[3])}
                  for t, p, q in zip(times, translation, quaternion)]  # fmt: skip
    name = f"twin_{Path(rec.path).name}"
    return {
        "name": name,
        "description": f"digital twin of {rec.path} ({rec.topic}, {frames} frames; poses: {poses.source}), "
                       "built by lidar-weather-sim twin from its calibration split",
        "map": None,
        "static_meshes": [str(mesh)],
        "duration_s": round(float(times[-1]), 6),
        "seed": 0,
        "sensor": {"profile": profile_ref, "mount": {"x_m": 0.0, "y_m": 0.0, "z_m": 0.0},
                   **({"fixed_parts": fixed_parts} if fixed_parts else {})},
        "trajectory": trajectory,
        "weather": {"fog": {"visual_range_m": 100000.0}, "precipitation": {"type": "dry", "intensity_mm_h": 0.0},
                    "sun": {"irradiance_w_m2": 0.0}, "wind": {"speed_m_s": 0.0}},
        "regions": [],
    }  # fmt: skip


def _markdown(r: dict) -> str:
    c, d, m = r["coverage"], r["point_to_mesh_m"], r["mesh_to_points_m"]
    return "\n".join([
        f"# Twin of {r['bag']}", "",
        f"{r['frames']} frames of {r['topic']}; profile {r['profile']['name']} ({r['profile']['how']}); "
        f"poses: {r['poses']}; split: {r['split']['kind']} ({r['split']['calibration_frames']} calibration, "
        f"{r['split']['heldout_frames']} held-out frames; {len(r['split']['frames_used_for_mesh'])} build the mesh).",
        "", f"Weather: {r['weather_filter']['note']}.", "", f"Ego part: {r['ego_part']['note']}.", "",
        f"Moving objects: {r['moving_note']}.", "",
        f"| part | within {r['coverage_within_m']} m of the mesh | point-to-mesh median (m) | p95 (m) |",
        "|---|---:|---:|---:|",
        *[f"| {p} | {c[p]:.3f} | {d[p]['median']:.3f} | {d[p]['p95']:.3f} |" for p in ("calibration", "heldout")],
        "", f"Mesh: {r['mesh']['triangles']} triangles; mesh-to-points distance (triangle centroids to the "
        f"nearest static calibration point) median {m['median']:.3f} m, p95 {m['p95']:.3f} m.",
        f"Reflectivity: median {r['reflectivity']['median']:.3f}, points clipped high "
        f"{r['reflectivity']['clipped_high']:.3f}, low {r['reflectivity']['clipped_low']:.3f}.", "",
        "Time (s): " + ", ".join(f"{k} {v}" for k, v in r["time_s"].items()), "",
    ])  # fmt: skip
