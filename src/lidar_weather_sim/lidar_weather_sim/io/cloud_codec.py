"""numpy structured arrays <-> sensor_msgs/PointCloud2, without ROS and without per-point loops.

Decoding reads clouds from any driver: a subset of fields, any field order,
padding between fields and at the end of rows, organised clouds (flattened
row-major). Bad clouds raise :class:`CloudFormatError` with a reason naming the
field or size at fault. Messages are duck-typed: rclpy's ``sensor_msgs.msg``
classes and rosbags' typestore classes both work (see :class:`MessageTypes`).
"""

from __future__ import annotations

import functools

import re
from dataclasses import dataclass
from typing import Any, Callable, Literal, Sequence

import numpy as np

#: sensor_msgs/PointField datatype codes.
INT8, UINT8, INT16, UINT16, INT32, UINT32, FLOAT32, FLOAT64 = range(1, 9)
DATATYPE_TO_DTYPE = {
    INT8: np.dtype("<i1"),
    UINT8: np.dtype("<u1"),
    INT16: np.dtype("<i2"),
    UINT16: np.dtype("<u2"),
    INT32: np.dtype("<i4"),
    UINT32: np.dtype("<u4"),
    FLOAT32: np.dtype("<f4"),
    FLOAT64: np.dtype("<f8"),
}
_KIND_SIZE_TO_DATATYPE = {(dt.kind, dt.itemsize): code for code, dt in DATATYPE_TO_DTYPE.items()}

NanPolicy = Literal["drop", "keep", "reject"]


class CloudFormatError(ValueError):
    """A PointCloud2 that cannot be decoded; the message names the field or size at fault."""

    @property
    def cause(self) -> str:
        """The message with its numbers blanked: one key per kind of fault (log once per cause)."""
        return re.sub(r"[-+]?\d+(\.\d+)?", "#", str(self))


@dataclass(frozen=True)
class FieldSpec:
    """One sensor_msgs/PointField: name, byte offset, datatype code, element count."""

    name: str
    offset: int
    datatype: int
    count: int = 1


@dataclass(frozen=True)
class DecodedCloud:
    """Points of a decoded cloud and the number of non-finite points dropped from it."""

    points: np.ndarray
    dropped_nonfinite: int


@dataclass(frozen=True)
class EncodedCloud:
    """The body of a PointCloud2 (height 1, little-endian)."""

    fields: tuple[FieldSpec, ...]
    point_step: int
    width: int
    data: bytes
    dropped_nonfinite: int

    @property
    def row_step(self) -> int:
        return self.point_step * self.width


def fields_from_dtype(dtype: np.dtype) -> tuple[FieldSpec, ...]:
    """PointField descriptions of a structured dtype (sub-arrays become ``count`` > 1)."""
    specs = []
    for name in dtype.names:
        field_dtype, offset = dtype.fields[name][:2]
        base, count = field_dtype, 1
        if field_dtype.subdtype is not None:
            base, shape = field_dtype.subdtype
            count = int(np.prod(shape))
        code = _KIND_SIZE_TO_DATATYPE.get((base.kind, base.itemsize))
        if code is None:
            raise CloudFormatError(f"field '{name}': dtype {base} has no PointField datatype")
        specs.append(FieldSpec(name, int(offset), code, count))
    return tuple(specs)


def dtype_from_fields(fields: Sequence[Any], point_step: int) -> np.dtype:
    """Structured dtype (with padding, itemsize ``point_step``) for PointField-like objects."""
    if point_step <= 0:
        raise CloudFormatError(f"point_step {point_step} must be positive")
    names, formats, offsets = [], [], []
    for field in fields:
        name = str(field.name)
        if name in names:
            raise CloudFormatError(f"field '{name}' appears twice")
        base = DATATYPE_TO_DTYPE.get(int(field.datatype))
        if base is None:
            raise CloudFormatError(f"field '{name}': unknown PointField datatype {field.datatype}")
        count = int(field.count)
        if count < 1:
            raise CloudFormatError(f"field '{name}': count {count} must be at least 1")
        end = int(field.offset) + base.itemsize * count
        if field.offset < 0 or end > point_step:
            raise CloudFormatError(
                f"field '{name}' spans bytes {field.offset}-{end}, beyond point_step {point_step}"
            )
        names.append(name)
        formats.append(base if count == 1 else np.dtype((base, (count,))))
        offsets.append(int(field.offset))
    spans = sorted((offset, offset + np.dtype(fmt).itemsize, name) for offset, fmt, name in zip(offsets, formats, names))
    for (_, end, first), (start, _, second) in zip(spans, spans[1:]):
        if start < end:  # numpy would read one field's bytes as part of another
            raise CloudFormatError(f"fields '{first}' and '{second}' overlap (bytes {start}-{end})")
    try:
        return np.dtype({"names": names, "formats": formats, "offsets": offsets, "itemsize": point_step})
    except (ValueError, TypeError) as exc:  # names numpy refuses, sizes past a C int
        raise CloudFormatError(f"fields {names} with point_step {point_step}: {exc}") from None


def nonfinite_mask(points: np.ndarray) -> np.ndarray:
    """True where x, y or z (those present) is NaN or infinite."""
    mask = np.zeros(len(points), dtype=bool)
    for axis in ("x", "y", "z"):
        if points.dtype.names and axis in points.dtype.names:
            mask |= ~np.isfinite(points[axis])
    return mask


def decode(
    *,
    fields: Sequence[Any],
    width: int,
    height: int,
    point_step: int,
    row_step: int,
    data: Any,
    is_bigendian: bool = False,
    nan_policy: NanPolicy = "drop",
) -> DecodedCloud:
    """Decode a PointCloud2 body into a structured array (one row per point).

    ``data`` is anything exposing the buffer protocol (bytes, array.array,
    numpy uint8). Raises :class:`CloudFormatError` naming the problem.
    """
    if nan_policy not in ("drop", "keep", "reject"):
        raise ValueError(f"nan_policy must be 'drop', 'keep' or 'reject', not {nan_policy!r}")
    if is_bigendian:
        raise CloudFormatError("big-endian clouds are not supported (is_bigendian=true)")
    dtype = dtype_from_fields(fields, point_step)
    for axis in ("x", "y", "z"):
        if axis not in dtype.names:
            raise CloudFormatError(f"missing field '{axis}'")
        if dtype[axis].shape:
            raise CloudFormatError(f"field '{axis}' has count {dtype[axis].shape[0]}: x, y and z must be scalars")
    width, height, row_step = int(width), int(height), int(row_step)
    if width < 0 or height < 0:
        raise CloudFormatError(f"negative size width={width} height={height}")
    if row_step < width * point_step:
        raise CloudFormatError(
            f"row_step {row_step} is smaller than width {width} * point_step {point_step}"
        )
    raw = np.frombuffer(data, dtype=np.uint8) if not isinstance(data, np.ndarray) else data.view(np.uint8)
    if raw.size != row_step * height:
        raise CloudFormatError(
            f"data length {raw.size} != row_step {row_step} * height {height} = {row_step * height}"
        )
    if row_step == width * point_step:
        points = raw.view(dtype).copy() if raw.size else np.zeros(0, dtype)
    else:
        rows = raw.reshape(height, row_step)[:, : width * point_step]
        points = np.ascontiguousarray(rows).view(dtype).reshape(-1).copy()
    bad = nonfinite_mask(points)
    n_bad = int(bad.sum())
    if n_bad and nan_policy == "reject":
        raise CloudFormatError(f"{n_bad} points with non-finite x/y/z (nan_policy='reject')")
    if n_bad and nan_policy == "drop":
        points = points[~bad]
    return DecodedCloud(points, n_bad if nan_policy == "drop" else 0)


def decode_message(msg: Any, nan_policy: NanPolicy = "drop") -> DecodedCloud:
    """Decode a PointCloud2 message object (rclpy or rosbags)."""
    return decode(
        fields=msg.fields,
        width=msg.width,
        height=msg.height,
        point_step=msg.point_step,
        row_step=msg.row_step,
        data=msg.data,
        is_bigendian=bool(msg.is_bigendian),
        nan_policy=nan_policy,
    )


@functools.lru_cache(maxsize=32)
def _padding_runs(dtype: np.dtype) -> tuple[tuple[int, int], ...]:
    """The byte ranges [start, end) of a point of ``dtype`` that no field covers."""
    covered = np.zeros(dtype.itemsize, bool)
    for name in dtype.names:
        field, offset = dtype.fields[name][:2]
        covered[offset : offset + field.itemsize] = True
    edges = np.flatnonzero(np.diff(np.concatenate([[True], covered, [True]]).astype(np.int8)))
    return tuple((int(a), int(b)) for a, b in zip(edges[::2], edges[1::2]))


def _zero_padding(points: np.ndarray) -> np.ndarray:
    """``points`` (contiguous) with the bytes between fields set to 0: an array made with ``np.empty`` (or a
    structured ``astype``) holds whatever memory was there, and the same points must give the same bytes."""
    runs = _padding_runs(points.dtype)
    if not runs or not len(points):
        return points
    if not points.flags.writeable:
        points = points.copy()
    raw = points.view(np.uint8).reshape(len(points), points.dtype.itemsize)
    for start, end in runs:
        raw[:, start:end] = 0
    return points


def encode(points: np.ndarray, drop_nonfinite: bool = True) -> EncodedCloud:
    """Encode a structured array as an unorganised little-endian cloud body.

    Non-finite points (x, y or z) are dropped and counted unless
    ``drop_nonfinite`` is false.
    """
    if points.dtype.names is None:
        raise CloudFormatError(f"points must be a structured array, not dtype {points.dtype}")
    for axis in ("x", "y", "z"):
        if axis not in points.dtype.names:
            raise CloudFormatError(f"missing field '{axis}'")
        if points.dtype.fields[axis][0].shape:
            raise CloudFormatError(f"field '{axis}' holds {points.dtype.fields[axis][0].shape} values per point, not one")
    little = points.dtype.newbyteorder("<")
    if little != points.dtype:
        points = points.astype(little)
    dropped = 0
    if drop_nonfinite:
        bad = nonfinite_mask(points)
        dropped = int(bad.sum())
        if dropped:
            points = points[~bad]
    points = _zero_padding(np.ascontiguousarray(points))
    return EncodedCloud(
        fields=fields_from_dtype(points.dtype),
        point_step=points.dtype.itemsize,
        width=len(points),
        data=points.tobytes(),
        dropped_nonfinite=dropped,
    )


@dataclass(frozen=True)
class MessageTypes:
    """The message classes of one ROS binding, for building clouds without importing ROS here.

    ``data`` converts the body bytes to what that binding stores in ``uint8[]``.
    """

    PointCloud2: Callable[..., Any]
    PointField: Callable[..., Any]
    Header: Callable[..., Any]
    Time: Callable[..., Any]
    data: Callable[[bytes], Any]


def build_message(
    points: np.ndarray, *, stamp_ns: int, frame_id: str, types: MessageTypes, drop_nonfinite: bool = True
) -> tuple[Any, int]:
    """A PointCloud2 of ``points`` stamped ``stamp_ns`` (ns) in ``frame_id``.

    Returns the message and the number of non-finite points dropped.
    """
    body = encode(points, drop_nonfinite=drop_nonfinite)
    sec, nanosec = divmod(int(stamp_ns), 1_000_000_000)
    msg = types.PointCloud2(
        header=types.Header(stamp=types.Time(sec=sec, nanosec=nanosec), frame_id=frame_id),
        height=1,
        width=body.width,
        fields=[types.PointField(name=f.name, offset=f.offset, datatype=f.datatype, count=f.count) for f in body.fields],
        is_bigendian=False,
        point_step=body.point_step,
        row_step=body.row_step,
        data=types.data(body.data),
        is_dense=True,
    )
    return msg, body.dropped_nonfinite
