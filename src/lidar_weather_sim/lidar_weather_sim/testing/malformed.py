"""Seeded malformed PointCloud2 and nav_msgs/Odometry messages, for robustness tests and scripts (no ROS import).

Each generator takes a good message, a ``numpy.random.Generator`` and a
``copy`` function that deep-copies a message of the caller's binding (rclpy
or rosbags), and returns ``(cause, message)`` with ``cause`` one of the kinds
below. Same seed, same messages.

PointCloud2 kinds: random field tables (unknown datatypes, zero counts,
offsets past ``point_step``, duplicated or missing x/y/z, vector x), truncated
or padded data, NaN/inf coordinates, absurd sizes (width, height, point_step,
row_step near 2^32), big-endian flag; and clouds the decoder accepts but no filter can use: a
channel turned signed and negative or beyond any ring count, a point 3e38 m away. Odometry kinds: NaN or infinite pose,
zero quaternion, wrong frame ids, stamps far in the future or the past, a
position kilometres away.
"""

from __future__ import annotations

from typing import Any, Callable

import numpy as np

from lidar_weather_sim.io.cloud_codec import DATATYPE_TO_DTYPE

CLOUD_KINDS = ("field_table", "truncated", "padded", "nonfinite", "absurd_size", "big_endian", "vector_xyz",
               "bad_channel", "far_point")  # fmt: skip
#: Kinds the decoder accepts (valid PointCloud2) that the filters must refuse or set aside.
DECODABLE_KINDS = ("bad_channel", "far_point")
ODOMETRY_KINDS = ("nan_pose", "inf_orientation", "zero_quaternion", "wrong_frame", "future_stamp", "past_stamp",
                  "teleport")  # fmt: skip
U32_MAX = 2**32 - 1
_NAMES = ("x", "y", "z", "intensity", "epw", "echo", "label", "", "x ", "ring", "\u00e9", "t" * 40)


def _set_stamp_ns(header, ns: int) -> None:
    header.stamp.sec, header.stamp.nanosec = divmod(max(0, int(ns)), 1_000_000_000)


def _stamp_ns(header) -> int:
    return int(header.stamp.sec) * 1_000_000_000 + int(header.stamp.nanosec)


def malformed_cloud(good: Any, rng: np.random.Generator, copy: Callable[[Any], Any],
                    field_type: Callable[..., Any], kind: str | None = None) -> tuple[str, Any]:  # fmt: skip
    """A malformed copy of the PointCloud2 ``good``; ``field_type`` builds a PointField (name, offset, datatype, count)."""
    kind = kind or str(rng.choice(CLOUD_KINDS))
    msg = copy(good)
    data = bytes(good.data)
    if kind == "field_table":
        n = int(rng.integers(0, 6))
        msg.fields = [
            field_type(name=str(rng.choice(_NAMES)), offset=int(rng.integers(0, msg.point_step + 9)),
                       datatype=int(rng.integers(0, 11)), count=int(rng.integers(0, 4)))  # fmt: skip
            for _ in range(n)
        ]
    elif kind == "truncated":
        msg.data = data[: int(rng.integers(0, max(1, len(data))))]
    elif kind == "padded":
        msg.data = data + bytes(int(rng.integers(1, 64)))
    elif kind == "nonfinite":
        points = np.frombuffer(data, dtype=np.uint8).copy()
        x = next(f for f in good.fields if f.name == "x")
        step, n = int(good.point_step), int(good.width) * int(good.height)
        rows = rng.choice(n, size=max(1, n // 10), replace=False) if n else np.zeros(0, int)
        bad = np.array([np.nan, np.inf, -np.inf], dtype=DATATYPE_TO_DTYPE[int(x.datatype)])
        for i, value in enumerate(rng.choice(bad, size=len(rows))):
            start = int(rows[i]) * step + int(x.offset)
            points[start : start + bad.itemsize] = np.frombuffer(value.tobytes(), dtype=np.uint8)
        msg.data = points.tobytes()
    elif kind == "absurd_size":
        which = str(rng.choice(["width", "height", "point_step", "row_step"]))
        # width 0 is left out: with row_step and data unchanged it is a valid empty cloud (all row padding)
        sizes = [U32_MAX, U32_MAX // 2, 2**31] if which == "width" else [0, U32_MAX, U32_MAX // 2, 2**31]
        setattr(msg, which, int(rng.choice(sizes)))
    elif kind == "big_endian":
        msg.is_bigendian = True
    elif kind == "vector_xyz":
        x = next(f for f in msg.fields if f.name == "x")
        x.count = 3
    elif kind in ("bad_channel", "far_point"):
        name = "channel" if kind == "bad_channel" else "x"
        field = next((f for f in msg.fields if f.name == name), None)
        n = int(good.width) * int(good.height)
        if field is not None and n:
            if kind == "bad_channel" and DATATYPE_TO_DTYPE[int(field.datatype)].kind == "u":
                field.datatype = int(field.datatype) - 1  # the signed type of the same size: high values turn negative
            dtype = DATATYPE_TO_DTYPE[int(field.datatype)]
            value = np.array(-1 if kind == "bad_channel" and dtype.kind == "i" else
                             np.iinfo(dtype).max if dtype.kind in "iu" else 3e38, dtype=dtype)  # fmt: skip
            points = np.frombuffer(data, dtype=np.uint8).copy()
            for row in rng.choice(n, size=max(1, n // 100), replace=False):
                start = int(row) * int(good.point_step) + int(field.offset)
                points[start : start + dtype.itemsize] = np.frombuffer(value.tobytes(), dtype=np.uint8)
            msg.data = points.tobytes()
    else:
        raise ValueError(f"unknown malformed cloud kind {kind!r}; kinds: {', '.join(CLOUD_KINDS)}")
    return kind, msg


def malformed_odometry(good: Any, rng: np.random.Generator, copy: Callable[[Any], Any],
                       kind: str | None = None) -> tuple[str, Any]:  # fmt: skip
    """A malformed copy of the nav_msgs/Odometry ``good`` (stamps in ns of its header)."""
    kind = kind or str(rng.choice(ODOMETRY_KINDS))
    msg = copy(good)
    pose = msg.pose.pose
    if kind == "nan_pose":
        setattr(pose.position, str(rng.choice(["x", "y", "z"])), float("nan"))
    elif kind == "inf_orientation":
        setattr(pose.orientation, str(rng.choice(["x", "y", "z", "w"])), float("inf"))
    elif kind == "zero_quaternion":
        o = pose.orientation
        o.x = o.y = o.z = o.w = 0.0
    elif kind == "wrong_frame":
        msg.header.frame_id = str(rng.choice(["world", "base_link", "utm"]))
    elif kind == "future_stamp":
        _set_stamp_ns(msg.header, _stamp_ns(good.header) + int(rng.integers(2, 10**6)) * 1_000_000_000)
    elif kind == "past_stamp":
        _set_stamp_ns(msg.header, _stamp_ns(good.header) - int(rng.integers(2, 10**6)) * 1_000_000_000)
    elif kind == "teleport":
        pose.position.x += float(rng.choice([-1, 1]) * rng.uniform(1e3, 1e7))
    else:
        raise ValueError(f"unknown malformed odometry kind {kind!r}; kinds: {', '.join(ODOMETRY_KINDS)}")
    return kind, msg
