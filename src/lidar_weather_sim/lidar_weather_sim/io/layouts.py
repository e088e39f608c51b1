"""Clouds of the common ROS 2 LiDAR drivers read into the project's point layout (:mod:`lidar_weather_sim.core.points`).

What the drivers write (little-endian; offsets in bytes; docs/point-layout.md has the table):

| Driver                           | Fields (offset)                                                                                   | point_step |
|----------------------------------|---------------------------------------------------------------------------------------------------|-----------:|
| velodyne_pointcloud XYZIRT       | x, y, z, intensity f32 (0, 4, 8, 12), ring u16 (16), time f32 (18, s after the header stamp)      |         22 |
| ouster-ros (default point)       | x, y, z f32 (0, 4, 8), intensity f32 (16, signal photons), t u32 (20, ns after the stamp),        |         48 |
|                                  | reflectivity u16 (24), ring u16 (26, 0 = top beam), ambient u16 (28), range u32 (32, mm)          |            |
| HesaiLidar_ROS_2.0               | x, y, z, intensity f32 (0-12), ring u16 (16), timestamp f64 (18, absolute s)                      |         26 |
| livox_ros_driver2 (xfer_format 0)| x, y, z, intensity f32 (0-12), tag u8 (16), line u8 (17), timestamp f64 (18, absolute ns)         |         26 |
| Nebula / this project            | :data:`~lidar_weather_sim.core.points.POINT_DTYPE` and its 40-byte forms                          |      40/44 |

Fields are mapped by name, whatever the driver, so other layouts built from the same names read too:

- ``intensity`` (0-255, uint8): the project's as it is; else ``reflectivity`` when present (Ouster's calibrated
  reflectivity; its ``intensity`` counts signal photons), else ``intensity``; rounded and clipped to 0-255, x255
  when the first frame's values all lie within 0-1.
- ``channel`` (0 = lowest beam): the project's; else ``ring`` or ``line`` ranked by each ring's mean elevation
  (so rings counted from the top beam down become channels counted from the bottom); else the nearest of the
  elevation clusters of the first frame (sorted elevations split where they jump by more than 0.05 deg).
- ``time_stamp`` (ns after the header stamp): the project's; else ``t``, ``time``, ``timestamp``,
  ``time_offset`` or ``offset_time``: integers are ns, floats s (ns when above 1e12); absolute times (past
  1e15 ns, i.e. an epoch stamp) lose the header stamp; times before the header stamp move the frame's stamp
  to its first point. Without one, every point's time is 0 (consumers then do not deskew).
- ``azimuth``, ``elevation``, ``distance`` (rad, rad, m, sensor frame): from x, y, z when missing.
- ``return_type`` 0 (unknown) and ``echo`` 1 when missing; ``epw``, ``label`` and ``object_id`` kept only when
  present (a missing ``epw`` is how the weather filters know EPW is unknown).
- Points at the sensor origin (x = y = z = 0: organised clouds' placeholders for no return, as ouster-ros
  writes them) are dropped, as non-finite ones are by the decoder.
- A cloud naming every base field of the project's layout passes unchanged (its own types and values; the
  consumers check them).

One :class:`CloudReader` per recording or subscription keeps what the first frame decided (the channel
mapping, the intensity scale) and says in one line what it assumed, once, through its ``note`` callable.
"""

from __future__ import annotations

import sys
from dataclasses import dataclass
from typing import Any, Callable

import numpy as np

from lidar_weather_sim.core.points import POINT_DTYPE_NO_EPW, fill_polar
from lidar_weather_sim.io.cloud_codec import CloudFormatError, NanPolicy, decode_message

PROJECT_FIELDS = POINT_DTYPE_NO_EPW.names
_OPTIONAL = (("label", np.uint8, 33), ("epw", np.float32, 36), ("object_id", np.uint32, 40))
TIME_FIELDS = ("time_stamp", "t", "time", "timestamp", "time_offset", "offset_time")
RING_FIELDS = ("ring", "line")
CLUSTER_GAP_RAD = np.radians(0.05)
ABSOLUTE_NS = 1e15  # later than 1970-01-12: an epoch time, not an offset within a scan

#: Drivers recognised by their field names (first match wins), for the one-line note.
DRIVERS = (
    ("Nebula / this project", {"channel", "azimuth", "elevation", "distance", "time_stamp"}),
    ("ouster-ros", {"t", "reflectivity", "ring", "ambient", "range"}),
    ("livox_ros_driver2", {"tag", "line", "timestamp"}),
    ("velodyne_pointcloud XYZIRT", {"ring", "time"}),
    ("Hesai (HesaiLidar_ROS_2.0)", {"ring", "timestamp"}),
    ("velodyne_pointcloud XYZIR", {"ring"}),
)


def driver_name(names: tuple[str, ...] | set[str]) -> str:
    """The driver whose fields ``names`` hold (module table), else ``"generic"``."""
    present = set(names)
    return next((name for name, fields in DRIVERS if fields <= present), "generic")


_NOTED: set[str] = set()


def stderr_note(text: str) -> None:
    """The command-line sink of a reader's note: one ``note:`` line on stderr, each text once per process
    (a command that reads a recording twice says it once)."""
    if text not in _NOTED:
        _NOTED.add(text)
        print(f"note: {text}", file=sys.stderr)


def output_dtype(names: tuple[str, ...]) -> np.dtype:
    """The project's layout with those of ``label``, ``epw``, ``object_id`` that ``names`` hold."""
    extra = [f for f in _OPTIONAL if f[0] in names]
    fields = [(n, POINT_DTYPE_NO_EPW.fields[n][0], POINT_DTYPE_NO_EPW.fields[n][1]) for n in PROJECT_FIELDS]
    fields += [(n, np.dtype(t).newbyteorder("<"), o) for n, t, o in extra]
    itemsize = 44 if "object_id" in names else POINT_DTYPE_NO_EPW.itemsize
    return np.dtype({"names": [f[0] for f in fields], "formats": [f[1] for f in fields],
                     "offsets": [f[2] for f in fields], "itemsize": itemsize})  # fmt: skip


def is_project_layout(dtype: np.dtype) -> bool:
    """True when ``dtype`` names every base field of the project's layout. Such clouds pass as they are, in
    whatever types they hold: the consumers check those types and values themselves (the weather filters name
    a field out of range)."""
    return set(PROJECT_FIELDS) <= set(dtype.names or ())


def elevation_clusters(elevation: np.ndarray, gap_rad: float = CLUSTER_GAP_RAD) -> np.ndarray:
    """Median elevation (rad, ascending) of each cluster of ``elevation`` split where sorted values jump > ``gap_rad``."""
    e = np.sort(np.asarray(elevation, dtype=np.float64))
    if not len(e):
        return np.zeros(0)
    starts = np.concatenate([[0], np.flatnonzero(np.diff(e) > gap_rad) + 1])
    ends = np.concatenate([starts[1:], [len(e)]])
    return e[(starts + ends - 1) // 2]


def nearest_channel(elevation: np.ndarray, table_rad: np.ndarray) -> np.ndarray:
    """Index of the nearest entry of the ascending ``table_rad`` for each elevation (rad)."""
    if len(table_rad) < 2:
        return np.zeros(len(elevation), dtype=np.uint16)
    mids = 0.5 * (table_rad[1:] + table_rad[:-1])
    return np.searchsorted(mids, np.asarray(elevation, dtype=np.float64)).astype(np.uint16)


def ring_ranks(ring: np.ndarray, elevation: np.ndarray) -> np.ndarray:
    """Lookup table ring -> channel: the rings of one frame ranked by their mean elevation (0 = lowest);
    rings absent from the frame keep their own number."""
    ring = ring.astype(np.int64)
    size = int(ring.max()) + 1 if len(ring) else 1
    counts = np.bincount(ring, minlength=size)
    mean = np.bincount(ring, weights=elevation.astype(np.float64), minlength=size) / np.maximum(counts, 1)
    seen = np.flatnonzero(counts)
    lut = np.arange(max(size, 65536), dtype=np.int64)
    lut[seen[np.argsort(mean[seen], kind="stable")]] = np.arange(len(seen))
    return lut


def _time_ns(values: np.ndarray) -> tuple[np.ndarray, str]:
    """Per-point times in ns (float64) and the unit assumed."""
    if values.dtype.kind in "iu":
        return values.astype(np.float64), "ns"
    v = values.astype(np.float64)
    if len(v) and np.nanmax(np.abs(v)) > 1e12:
        return v, "ns"
    return v * 1e9, "s"


@dataclass(frozen=True)
class ReadFrame:
    """One frame in the project's layout: points, header stamp (ns; moved to the first point when the
    driver's times precede it) and the number of placeholder points dropped."""

    points: np.ndarray
    stamp_ns: int
    placeholders: int


class CloudReader:
    """Maps the frames of one recording or subscription to the project's layout (module doc); says once,
    through ``note``, what it assumed. ``source`` names the recording (file and topic) in that note."""

    def __init__(self, source: str, note: Callable[[str], None] | None = stderr_note) -> None:
        self.source = source
        self.note = note
        self.driver: str | None = None
        self.assumptions: list[str] = []
        self.has_time = True
        self._ring_lut: np.ndarray | None = None
        self._clusters: np.ndarray | None = None
        self._intensity_scale = 1.0
        self._said = False

    def read(self, points: np.ndarray, stamp_ns: int) -> ReadFrame:
        """``points`` (a decoded cloud, any driver) in the project's layout."""
        names = points.dtype.names or ()
        first = self.driver is None
        if first:
            self.driver = driver_name(names)
        if is_project_layout(points.dtype):
            self._say()
            return ReadFrame(points, int(stamp_ns), 0)
        origin = _placeholders(points)
        if origin.any():
            points = points[~origin]
        out = np.zeros(len(points), dtype=output_dtype(names))
        for name in ("x", "y", "z"):
            out[name] = points[name]
        for name in out.dtype.names:
            if name in names and name not in ("x", "y", "z", "intensity", "channel", "time_stamp"):
                out[name] = points[name]
        if not {"azimuth", "elevation", "distance"} <= set(names):
            fill_polar(out)
            self._assume(first, "azimuth, elevation, distance from x, y, z")
        if "echo" not in names:
            out["echo"] = 1
            self._assume(first, "one echo per beam")
        self._intensity(points, out, first)
        self._channel(points, out, first)
        stamp = self._time(points, out, int(stamp_ns), first)
        self._assume(first and bool(origin.any()), "points at the sensor origin (placeholders of no return) dropped")
        self._say()
        return ReadFrame(out, stamp, int(origin.sum()))

    def read_message(self, msg: Any, nan_policy: NanPolicy = "drop") -> ReadFrame:
        """A sensor_msgs/PointCloud2 (rclpy or rosbags) decoded and read; CloudFormatError names the fault."""
        cloud = decode_message(msg, nan_policy)
        stamp = msg.header.stamp
        return self.read(cloud.points, int(stamp.sec) * 1_000_000_000 + int(stamp.nanosec))

    def line(self) -> str:
        """The one-line note: the source, the driver and every assumption."""
        said = "; ".join(self.assumptions)
        return f"{self.source}: read as {self.driver}" + (f" ({said})" if said else "")

    def _assume(self, when: bool, text: str) -> None:
        if when:
            self.assumptions.append(text)

    def _say(self) -> None:
        if not self._said and self.assumptions and self.note is not None:
            self.note(self.line())
        self._said = True

    def _intensity(self, points: np.ndarray, out: np.ndarray, first: bool) -> None:
        names = points.dtype.names
        if "intensity" in names and points.dtype["intensity"] == np.uint8:
            out["intensity"] = points["intensity"]
            return
        source = "reflectivity" if "reflectivity" in names else "intensity" if "intensity" in names else None
        if source is None:
            self._assume(first, "no intensity: 0")
            return
        values = points[source].astype(np.float64)
        if first:
            finite = values[np.isfinite(values)]
            if len(finite) and finite.max() <= 1.0 and finite.min() >= 0.0 and values.dtype.kind == "f":
                self._intensity_scale = 255.0
            scale = " x255" if self._intensity_scale != 1.0 else ""
            clipped = " clipped to 0-255" if len(finite) and (finite * self._intensity_scale).max() > 255.5 else ""
            self.assumptions.append(f"intensity from {source} {points.dtype[source].name}{scale}{clipped}")
        scaled = np.nan_to_num(values * self._intensity_scale, nan=0.0)
        out["intensity"] = np.clip(np.rint(scaled), 0, 255).astype(np.uint8)

    def _channel(self, points: np.ndarray, out: np.ndarray, first: bool) -> None:
        names = points.dtype.names
        if "channel" in names:
            out["channel"] = points["channel"]
            return
        ring = next((n for n in RING_FIELDS if n in names), None)
        if ring is not None:
            values = points[ring].astype(np.int64)
            if self._ring_lut is None:
                self._ring_lut = ring_ranks(values, out["elevation"])
                order = self._ring_lut[np.unique(values)]
                how = "" if np.all(np.diff(order) > 0) else ", counted down from the top beam" if np.all(np.diff(order) < 0) else ", reordered"
                self.assumptions.append(f"channel from {ring} ranked by elevation{how}")
            out["channel"] = self._ring_lut[np.clip(values, 0, len(self._ring_lut) - 1)]
            return
        if self._clusters is None:
            self._clusters = elevation_clusters(out["elevation"])
            self.assumptions.append(f"no ring: channel from {len(self._clusters)} elevation clusters of the first frame")
        out["channel"] = nearest_channel(out["elevation"], self._clusters)

    def _time(self, points: np.ndarray, out: np.ndarray, stamp_ns: int, first: bool) -> int:
        names = points.dtype.names
        name = next((n for n in TIME_FIELDS if n in names), None)
        if name is None:
            if first:
                self.has_time = False
                self.assumptions.append("no per-point time: time_stamp 0, not deskewed")
            return stamp_ns
        if name == "time_stamp" and points.dtype[name] == np.uint32:
            out["time_stamp"] = points[name]
            return stamp_ns
        ns, unit = _time_ns(points[name])
        if not np.isfinite(ns).all():
            raise CloudFormatError(f"field '{name}': non-finite per-point time {ns[~np.isfinite(ns)][0]}")
        absolute = bool(len(ns)) and float(np.median(ns)) > ABSOLUTE_NS
        if absolute:
            ns = ns - stamp_ns
        shift = int(np.rint(ns.min())) if len(ns) and ns.min() < -1e3 else 0  # float64 epoch seconds: 0.2 us steps
        if ns.max(initial=0) - shift > np.iinfo(np.uint32).max:
            raise CloudFormatError(f"field '{name}': times span {(ns.max() - shift) * 1e-9:.3f} s, more than a "
                                   f"uint32 of ns after the header stamp")  # fmt: skip
        out["time_stamp"] = np.clip(np.rint(ns - shift), 0, None).astype(np.uint32)
        if first:
            kind = "absolute" if absolute else "after the header stamp"
            self.assumptions.append(f"time_stamp from {name} {points.dtype[name].name} ({unit}, {kind})")
        self._assume(first and shift < 0, "times before the header stamp: stamp moved to the first point")
        return stamp_ns + shift


def _placeholders(points: np.ndarray) -> np.ndarray:
    """True where x, y and z are all exactly 0 (no return)."""
    return (points["x"] == 0) & (points["y"] == 0) & (points["z"] == 0)
