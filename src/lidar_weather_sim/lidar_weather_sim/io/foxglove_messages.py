"""Foxglove messages of the project's clouds, transforms and actors (the live view of ``foxglove_bridge_node``).

Pure conversion with the ``foxglove-sdk`` message classes (``foxglove.messages``), no ROS import:
the node hands in decoded clouds (:mod:`lidar_weather_sim.core.points` structured arrays, or any
structured array with x, y, z) and tf2_msgs/TFMessage objects (rclpy or rosbags, read by attribute,
as :meth:`~lidar_weather_sim.poses.tf_buffer.TransformBuffer.add_tf_message` does).

- :func:`point_cloud`: a ``foxglove.PointCloud`` whose data are the array's bytes as they are
  (one ``tobytes``, no per-point work), described field by field: coordinates in m in the cloud's
  own frame (``frame_id``, e.g. ``lidar``), every other field with its stored type.
- :func:`frame_transforms`: a ``foxglove.FrameTransforms`` of a TFMessage (translations in m,
  rotations as unit quaternions x, y, z, w; each child frame in its parent frame).
- :func:`actor_scene`: a ``foxglove.SceneUpdate`` with one box per actor, drawn in the actor's own
  frame ``actor_<id>`` (body origin: centre of the footprint on the road, x forward; REP-103), so
  Foxglove moves the box with that frame's /tf.

Times are integer nanoseconds (ROS time: simulated time under ``use_sim_time``).
"""

from __future__ import annotations

import math
import re
from collections.abc import Iterable, Mapping

import numpy as np
from foxglove.messages import (
    Color,
    CubePrimitive,
    Duration,
    FrameTransform,
    FrameTransforms,
    PackedElementField,
    PackedElementFieldNumericType,
    PointCloud,
    Pose,
    Quaternion,
    SceneEntity,
    SceneUpdate,
    TextPrimitive,
    Timestamp,
    Vector3,
)

from lidar_weather_sim.core.names import actor_frame

#: numpy dtype (little-endian) -> Foxglove PackedElementField numeric type; other types are not sent.
NUMERIC_TYPES = {
    np.dtype("<u1"): PackedElementFieldNumericType.Uint8,
    np.dtype("<i1"): PackedElementFieldNumericType.Int8,
    np.dtype("<u2"): PackedElementFieldNumericType.Uint16,
    np.dtype("<i2"): PackedElementFieldNumericType.Int16,
    np.dtype("<u4"): PackedElementFieldNumericType.Uint32,
    np.dtype("<i4"): PackedElementFieldNumericType.Int32,
    np.dtype("<f4"): PackedElementFieldNumericType.Float32,
    np.dtype("<f8"): PackedElementFieldNumericType.Float64,
}
#: A vehicle's box when its size is unknown: length, width, height (m), the scenario schema's defaults.
DEFAULT_ACTOR_SIZE_M = (4.7, 1.85, 1.45)
ACTOR_COLOR = (1.0, 0.55, 0.0, 0.5)  # r, g, b, alpha in 0..1: translucent orange
_ACTOR_FRAME = re.compile(r"^/?actor_(\d+)$")
_IDENTITY = Pose(position=Vector3(x=0.0, y=0.0, z=0.0), orientation=Quaternion(x=0.0, y=0.0, z=0.0, w=1.0))


def timestamp(stamp_ns: int) -> Timestamp:
    """Foxglove timestamp of ``stamp_ns`` (ns, >= 0)."""
    sec, nsec = divmod(int(stamp_ns), 1_000_000_000)
    if sec < 0:
        raise ValueError(f"stamp {stamp_ns} ns is before 0")
    return Timestamp(sec, nsec)


def _sendable(points: np.ndarray) -> np.ndarray:
    """``points`` as a C-contiguous little-endian structured array of the fields Foxglove can describe.

    The project's clouds pass unchanged; otherwise the describable fields are copied field by field
    (one vectorised copy per field, little-endian), and fields of other types (int64, bool, sub-arrays,
    nested records) are left out.
    """
    if points.dtype.names is None:
        raise ValueError(f"a point cloud must be a structured array, not {points.dtype}")
    fields = points.dtype.fields
    describable = [n for n in points.dtype.names if fields[n][0].newbyteorder("<") in NUMERIC_TYPES]
    missing = [n for n in ("x", "y", "z") if n not in describable]
    if missing:
        raise ValueError(f"cloud lacks numeric field(s) {', '.join(missing)}: Foxglove needs x, y and z")
    if all(fields[n][0] in NUMERIC_TYPES for n in points.dtype.names) and points.flags.c_contiguous:
        return points  # the project's clouds: sent as they are
    out = np.empty(len(points), np.dtype({"names": describable,
                                          "formats": [fields[n][0].newbyteorder("<") for n in describable]}))  # fmt: skip
    for n in describable:
        out[n] = points[n]
    return out


def point_cloud(points: np.ndarray, stamp_ns: int, frame_id: str) -> PointCloud:
    """A ``foxglove.PointCloud`` of ``points`` (x, y, z in m in ``frame_id``), stamped ``stamp_ns`` (ns).

    Every field of a supported numeric type is described at its byte offset; the point stride is the
    array's item size. Raises ValueError for an array without numeric x, y and z.
    """
    pts = _sendable(points)
    fields = [PackedElementField(name=name, offset=int(pts.dtype.fields[name][1]),
                                 type=NUMERIC_TYPES[pts.dtype.fields[name][0].newbyteorder("<")])
              for name in pts.dtype.names]  # fmt: skip
    return PointCloud(timestamp=timestamp(stamp_ns), frame_id=frame_id, pose=_IDENTITY,
                      point_stride=int(pts.dtype.itemsize), fields=fields, data=pts.tobytes())  # fmt: skip


def _stamp_ns(stamp) -> int:
    return int(stamp.sec) * 1_000_000_000 + int(stamp.nanosec)


def frame_transforms(msg) -> tuple[FrameTransforms, int, list[str]]:
    """A TFMessage as ``foxglove.FrameTransforms``: (message, latest stamp in ns, one reason per skipped transform).

    A transform with an empty frame name, a non-finite value or a zero quaternion is skipped (the
    others are kept); quaternions are normalised. Frame names lose a leading ``/`` (tf2's rule).
    """
    out, rejected, latest = [], [], 0
    for ts in msg.transforms:
        parent, child = ts.header.frame_id.lstrip("/"), ts.child_frame_id.lstrip("/")
        tr, rot = ts.transform.translation, ts.transform.rotation
        t = (float(tr.x), float(tr.y), float(tr.z))
        q = np.array([rot.x, rot.y, rot.z, rot.w], dtype=np.float64)
        norm = float(np.linalg.norm(q))
        if not parent or not child:
            rejected.append(f"'{parent}' -> '{child}': empty frame name")
            continue
        if not all(map(math.isfinite, t)) or not np.isfinite(q).all() or norm < 1e-9:
            rejected.append(f"{parent} -> {child}: non-finite translation or rotation, or a zero quaternion")
            continue
        try:
            stamp = _stamp_ns(ts.header.stamp)
            when = timestamp(stamp)
        except (ValueError, OverflowError) as exc:
            rejected.append(f"{parent} -> {child}: {exc}")
            continue
        q /= norm
        latest = max(latest, stamp)
        out.append(FrameTransform(timestamp=when, parent_frame_id=parent, child_frame_id=child,
                                  translation=Vector3(x=t[0], y=t[1], z=t[2]),
                                  rotation=Quaternion(x=float(q[0]), y=float(q[1]), z=float(q[2]), w=float(q[3]))))  # fmt: skip
    return FrameTransforms(transforms=out), latest, rejected


def actor_ids(msg) -> list[int]:
    """Ids of the actors whose frame ``actor_<id>`` is a child frame in a TFMessage, in message order."""
    ids = []
    for ts in msg.transforms:
        m = _ACTOR_FRAME.match(ts.child_frame_id)
        if m and int(m.group(1)) not in ids:
            ids.append(int(m.group(1)))
    return ids


def actor_scene(ids: Iterable[int], stamp_ns: int, sizes_m: Mapping[int, tuple[float, float, float]] | None = None,
                lifetime_s: float = 0.0) -> SceneUpdate:  # fmt: skip
    """A ``foxglove.SceneUpdate``: per actor a box (length x width x height in m, from ``sizes_m`` or
    :data:`DEFAULT_ACTOR_SIZE_M`) standing on the footprint centre of frame ``actor_<id>``, and its name above.

    The entities are frame-locked (they follow the frame's /tf) and expire ``lifetime_s`` s after
    ``stamp_ns`` (0: never); entity ids are the frame names, so a later update replaces them.
    """
    sizes_m = sizes_m or {}
    color = Color(r=ACTOR_COLOR[0], g=ACTOR_COLOR[1], b=ACTOR_COLOR[2], a=ACTOR_COLOR[3])
    label = Color(r=1.0, g=1.0, b=1.0, a=1.0)
    entities = []
    for i in ids:
        length, width, height = sizes_m.get(int(i), DEFAULT_ACTOR_SIZE_M)
        frame = actor_frame(int(i))
        box = CubePrimitive(pose=Pose(position=Vector3(x=0.0, y=0.0, z=0.5 * height), orientation=Quaternion(w=1.0)),
                            size=Vector3(x=length, y=width, z=height), color=color)  # fmt: skip
        text = TextPrimitive(pose=Pose(position=Vector3(x=0.0, y=0.0, z=height + 0.5), orientation=Quaternion(w=1.0)),
                             billboard=True, font_size=14.0, scale_invariant=True, color=label, text=frame)  # fmt: skip
        entities.append(SceneEntity(timestamp=timestamp(stamp_ns), frame_id=frame, id=frame, frame_locked=True,
                                    lifetime=Duration.from_secs(lifetime_s) if lifetime_s > 0 else None,
                                    cubes=[box], texts=[text]))  # fmt: skip
    return SceneUpdate(entities=entities)
