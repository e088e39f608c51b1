"""The real OS1-128 street recording of the ouster-sdk 1.0.1 sdist as a rosbag2 and a static mesh.

Source (``sdk/tests`` of the sdist ``ouster_sdk-1.0.1.tar.gz``; no ROS needed):
``pcaps/OS-1-128_v2.3.0_1024x10_lb_n3.pcap`` (UDP lidar and IMU packets; "lb":
the low-bandwidth profile RNG15_RFL8_NIR8, "n3": three complete scans),
``pcaps/OS-1-128_v2.3.0_1024x10.json`` (the metadata of that sensor session:
the packets carry its serial number and init id, which are checked),
``pcaps/..._lb_n3_poses_kitti.txt`` (one KITTI 3x4 pose per scan) and
``osfs/..._lb_n3_map-000.ply`` (Ouster's SLAM map of the street: 155 000 points,
*no faces*).

Conventions, found by aligning the scans with the mesh of that map (median
point-to-mesh distance per scan, every column placed with its own pose): a
KITTI pose maps points of Ouster's *sensor* frame (this project's ``lidar``
frame, REP-103) into ``map`` (the sensor frame of the first scan): 1.1-1.3 cm,
against 4.9 and 7.8 cm for scans 2 and 3 with the inverse poses and 1.2 m in
Ouster's lidar frame. It is the pose at the scan's middle column, as ouster-sdk's
``pose_frames_from_kitti`` assumes (at the scan start: 1.5-2.1 cm, at the end:
1.3-1.5 cm). Cast again from the same poses, the mesh misses 8-9 % of the beams
that returned (gaps in the map at 10-55 m), and 18-20 % of the beams without a
return hit it (mostly road where the sensor saw nothing).

What is written:

- ``/lidar/points``: one unorganised cloud per scan in ``lidar``, stamped with
  the sensor-clock time (ns since the sensor booted, as in the packets) of the
  scan's first column, logged at its last column; per point ``time_stamp`` is
  the column's firing time after that stamp. ``intensity`` is Ouster's 8-bit
  calibrated reflectivity, ``return_type`` 3 (Nebula STRONGEST: the profile's
  single return), ``echo`` 1. The layout is :data:`points.POINT_DTYPE_NO_EPW`:
  the sensor measures no EPW and there is no ground truth, so ``epw``,
  ``label`` and ``object_id`` are absent (not zero), which sends the weather
  filters to their intensity/geometry fallbacks instead of trusting fake EPWs.
- ``/tf`` (map -> base_link) and ``/clock`` every 10 ms over the recording, the
  KITTI poses interpolated (translation linear, rotation slerp) and extrapolated
  at constant velocity beyond the first and last middle column; ``/tf_static``
  base_link -> lidar is the identity (the recording's vehicle frame is unknown,
  so base_link is the sensor frame).
- The street mesh (PLY, map frame, m): ball-pivoting reconstruction of the map
  points (radii :data:`BALL_RADII` times their mean spacing), which loads with
  :func:`lidar_weather_sim.scene.scene.load_static_mesh`.
"""

from __future__ import annotations

import io
import json
import tarfile
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from lidar_weather_sim.core.geometry import pose_transform
from lidar_weather_sim.core.names import (
    FRAME_BASE_LINK,
    FRAME_LIDAR,
    FRAME_MAP,
    TOPIC_CLOCK,
    TOPIC_POINTS,
    TOPIC_TF,
    TOPIC_TF_STATIC,
)
from lidar_weather_sim.core.points import POINT_DTYPE_NO_EPW, ReturnType, fill_polar
from lidar_weather_sim.io.bags import BagWriter, clock_message, tf_message
from lidar_weather_sim.io.ouster_pcap import (
    OusterFormatError,
    OusterMetadata,
    Scan,
    decode_scans,
    lidar_payloads,
    xyz_lut,
)

SDIST_NAME = "ouster_sdk-1.0.1.tar.gz"
_BASE = "sdk/tests/pcaps/OS-1-128_v2.3.0_1024x10"
MEMBERS = {
    "pcap": f"{_BASE}_lb_n3.pcap",
    "metadata": f"{_BASE}.json",
    "poses": f"{_BASE}_lb_n3_poses_kitti.txt",
    "map": "sdk/tests/osfs/OS-1-128_v2.3.0_1024x10_lb_n3_map-000.ply",
}
TF_STEP_NS = 10_000_000  # /tf and /clock every 10 ms, as `lidar-weather-sim run`
BALL_RADII = (1.5, 3.0, 6.0, 12.0)  # ball-pivoting radii in units of the map's mean point spacing


@dataclass(frozen=True)
class OusterRecording:
    """Decoded scans, their poses (sensor -> map, 4x4, m) at ``pose_ns`` and the map points (M, 3) m."""

    meta: OusterMetadata
    scans: list[Scan]
    poses: np.ndarray
    map_points: np.ndarray

    @property
    def pose_ns(self) -> np.ndarray:
        """Time of each pose: the scan's middle column (ns, sensor clock)."""
        return np.array([s.timestamp_ns[len(s.timestamp_ns) // 2] for s in self.scans], dtype=np.int64)

    def points(self, index: int) -> np.ndarray:
        """Points of scan ``index`` in the ``lidar`` frame, in firing order (see the module docstring)."""
        scan = self.scans[index]
        direction, offset = xyz_lut(self.meta)
        valid = scan.range_mm.T > 0  # (W, H): column by column
        r = scan.range_mm.T[valid] * 1e-3
        xyz = r[:, None] * direction.transpose(1, 0, 2)[valid] + offset.transpose(1, 0, 2)[valid]
        channel = np.argsort(np.argsort(self.meta.altitude_deg, kind="stable"), kind="stable")  # 0 = lowest
        pts = np.zeros(len(r), POINT_DTYPE_NO_EPW)
        pts["x"], pts["y"], pts["z"] = xyz.T
        pts["intensity"] = scan.reflectivity.T[valid]
        pts["return_type"] = ReturnType.STRONGEST
        pts["channel"] = np.broadcast_to(channel, valid.shape)[valid]
        pts["time_stamp"] = np.broadcast_to((scan.timestamp_ns - scan.timestamp_ns[0])[:, None], valid.shape)[valid]
        pts["echo"] = 1
        fill_polar(pts)
        return pts

    def sensor_poses(self, stamps_ns: np.ndarray) -> np.ndarray:
        """(N, 4, 4) sensor -> map at ``stamps_ns`` (interpolated, extrapolated at the ends)."""
        return interpolate_poses(self.pose_ns, self.poses, np.asarray(stamps_ns, dtype=np.int64))


def default_sdist() -> Path:
    """``.venv/cache/ouster_sdk-1.0.1.tar.gz`` of the workspace (downloaded by scripts/setup.sh)."""
    from lidar_weather_sim.core.paths import config_dir

    return config_dir().parent / ".venv" / "cache" / SDIST_NAME


def load_recording(sdist: str | Path) -> OusterRecording:
    """Read and decode the recording from the sdist; errors name the sdist and member."""
    sdist = Path(sdist)
    if not sdist.is_file():
        raise FileNotFoundError(f"{sdist}: no such file (scripts/setup.sh downloads the ouster-sdk 1.0.1 sdist)")
    data = _read_members(sdist)
    source = {key: f"{sdist}:{name}" for key, name in MEMBERS.items()}
    try:
        meta = OusterMetadata.from_json(json.loads(data["metadata"]), source["metadata"])
    except json.JSONDecodeError as err:
        raise OusterFormatError(f"{source['metadata']}: not JSON: {err}") from None
    scans = decode_scans(lidar_payloads(data["pcap"], meta, source["pcap"]), meta)
    try:
        kitti = np.loadtxt(io.BytesIO(data["poses"]), ndmin=2)
    except ValueError as err:
        raise OusterFormatError(f"{source['poses']}: not KITTI poses: {err}") from None
    if kitti.shape != (len(scans), 12):
        raise OusterFormatError(f"{source['poses']}: {kitti.shape[0]} poses of {kitti.shape[1]} values "
                                f"for {len(scans)} complete scans in {source['pcap']} (need 12 values per scan)")  # fmt: skip
    poses = np.tile(np.eye(4), (len(scans), 1, 1))
    poses[:, :3, :] = kitti.reshape(-1, 3, 4)
    return OusterRecording(meta, scans, poses, _ply_points(data["map"], source["map"]))


def _read_members(sdist: Path) -> dict[str, bytes]:
    try:
        with tarfile.open(sdist) as tar:
            found = {m.name.split("/", 1)[-1]: m for m in tar.getmembers() if m.isfile()}
            missing = [name for name in MEMBERS.values() if name not in found]
            if missing:
                raise OusterFormatError(f"{sdist}: no {', '.join(missing)} in the archive")
            return {key: tar.extractfile(found[name]).read() for key, name in MEMBERS.items()}
    except (tarfile.TarError, EOFError, OSError) as err:
        raise OusterFormatError(f"{sdist}: cannot read the archive: {err}") from None


def _ply_points(data: bytes, source: str) -> np.ndarray:
    import trimesh

    try:
        cloud = trimesh.load(io.BytesIO(data), file_type="ply", process=False)
    except Exception as err:  # trimesh raises many types for corrupt files
        raise OusterFormatError(f"{source}: cannot read PLY: {type(err).__name__}: {err}") from None
    vertices = np.asarray(getattr(cloud, "vertices", np.zeros((0, 3))), dtype=np.float64)
    if len(vertices) < 100:
        raise OusterFormatError(f"{source}: {len(vertices)} map points, too few for a mesh")
    return vertices


def interpolate_poses(key_ns: np.ndarray, poses: np.ndarray, stamps_ns: np.ndarray) -> np.ndarray:
    """(N, 4, 4) poses at ``stamps_ns`` from (K, 4, 4) ``poses`` at increasing ``key_ns``.

    Between keys the translation is linear and the rotation a slerp; before the
    first and after the last key the end segment is continued (constant velocity).
    """
    from scipy.spatial.transform import Rotation

    out = np.tile(np.eye(4), (len(stamps_ns), 1, 1))
    if len(poses) == 1:
        out[:] = poses[0]
        return out
    i = np.clip(np.searchsorted(key_ns, stamps_ns, side="right") - 1, 0, len(poses) - 2)
    u = (stamps_ns - key_ns[i]).astype(np.float64) / (key_ns[i + 1] - key_ns[i])
    rot = Rotation.from_matrix(poses[:, :3, :3])
    step = (rot[i].inv() * rot[i + 1]).as_rotvec()
    out[:, :3, :3] = (rot[i] * Rotation.from_rotvec(u[:, None] * step)).as_matrix()
    out[:, :3, 3] = poses[i, :3, 3] + u[:, None] * (poses[i + 1, :3, 3] - poses[i, :3, 3])
    return out


def street_mesh(map_points: np.ndarray, viewpoint: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Vertices (V, 3) m and triangles (T, 3) of a ball-pivoting surface through ``map_points``.

    Normals (for the pivoting) are estimated from 30 neighbours within 1 m and turned
    towards ``viewpoint`` (a sensor position, map frame).
    """
    import open3d as o3d

    cloud = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(np.asarray(map_points, dtype=np.float64)))
    cloud.estimate_normals(o3d.geometry.KDTreeSearchParamHybrid(radius=1.0, max_nn=30))
    cloud.orient_normals_towards_camera_location(np.asarray(viewpoint, dtype=np.float64))
    spacing = float(np.mean(np.asarray(cloud.compute_nearest_neighbor_distance())))
    radii = o3d.utility.DoubleVector([spacing * k for k in BALL_RADII])
    mesh = o3d.geometry.TriangleMesh.create_from_point_cloud_ball_pivoting(cloud, radii)
    mesh.remove_duplicated_triangles()
    mesh.remove_degenerate_triangles()
    mesh.remove_unreferenced_vertices()
    return np.asarray(mesh.vertices), np.asarray(mesh.triangles)


def frame_alignment(recording: OusterRecording, vertices: np.ndarray, triangles: np.ndarray) -> np.ndarray:
    """Median distance (m) of each scan's points to the mesh, every column placed with its own pose."""
    import open3d as o3d

    scene = o3d.t.geometry.RaycastingScene()
    scene.add_triangles(o3d.core.Tensor(vertices.astype(np.float32)), o3d.core.Tensor(triangles.astype(np.uint32)))
    medians = []
    for k, scan in enumerate(recording.scans):
        pts = recording.points(k)
        pose = recording.sensor_poses(scan.timestamp_ns[0] + pts["time_stamp"].astype(np.int64))
        xyz = np.column_stack([pts["x"], pts["y"], pts["z"]]).astype(np.float64)
        world = np.einsum("nij,nj->ni", pose[:, :3, :3], xyz) + pose[:, :3, 3]
        medians.append(float(np.median(scene.compute_distance(o3d.core.Tensor(world.astype(np.float32))).numpy())))
    return np.array(medians)


def write_bag(recording: OusterRecording, out: str | Path, overwrite: bool = False) -> list[int]:
    """Write the recording to the MCAP bag ``out``; returns the points per frame."""
    start = int(recording.scans[0].timestamp_ns[0])
    end = int(recording.scans[-1].timestamp_ns[-1])
    stamps = np.union1d(np.arange(start, end + TF_STEP_NS, TF_STEP_NS), recording.pose_ns)
    poses = recording.sensor_poses(stamps)
    clouds = [(int(s.timestamp_ns[-1]), k) for k, s in enumerate(recording.scans)]
    counts = []
    with BagWriter(out, overwrite=overwrite) as bag:
        bag.write(TOPIC_TF_STATIC, tf_message(start, [pose_transform(FRAME_BASE_LINK, FRAME_LIDAR, np.eye(4))]), start)
        for ns, pose in zip(stamps.tolist(), poses):
            while clouds and clouds[0][0] <= ns:
                log_ns, k = clouds.pop(0)
                points = recording.points(k)
                bag.write_cloud(TOPIC_POINTS, points, int(recording.scans[k].timestamp_ns[0]), FRAME_LIDAR, log_time_ns=log_ns)
                counts.append(len(points))
            bag.write(TOPIC_CLOCK, clock_message(ns), ns)
            bag.write(TOPIC_TF, tf_message(ns, [pose_transform(FRAME_MAP, FRAME_BASE_LINK, pose)]), ns)
    return counts


@dataclass(frozen=True)
class ImportReport:
    """What :func:`import_ouster` wrote: frames, points per frame, seconds covered, mesh size and
    the median point-to-mesh distance of each frame (m)."""

    bag: Path
    mesh: Path
    points_per_frame: list[int]
    duration_s: float
    triangles: int
    alignment_m: np.ndarray


def import_ouster(sdist: str | Path, out: str | Path, mesh_out: str | Path, overwrite: bool = False) -> ImportReport:
    """Convert the sdist's recording into the bag ``out`` and the street mesh ``mesh_out`` (PLY)."""
    import trimesh

    mesh_out = Path(mesh_out)
    for path in (Path(out), mesh_out):
        if path.exists() and not overwrite:
            raise FileExistsError(f"{path} already exists (--overwrite / overwrite=True replaces it)")
    recording = load_recording(sdist)
    vertices, triangles = street_mesh(recording.map_points, recording.poses[len(recording.poses) // 2, :3, 3])
    counts = write_bag(recording, out, overwrite)
    mesh_out.parent.mkdir(parents=True, exist_ok=True)
    trimesh.Trimesh(vertices, triangles, process=False).export(mesh_out)
    span_ns = recording.scans[-1].timestamp_ns[-1] - recording.scans[0].timestamp_ns[0]
    alignment = frame_alignment(recording, vertices, triangles)
    return ImportReport(Path(out), mesh_out, counts, float(span_ns) * 1e-9, len(triangles), alignment)
