"""Pose sources over a :class:`~lidar_weather_sim.poses.tf_buffer.TransformBuffer`: /tf, /tf_static, odometry.

A pose source gives the simulator the sensor pose in the fixed frame at every
firing time (rolling shutter) and the actor poses (see
:class:`lidar_weather_sim.sim.simulator.PoseSource`). Here the sensor pose comes
from a transform buffer fed with tf2_msgs/TFMessage (``/tf``, ``/tf_static``) or
with nav_msgs/Odometry (the pose of the base frame in the fixed frame) plus a
static mount base -> sensor (from ``/tf_static`` or from parameters).

Simulated time is seconds after ``time_origin_ns`` (the ROS stamp of simulated
time 0): float64 seconds since 1970 would lose the nanoseconds of the stamps.
Messages are duck-typed (rclpy or rosbags classes); no ROS import.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable
from typing import NamedTuple

import numpy as np

from lidar_weather_sim.core.geometry import matrix_quaternion, rpy_matrix
from lidar_weather_sim.poses.tf_buffer import Transform, TransformBuffer, TransformError

ActorPoses = Callable[[float], dict[int, np.ndarray]]


def stamp_ns(stamp) -> int:
    """builtin_interfaces/Time -> integer nanoseconds."""
    return int(stamp.sec) * 1_000_000_000 + int(stamp.nanosec)


class InputProblem(NamedTuple):
    """Why (part of) an input message was skipped: ``cause`` is stable (log it once), ``detail`` full."""

    cause: str
    detail: str


class TfPoseSource:
    """Sensor poses looked up in a transform buffer; actors from ``actors(time_s)`` (or none), or,
    with ``actor_frames`` ({actor id: frame}), from the buffer too (fixed_frame -> that frame: the
    body-to-fixed pose; an actor whose frame cannot be looked up at a time is absent then).

    ``buffer.lookup_many(fixed_frame, sensor_frame, stamps)`` maps points in the
    sensor frame into the fixed frame: it is the sensor's pose in the fixed frame.
    """

    def __init__(
        self,
        buffer: TransformBuffer,
        fixed_frame: str,
        sensor_frame: str,
        actors: ActorPoses | None = None,
        time_origin_ns: int = 0,
        actor_frames: dict[int, str] | None = None,
    ) -> None:
        self.buffer = buffer
        self.fixed_frame = fixed_frame
        self.sensor_frame = sensor_frame
        self.actors = actors
        self.time_origin_ns = int(time_origin_ns)
        self.actor_frames = dict(actor_frames or {})

    # -- time -----------------------------------------------------------------
    def to_stamp_ns(self, time_s) -> np.ndarray | int:
        """Simulated seconds -> ROS stamps (ns); arrays stay arrays."""
        ns = np.round(np.asarray(time_s, dtype=np.float64) * 1e9).astype(np.int64) + self.time_origin_ns
        return int(ns) if ns.ndim == 0 else ns

    def to_time_s(self, stamp: int) -> float:
        """ROS stamp (ns) -> simulated seconds."""
        return (int(stamp) - self.time_origin_ns) * 1e-9

    def ready_stamp_ns(self, candidates_ns: Iterable[int]) -> int | None:
        """The newest candidate stamp at which the sensor pose can be looked up, or None.

        Candidates are the stamps of the messages just received; with a buffer of
        zero extrapolation tolerance, the newest that resolves is the latest time
        the whole fixed -> sensor chain is known (tf2's latest common time).
        """
        for stamp in sorted(set(int(c) for c in candidates_ns), reverse=True):
            if self.buffer.can_transform(self.fixed_frame, self.sensor_frame, stamp):
                return stamp
        return None

    def why_not_ready(self, stamp: int) -> InputProblem | None:
        """The lookup error at ``stamp`` (None if the pose is available)."""
        try:
            self.buffer.lookup(self.fixed_frame, self.sensor_frame, stamp)
        except TransformError as exc:
            return InputProblem(f"{type(exc).__name__} {self.fixed_frame} -> {self.sensor_frame}", str(exc))
        return None

    # -- PoseSource -------------------------------------------------------------
    def sensor_poses(self, times_s: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Sensor in the fixed frame at each time: translations (N, 3) m, quaternions (N, 4) x, y, z, w."""
        stamps = np.atleast_1d(self.to_stamp_ns(times_s))
        return self.buffer.lookup_many(self.fixed_frame, self.sensor_frame, stamps)

    def actor_poses(self, time_s: float) -> dict[int, np.ndarray]:
        """Body-to-fixed 4x4 of the actors present at ``time_s`` (simulated s)."""
        if not self.actor_frames:
            return dict(self.actors(time_s)) if self.actors is not None else {}
        stamp, poses = self.to_stamp_ns(time_s), {}
        for actor_id, frame in self.actor_frames.items():
            try:
                poses[actor_id] = self.buffer.lookup(self.fixed_frame, frame, stamp).as_matrix()
            except TransformError:
                continue
        return poses


# -- /tf and /tf_static ---------------------------------------------------------
def add_tf_message(buffer: TransformBuffer, msg, static: bool = False) -> tuple[list[int], list[InputProblem]]:
    """Add a tf2_msgs/TFMessage; returns the stamps (ns) stored and one problem per skipped transform.

    Never raises on bad content: a message that is not a TFMessage at all is one problem.
    """
    stored, problems = [], []
    try:
        transforms = list(msg.transforms)
    except (AttributeError, TypeError) as exc:
        return [], [InputProblem("not a TFMessage", f"not a TFMessage: {exc}")]
    for ts in transforms:
        try:
            parent, child = str(ts.header.frame_id), str(ts.child_frame_id)
            st, tr, rot = stamp_ns(ts.header.stamp), ts.transform.translation, ts.transform.rotation
            buffer.set_transform(parent, child, st, (tr.x, tr.y, tr.z), (rot.x, rot.y, rot.z, rot.w), static)
        except (AttributeError, TypeError, ValueError) as exc:
            where = f"{getattr(getattr(ts, 'header', None), 'frame_id', '?')} -> {getattr(ts, 'child_frame_id', '?')}"
            kind = str(exc).split(":")[0] if isinstance(exc, ValueError) else type(exc).__name__
            problems.append(InputProblem(f"{where}: {kind}", f"{where}: {exc}"))
        else:
            stored.append(st)
    return stored, problems


# -- odometry plus a static mount -------------------------------------------------
def mount_transform(xyz_m: Iterable[float], rpy_deg: Iterable[float]) -> Transform:
    """Sensor-in-base transform from a position (m) and fixed-axis roll, pitch, yaw (deg, REP-103)."""
    xyz, rpy = np.asarray(list(xyz_m), dtype=np.float64), np.asarray(list(rpy_deg), dtype=np.float64)
    if xyz.shape != (3,) or rpy.shape != (3,):
        raise ValueError(f"mount needs 3 values each: xyz_m {xyz.tolist()}, rpy_deg {rpy.tolist()}")
    return Transform(xyz, matrix_quaternion(rpy_matrix(*np.deg2rad(rpy))))


def set_static_mount(buffer: TransformBuffer, base_frame: str, sensor_frame: str, mount: Transform) -> None:
    """Store base -> sensor as a static edge (a later /tf_static edge for the sensor replaces it)."""
    buffer.set_transform(base_frame, sensor_frame, 0, mount.translation, mount.rotation, static=True)


def parse_odometry(msg, fixed_frame: str, base_frame: str) -> tuple[int, Transform]:
    """Stamp (ns) and pose of the base frame in the fixed frame from a nav_msgs/Odometry.

    Empty ``header.frame_id`` / ``child_frame_id`` mean ``fixed_frame`` / ``base_frame``;
    other frame ids, non-finite values or a zero quaternion raise ValueError naming them.
    """
    try:
        frame, child = str(msg.header.frame_id).lstrip("/"), str(msg.child_frame_id).lstrip("/")
        st = stamp_ns(msg.header.stamp)
        p, q = msg.pose.pose.position, msg.pose.pose.orientation
        translation, rotation = (p.x, p.y, p.z), (q.x, q.y, q.z, q.w)
    except (AttributeError, TypeError) as exc:
        raise ValueError(f"not a nav_msgs/Odometry: {exc}") from None
    if frame not in ("", fixed_frame.lstrip("/")):
        raise ValueError(f"odometry frame_id '{frame}' is not the fixed frame '{fixed_frame}'")
    if child not in ("", base_frame.lstrip("/")):
        raise ValueError(f"odometry child_frame_id '{child}' is not the base frame '{base_frame}'")
    return st, Transform(translation, rotation)  # validates: finite, non-zero quaternion


def add_odometry(buffer: TransformBuffer, msg, fixed_frame: str, base_frame: str) -> int:
    """Store a nav_msgs/Odometry pose as the fixed -> base edge (:func:`parse_odometry`); returns its stamp (ns)."""
    st, pose = parse_odometry(msg, fixed_frame, base_frame)
    buffer.set_transform(fixed_frame, base_frame, st, pose.translation, pose.rotation)
    return st
