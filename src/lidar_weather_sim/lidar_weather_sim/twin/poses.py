"""Sensor poses of a recording's frames for its twin: recorded, from KISS-ICP, or the identity.

- **recorded**: the bag's ``/tf`` (or odometry with the mount on ``/tf_static``): the sensor frame in the
  tree's root (``map``, REP-105) at every point's firing time (rolling shutter), as ``gap`` re-simulates.
- **kiss-icp**: without poses, KISS-ICP 1.3.0 (Vizzo et al. 2023; its Python API ``KissICP`` with a
  ``KISSConfig``, not its CLI) registers the clouds in stamp order, deskewing each with its point times
  (normalised to 0-1); its pose of a frame is the sensor at the frame's last point time (KISS-ICP 1.x
  deskews to the end of the scan), at the middle for the first two frames (not deskewed: no motion yet). The first frame defines
  ``map``. Between frames poses are interpolated (:class:`KeyframeTrack`). When any frame's point times are
  all equal (a driver without per-point time) no frame is deskewed and each pose is the frame's stamp:
  KISS-ICP's own normalisation would divide by a zero span and abort the process. Every frame is checked
  before it is handed over (finite points, at least :data:`MIN_ICP_POINTS` within range) and every pose
  after: a frame KISS-ICP cannot take is a ValueError naming it, never a native abort.
- **identity**: a single frame without poses: ``map`` is its sensor frame.

Units: s (simulated time, counted from the bag's start as :class:`~lidar_weather_sim.io.recording.Recording`
counts it), m, quaternions x, y, z, w.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation, Slerp

from lidar_weather_sim.core.geometry import quaternion_matrices
from lidar_weather_sim.io.recording import Recording


class KeyframeTrack:
    """A PoseSource of sensor poses (map frame) between keyframes: translation linear, rotation slerp,
    held before the first and after the last keyframe; no actors."""

    def __init__(self, times_s: np.ndarray, poses: np.ndarray) -> None:
        order = np.argsort(times_s)
        self.times = np.asarray(times_s, dtype=np.float64)[order]
        self.poses = np.asarray(poses, dtype=np.float64)[order]  # (F, 4, 4) sensor -> map
        self._rotations = Rotation.from_matrix(self.poses[:, :3, :3])
        self._slerp = Slerp(self.times, self._rotations) if len(self.times) > 1 else None

    def sensor_poses(self, times_s) -> tuple[np.ndarray, np.ndarray]:
        t = np.clip(np.atleast_1d(np.asarray(times_s, dtype=np.float64)), self.times[0], self.times[-1])
        if self._slerp is None:
            return np.tile(self.poses[0, :3, 3], (len(t), 1)), np.tile(self._rotations.as_quat(), (len(t), 1))
        xyz = np.stack([np.interp(t, self.times, self.poses[:, k, 3]) for k in range(3)], axis=-1)
        return xyz, self._slerp(t).as_quat()

    def actor_poses(self, time_s: float) -> dict[int, np.ndarray]:
        return {}


@dataclass
class TwinPoses:
    """Where the poses come from and a PoseSource (``sensor_poses(times_s)``) over the recording."""

    source: str  # "recorded", "kiss-icp" or "identity"
    track: object
    deskewed: bool = True  # False: KISS-ICP took the frames as they were (point times constant)

    def frame_pose(self, time_s: float) -> np.ndarray:
        """4x4 sensor -> map at ``time_s`` (s)."""
        t, q = self.track.sensor_poses(np.array([time_s]))
        out = np.eye(4)
        out[:3, :3], out[:3, 3] = quaternion_matrices(q)[0], t[0]
        return out


def point_times_s(recording: Recording, index: int) -> np.ndarray:
    """Firing time (s, recording time) of every point of frame ``index``."""
    frame = recording.frames[index]
    return recording.time_s(frame.stamp_ns) + frame.points["time_stamp"].astype(np.float64) * 1e-9


def points_in_map(recording: Recording, index: int, poses: TwinPoses) -> tuple[np.ndarray, np.ndarray]:
    """Points of frame ``index`` in the map frame (N, 3) m and the sensor origin of each (N, 3) m, each
    point placed with the pose of its own firing time (one pose lookup per distinct time)."""
    p = recording.frames[index].points
    xyz = np.stack([p["x"], p["y"], p["z"]], axis=-1).astype(np.float64)
    times, inverse = np.unique(point_times_s(recording, index), return_inverse=True)
    translation, quaternion = poses.track.sensor_poses(times)
    rotation = quaternion_matrices(np.ascontiguousarray(quaternion, dtype=np.float64))
    return np.einsum("nij,nj->ni", rotation[inverse], xyz) + translation[inverse], translation[inverse]


MIN_ICP_POINTS = 100  # points within KISS-ICP's range gate a frame needs


def _icp_input(recording: Recording, index: int, min_range_m: float, max_range_m: float) -> np.ndarray:
    """Frame ``index``'s points (N, 3) m, checked for KISS-ICP: finite, enough of them within range."""
    p = recording.frames[index].points
    xyz = np.stack([p["x"], p["y"], p["z"]], axis=-1).astype(np.float64)
    if not np.isfinite(xyz).all():
        raise ValueError(f"{recording.path}: frame {index} has non-finite x, y or z: not handed to KISS-ICP")
    r = np.linalg.norm(xyz, axis=1)
    inside = int(np.count_nonzero((r >= min_range_m) & (r <= max_range_m)))
    if inside < MIN_ICP_POINTS:
        raise ValueError(f"{recording.path}: frame {index} has {inside} points within {min_range_m:g}-{max_range_m:g} m, "
                         f"fewer than the {MIN_ICP_POINTS} KISS-ICP needs to register it")  # fmt: skip
    return xyz


def kiss_icp_track(recording: Recording, max_range_m: float = 100.0,
                   voxel_size_m: float | None = None) -> tuple[KeyframeTrack, bool]:  # fmt: skip
    """KISS-ICP odometry over every frame (stamp order): a :class:`KeyframeTrack` of the sensor at the end of
    each frame's point times (at the stamp when not deskewed), the first frame's sensor frame as ``map``, and
    whether the frames were deskewed (module doc). ``voxel_size_m`` default: KISS-ICP's (max range / 100)."""
    from kiss_icp.config import KISSConfig
    from kiss_icp.kiss_icp import KissICP

    config = KISSConfig()
    config.data.max_range = float(max_range_m)
    config.data.min_range = 0.5  # the vehicle's own body
    config.mapping.voxel_size = float(voxel_size_m or max_range_m / 100.0)
    config.registration.max_num_threads = 2
    spans = [float(np.ptp(f.points["time_stamp"])) if len(f.points) else 0.0 for f in recording.frames]
    config.data.deskew = deskew = min(spans, default=0.0) > 0
    odometry = KissICP(config)
    times, poses = [], []
    for i, frame in enumerate(recording.frames):
        xyz = _icp_input(recording, i, config.data.min_range, config.data.max_range)
        stamps = point_times_s(recording, i)
        span = float(np.ptp(stamps))
        odometry.register_frame(xyz, (stamps - stamps.min()) / span if deskew else np.zeros(len(stamps)))  # 0-1
        # KISS-ICP 1.x deskews to the scan's end with the last frame-to-frame motion, which is unknown (the
        # identity) for the first two frames: those stay raw and their poses are the scan's middle
        at_end = deskew and i >= 2
        times.append(stamps.max() if at_end else 0.5 * (stamps.min() + stamps.max()))
        pose = np.array(odometry.last_pose, dtype=np.float64)
        if not np.isfinite(pose).all():
            raise ValueError(f"{recording.path}: KISS-ICP lost track at frame {i} (non-finite pose)")
        poses.append(pose)
    return KeyframeTrack(np.array(times), np.array(poses)), deskew


def twin_poses(recording: Recording, max_range_m: float = 100.0) -> TwinPoses:
    """The recording's poses if it has them, else KISS-ICP's (several frames) or the identity (one frame)."""
    if recording.has_poses:
        return TwinPoses("recorded", recording.pose_source())
    if len(recording.frames) == 1:
        return TwinPoses("identity", KeyframeTrack(np.zeros(1), np.eye(4)[None]))
    track, deskewed = kiss_icp_track(recording, max_range_m)
    return TwinPoses("kiss-icp", track, deskewed)
