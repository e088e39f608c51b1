"""Decode an Ouster OS recording (libpcap file of UDP lidar packets + metadata JSON) with numpy.

Packet layout (Ouster firmware 2.x/3.x, non-legacy profiles; ouster-sdk
``parsing.cpp``): a 32-byte packet header (packet type u16, frame id u16, ...),
``columns_per_packet`` columns, a 32-byte footer. A column is a 12-byte header
(timestamp u64 ns, measurement id u16, status u16 with bit 0 = valid) and
``pixels_per_column`` pixel words in row order (row 0 = highest beam). In the
low-data-rate profile ``RNG15_RFL8_NIR8`` a pixel is 4 bytes: range in bits 0-14
in units of 8 mm (0 = no return), reflectivity in byte 2, near-IR in byte 3.

XYZ follows Ouster's published formula (ouster-sdk ``xyzlut.cpp``, OS1 manual
"Lidar Range to XYZ") for column measurement id ``m`` of ``W`` and row ``i``:
encoder angle theta_e = 2 pi (1 - m / W), beam azimuth theta_a = -az_i,
altitude phi = alt_i, beam-origin offset n (mm), range r (mm)::

    x = (r - n) cos(theta_e + theta_a) cos(phi) + n cos(theta_e)
    y = (r - n) sin(theta_e + theta_a) cos(phi) + n sin(theta_e)
    z = (r - n) sin(phi)

in Ouster's lidar frame, then ``lidar_to_sensor_transform`` (mm) into Ouster's
*sensor* frame (x forward away from the connector, y left, z up: REP-103),
which is this project's ``lidar`` frame. The formula works on measurement ids
(the staggered order the packets carry), so no destaggering is needed for
points; ``pixel_shift_by_row`` only matters for range images.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

_PCAP_MAGIC = {0xA1B2C3D4: "<", 0xD4C3B2A1: ">", 0xA1B23C4D: "<", 0x4D3CB2A1: ">"}  # us / ns resolution
_LINKTYPE_ETHERNET = 1
_UDP_OFFSET = 14 + 20  # Ethernet II header, IPv4 header without options
_PACKET_HEADER, _PACKET_FOOTER, _COLUMN_HEADER = 32, 32, 12
#: udp_profile_lidar -> (bytes per pixel, range bits, range unit mm, reflectivity byte)
_PROFILES = {"RNG15_RFL8_NIR8": (4, 15, 8, 2)}


class OusterFormatError(ValueError):
    """A recording or metadata file that cannot be decoded; the message names the file."""


@dataclass(frozen=True)
class OusterMetadata:
    """What decoding needs from an Ouster metadata JSON (angles deg, lengths mm).

    ``lidar_to_sensor``: 4x4, Ouster lidar frame -> sensor frame (translation mm).
    ``beam_origin_mm``: translation of the beam origin from the lidar origin
    (x, z of ``beam_to_lidar_transform``; older files give only x as
    ``lidar_origin_to_beam_origin_mm``). ``init_id`` and ``serial``: what the
    packets of the same sensor session carry in their header.
    """

    columns: int
    rows: int
    columns_per_packet: int
    profile: str
    udp_port: int
    altitude_deg: np.ndarray
    azimuth_deg: np.ndarray
    beam_origin_mm: tuple[float, float]
    lidar_to_sensor: np.ndarray
    init_id: int
    serial: int

    @classmethod
    def from_json(cls, meta: dict, name: str = "metadata") -> OusterMetadata:
        """Read the flat (firmware 2.x) or nested (``sensor_info``, 3.x) layout."""
        keys = ("beam_intrinsics", "lidar_intrinsics", "config_params", "sensor_info")
        sections = [meta] + [meta.get(k, {}) for k in keys]
        fmt = meta.get("lidar_data_format") or meta.get("data_format") or {}

        def get(key: str, source: list[dict] = sections):
            for section in source:
                if key in section:
                    return section[key]
            raise OusterFormatError(f"{name}: no '{key}' in the Ouster metadata")

        try:
            b2l = np.asarray(get("beam_to_lidar_transform"), dtype=np.float64).reshape(4, 4)
            origin = (float(b2l[0, 3]), float(b2l[2, 3]))
        except OusterFormatError:
            origin = (float(get("lidar_origin_to_beam_origin_mm")), 0.0)
        md = cls(
            columns=int(get("columns_per_frame", [fmt])),
            rows=int(get("pixels_per_column", [fmt])),
            columns_per_packet=int(get("columns_per_packet", [fmt])),
            profile=str(get("udp_profile_lidar", [fmt, *sections])),
            udp_port=int(get("udp_port_lidar")),
            altitude_deg=np.asarray(get("beam_altitude_angles"), dtype=np.float64),
            azimuth_deg=np.asarray(get("beam_azimuth_angles"), dtype=np.float64),
            beam_origin_mm=origin,
            lidar_to_sensor=np.asarray(get("lidar_to_sensor_transform"), dtype=np.float64).reshape(4, 4),
            init_id=int(get("initialization_id")),
            serial=int(get("prod_sn")),
        )
        if md.profile not in _PROFILES:
            raise OusterFormatError(f"{name}: udp_profile_lidar {md.profile} is not supported ({', '.join(_PROFILES)})")
        if len(md.altitude_deg) != md.rows or len(md.azimuth_deg) != md.rows:
            raise OusterFormatError(f"{name}: {len(md.altitude_deg)} beam angles for {md.rows} pixels per column")
        return md

    @property
    def packet_size(self) -> int:
        """UDP payload bytes of one lidar packet."""
        column = _COLUMN_HEADER + self.rows * _PROFILES[self.profile][0]
        return _PACKET_HEADER + self.columns_per_packet * column + _PACKET_FOOTER


@dataclass(frozen=True)
class Scan:
    """One complete rotation in measurement-id order: (W,) column stamps (ns, sensor clock),
    (H, W) range (mm, 0 = no return) and reflectivity (0-255); ``frame_id`` from the packets."""

    frame_id: int
    timestamp_ns: np.ndarray
    range_mm: np.ndarray
    reflectivity: np.ndarray


def lidar_payloads(data: bytes, meta: OusterMetadata, source: str) -> np.ndarray:
    """(N, packet_size) uint8: UDP payloads to ``meta.udp_port`` of the right size, in file order.

    ``data`` is a libpcap file (Ethernet framing, unfragmented IPv4); other packets
    (IMU, other ports) are skipped. ``source`` names the file in errors. Packets of
    another sensor or session (serial number, init id) than ``meta`` are an error.
    The loop is over packet records, not points.
    """
    data = np.frombuffer(data, dtype=np.uint8)
    magic = int(data[:4].view("<u4")[0]) if len(data) >= 24 else None
    if magic not in _PCAP_MAGIC:
        raise OusterFormatError(f"{source}: not a libpcap file (bad or missing magic number)")
    u32 = f"{_PCAP_MAGIC[magic]}u4"
    if int(data[20:24].view(u32)[0]) != _LINKTYPE_ETHERNET:
        raise OusterFormatError(f"{source}: link type {int(data[20:24].view(u32)[0])} is not Ethernet")
    frame_size = _UDP_OFFSET + 8 + meta.packet_size
    offsets, offset = [], 24
    while offset + 16 <= len(data):
        captured = int(data[offset + 8 : offset + 12].view(u32)[0])
        start, offset = offset + 16, offset + 16 + captured
        if offset > len(data):
            raise OusterFormatError(f"{source}: truncated packet record at byte {start - 16} "
                                    f"({captured} bytes announced, {len(data) - start} present)")  # fmt: skip
        if captured == frame_size:
            offsets.append(start)
    if offset != len(data):
        raise OusterFormatError(f"{source}: {len(data) - offset} stray bytes after the last packet record")
    frames = data[np.asarray(offsets, dtype=np.int64)[:, None] + np.arange(frame_size)]
    port = frames[:, _UDP_OFFSET + 2].astype(np.int64) << 8 | frames[:, _UDP_OFFSET + 3]
    ipv4_udp = (frames[:, 12] == 0x08) & (frames[:, 13] == 0x00) & (frames[:, 14] == 0x45) & (frames[:, 23] == 17)
    payloads = frames[ipv4_udp & (port == meta.udp_port), _UDP_OFFSET + 8 :]
    if not len(payloads):
        raise OusterFormatError(f"{source}: no {meta.packet_size}-byte UDP lidar packets to port {meta.udp_port} "
                                f"(profile {meta.profile})")  # fmt: skip
    header = payloads[:, :12].astype(np.uint64)
    init_id = header[:, 4] | header[:, 5] << np.uint64(8) | header[:, 6] << np.uint64(16)
    serial = sum(header[:, 7 + i] << np.uint64(8 * i) for i in range(5))
    if np.any(init_id != meta.init_id) or np.any(serial != meta.serial):
        raise OusterFormatError(f"{source}: packets of sensor {sorted(set(serial.tolist()))} session "
                                f"{sorted(set(init_id.tolist()))}, metadata of {meta.serial} session {meta.init_id}")  # fmt: skip
    return payloads


def decode_scans(payloads: np.ndarray, meta: OusterMetadata) -> list[Scan]:
    """Complete scans (every measurement id once, all columns valid) from lidar packet payloads.

    Incomplete scans (recording starting or ending mid-rotation, lost packets) are dropped.
    """
    bytes_px, range_bits, unit_mm, refl_byte = _PROFILES[meta.profile]
    n = len(payloads)
    frame_id = payloads[:, 2:4].copy().view("<u2")[:, 0]
    cols = payloads[:, _PACKET_HEADER : -_PACKET_FOOTER].reshape(n, meta.columns_per_packet, -1)
    stamp = cols[..., 0:8].copy().view("<u8")[..., 0].ravel()
    mid = cols[..., 8:10].copy().view("<u2")[..., 0].ravel().astype(np.int64)
    valid = (cols[..., 10] & 1).ravel().astype(bool)
    pixels = cols[..., _COLUMN_HEADER:].reshape(n * meta.columns_per_packet, meta.rows, bytes_px)
    words = pixels[..., :4].copy().view("<u4")[..., 0]
    range_mm = (words & ((1 << range_bits) - 1)) * np.uint32(unit_mm)
    frame = np.repeat(frame_id, meta.columns_per_packet)
    scans = []
    for run in np.split(np.arange(len(frame)), np.flatnonzero(np.diff(frame)) + 1):  # one run of packets per scan
        sel = run[valid[run] & (mid[run] < meta.columns)]
        if len(sel) != meta.columns or len(np.unique(mid[sel])) != meta.columns:
            continue
        sel = sel[np.argsort(mid[sel])]
        scans.append(Scan(int(frame[sel[0]]), stamp[sel], range_mm[sel].T.copy(), pixels[sel, :, refl_byte].T.copy()))
    return scans


def xyz_lut(meta: OusterMetadata) -> tuple[np.ndarray, np.ndarray]:
    """(H, W, 3) unit directions and (H, W, 3) offsets (m) in the sensor frame: xyz = r * dir + offset, r in m."""
    w = np.arange(meta.columns)
    encoder = 2.0 * np.pi * (1.0 - w / meta.columns)[None, :]
    azimuth = -np.radians(meta.azimuth_deg)[:, None]
    altitude = np.radians(meta.altitude_deg)[:, None]
    direction = np.stack(np.broadcast_arrays(np.cos(encoder + azimuth) * np.cos(altitude),
                                             np.sin(encoder + azimuth) * np.cos(altitude),
                                             np.sin(altitude) + 0.0 * encoder), axis=-1)  # fmt: skip
    bx, bz = meta.beam_origin_mm
    n = np.hypot(bx, bz)
    beam_origin = np.stack(np.broadcast_arrays(np.cos(encoder) * bx, np.sin(encoder) * bx, bz + 0.0 * altitude), axis=-1)
    offset = beam_origin - direction * n
    rotation, translation = meta.lidar_to_sensor[:3, :3], meta.lidar_to_sensor[:3, 3]
    return direction @ rotation.T, (offset @ rotation.T + translation) * 1e-3
