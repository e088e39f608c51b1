"""Reading what a Foxglove WebSocket server sends, for tests: no Foxglove code, only the published formats.

- :func:`message_data`: a binary server frame of Foxglove's WebSocket protocol (``foxglove.websocket.v1``;
  foxglove-sdk 0.30.3 negotiates ``foxglove.sdk.v1``, same framing), opcode 0x01 "Message Data":
  subscription id (uint32 LE), log time (uint64 LE, ns), payload.
- :func:`protobuf_fields`: a protobuf message's fields by number (the wire format: varint, 64-bit,
  length-delimited, 32-bit), enough to read Foxglove's schemas without their descriptors.
- :func:`decode_point_cloud`: a ``foxglove.PointCloud`` (protobuf; field numbers of
  foxglove/PointCloud.proto: timestamp 1, frame_id 2, pose 3, point_stride 4, fields 5, data 6;
  PackedElementField: name 1, offset 2, type 3) as a structured numpy array.
"""

from __future__ import annotations

import struct
from dataclasses import dataclass

import numpy as np

MESSAGE_DATA = 0x01
#: PackedElementField.NumericType -> numpy dtype (little-endian)
NUMERIC_DTYPES = {1: "<u1", 2: "<i1", 3: "<u2", 4: "<i2", 5: "<u4", 6: "<i4", 7: "<f4", 8: "<f8"}


def message_data(frame: bytes) -> tuple[int, int, bytes]:
    """(subscription id, log time in ns, payload) of a binary Message Data frame; ValueError for another opcode."""
    if len(frame) < 13 or frame[0] != MESSAGE_DATA:
        raise ValueError(f"not a Message Data frame (opcode {frame[:1].hex() or 'none'}, {len(frame)} bytes)")
    subscription, log_time = struct.unpack_from("<IQ", frame, 1)
    return subscription, log_time, bytes(frame[13:])


def _varint(buf: bytes, pos: int) -> tuple[int, int]:
    value = shift = 0
    while True:
        if pos >= len(buf):
            raise ValueError("truncated varint")
        byte = buf[pos]
        pos += 1
        value |= (byte & 0x7F) << shift
        if not byte & 0x80:
            return value, pos
        shift += 7


def protobuf_fields(buf: bytes) -> dict[int, list]:
    """Field number -> values in order (varint: int; 64-bit, 32-bit: raw bytes; length-delimited: bytes)."""
    out: dict[int, list] = {}
    pos = 0
    while pos < len(buf):
        key, pos = _varint(buf, pos)
        number, wire = key >> 3, key & 7
        if wire == 0:
            value, pos = _varint(buf, pos)
        elif wire == 1:
            value, pos = buf[pos:pos + 8], pos + 8
        elif wire == 2:
            size, pos = _varint(buf, pos)
            value, pos = buf[pos:pos + size], pos + size
        elif wire == 5:
            value, pos = buf[pos:pos + 4], pos + 4
        else:
            raise ValueError(f"wire type {wire} of field {number} not supported")
        if pos > len(buf):
            raise ValueError(f"field {number} runs past the end of the message")
        out.setdefault(number, []).append(value)
    return out


@dataclass(frozen=True)
class FoxgloveCloud:
    stamp_ns: int
    frame_id: str
    point_stride: int
    fields: dict[str, tuple[int, int]]  # name -> (byte offset, NumericType)
    points: np.ndarray  # structured, one record per point_stride bytes


def decode_point_cloud(payload: bytes) -> FoxgloveCloud:
    """A protobuf-encoded ``foxglove.PointCloud`` with its points as a structured array of its described fields."""
    f = protobuf_fields(payload)
    stamp = protobuf_fields(f[1][0]) if 1 in f else {}
    stamp_ns = stamp.get(1, [0])[0] * 1_000_000_000 + stamp.get(2, [0])[0]
    stride = struct.unpack("<I", f[4][0])[0] if 4 in f else 0
    fields = {}
    for raw in f.get(5, []):
        pf = protobuf_fields(raw)
        offset = struct.unpack("<I", pf[2][0])[0] if 2 in pf else 0
        fields[pf[1][0].decode()] = (offset, pf.get(3, [0])[0])
    data = f.get(6, [b""])[0]
    if not stride or len(data) % stride:
        raise ValueError(f"{len(data)} bytes of data are not a multiple of the point stride {stride}")
    dtype = np.dtype({"names": list(fields), "formats": [NUMERIC_DTYPES[t] for _, t in fields.values()],
                      "offsets": [o for o, _ in fields.values()], "itemsize": stride})  # fmt: skip
    return FoxgloveCloud(stamp_ns, f.get(2, [b""])[0].decode(), stride, fields, np.frombuffer(data, dtype))
