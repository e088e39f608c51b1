"""A simulated cloud written the way each common ROS 2 driver writes its clouds (the layouts of
:mod:`lidar_weather_sim.io.layouts`): exact field names, datatypes, offsets and point_step, the driver's
units (velodyne ``time`` s after the stamp, Ouster ``t`` ns and ``range`` mm, Hesai ``timestamp`` absolute
s, Livox ``timestamp`` absolute ns), Ouster's rings counted from the top beam and organised clouds with the
driver's placeholders (NaN for velodyne_pointcloud, zeros for ouster-ros).

``python -m lidar_weather_sim.testing.driver_layouts OUT_DIR`` writes the samples committed under
test/data/driver_layouts (one small rosbag2 directory per layout, :func:`samples`).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

from lidar_weather_sim.io.bags import BagWriter, message_types

F4, F8, U1, U2, U4 = "<f4", "<f8", "u1", "<u2", "<u4"


def _dtype(fields: list[tuple[str, str, int]], itemsize: int) -> np.dtype:
    return np.dtype({"names": [f[0] for f in fields], "formats": [f[1] for f in fields],
                     "offsets": [f[2] for f in fields], "itemsize": itemsize})  # fmt: skip


_XYZI = [("x", F4, 0), ("y", F4, 4), ("z", F4, 8), ("intensity", F4, 12)]
#: velodyne_pointcloud (ROS 2) PointXYZIRT: PointCloud2Modifier packs the fields, 22 bytes.
VELODYNE_XYZIRT = _dtype(_XYZI + [("ring", U2, 16), ("time", F4, 18)], 22)
#: velodyne_pointcloud (ROS 2) PointXYZIR: no per-point time, 18 bytes.
VELODYNE_XYZIR = _dtype(_XYZI + [("ring", U2, 16)], 18)
#: ouster-ros' default point (PCL_ADD_POINT4D pads x, y, z to 16 bytes; EIGEN_ALIGN16: 48 bytes).
OUSTER = _dtype([("x", F4, 0), ("y", F4, 4), ("z", F4, 8), ("intensity", F4, 16), ("t", U4, 20),
                 ("reflectivity", U2, 24), ("ring", U2, 26), ("ambient", U2, 28), ("range", U4, 32)], 48)  # fmt: skip
#: HesaiLidar_ROS_2.0: x, y, z, intensity float32, ring uint16, timestamp float64 (absolute s), packed.
HESAI = _dtype(_XYZI + [("ring", U2, 16), ("timestamp", F8, 18)], 26)
#: livox_ros_driver2 (xfer_format 0, LivoxPointXyzrtlt, packed): timestamp float64 absolute ns.
LIVOX = _dtype(_XYZI + [("tag", U1, 16), ("line", U1, 17), ("timestamp", F8, 18)], 26)
#: Nebula's PointXYZIRCAEDT (Autoware): the first 32 bytes of the project's layout.
NEBULA = _dtype([("x", F4, 0), ("y", F4, 4), ("z", F4, 8), ("intensity", U1, 12), ("return_type", U1, 13),
                 ("channel", U2, 14), ("azimuth", F4, 16), ("elevation", F4, 20), ("distance", F4, 24),
                 ("time_stamp", U4, 28)], 32)  # fmt: skip

#: name -> (dtype, topic the driver publishes on by default, organised)
LAYOUTS = {
    "velodyne": (VELODYNE_XYZIRT, "/velodyne_points", False),
    "velodyne_no_time": (VELODYNE_XYZIR, "/velodyne_points", False),
    "velodyne_organised": (VELODYNE_XYZIRT, "/velodyne_points", True),
    "ouster": (OUSTER, "/ouster/points", True),
    "hesai": (HESAI, "/lidar_points", False),
    "livox": (LIVOX, "/livox/lidar", False),
    "nebula": (NEBULA, "/pandar_points", False),
}


def to_driver(points: np.ndarray, layout: str, stamp_ns: int) -> np.ndarray:
    """``points`` (project layout, header stamp ``stamp_ns``) as the ``layout`` driver writes them (unorganised)."""
    dtype = LAYOUTS[layout][0]
    out = np.zeros(len(points), dtype=dtype)
    for axis in ("x", "y", "z"):
        out[axis] = points[axis]
    t_ns = points["time_stamp"].astype(np.int64)
    n_channels = int(points["channel"].max()) + 1
    if layout == "nebula":
        for name in dtype.names:
            out[name] = points[name]
    elif layout == "ouster":
        out["intensity"] = points["intensity"].astype(np.float32) * 12.0  # signal photons, not 0-255
        out["reflectivity"] = points["intensity"]
        out["ring"] = n_channels - 1 - points["channel"]  # ring 0 is the top beam
        out["t"] = t_ns
        out["ambient"] = 7
        out["range"] = np.rint(points["distance"].astype(np.float64) * 1000.0)
    else:
        out["intensity"] = points["intensity"]
        if "ring" in dtype.names:
            out["ring"] = points["channel"]
        if layout.startswith("velodyne") and "time" in dtype.names:
            out["time"] = t_ns * 1e-9
        elif layout == "hesai":
            out["timestamp"] = (stamp_ns + t_ns) * 1e-9
        elif layout == "livox":
            out["line"] = points["channel"]
            out["timestamp"] = (stamp_ns + t_ns).astype(np.float64)
    return out


def organise(points: np.ndarray, channel: np.ndarray, placeholder: float) -> np.ndarray:
    """(channels, columns) grid of ``points``: row = channel (top row the highest beam), each row's points in
    azimuth order, the rest ``placeholder`` in x, y, z (NaN or 0)."""
    n_rows = int(channel.max()) + 1
    order = np.lexsort((np.arctan2(points["y"], points["x"]), channel))
    counts = np.bincount(channel, minlength=n_rows)
    column = np.arange(len(order)) - np.repeat(np.cumsum(counts) - counts, counts)
    grid = np.zeros((n_rows, int(counts.max())), dtype=points.dtype)
    for axis in ("x", "y", "z"):
        grid[axis] = placeholder
    grid[n_rows - 1 - channel[order], column] = points[order]
    return grid


def cloud_message(points: np.ndarray, stamp_ns: int, frame_id: str):
    """A rosbags PointCloud2 of ``points`` (1-D: unorganised; 2-D: organised, non-finite points kept)."""
    types = message_types()
    grid = np.atleast_2d(points)
    fields = [types.PointField(name=n, offset=int(points.dtype.fields[n][1]),
                               datatype={"f4": 7, "f8": 8, "u1": 2, "u2": 4, "u4": 6}[points.dtype[n].str[1:]],
                               count=1) for n in points.dtype.names]  # fmt: skip
    sec, nanosec = divmod(int(stamp_ns), 1_000_000_000)
    return types.PointCloud2(
        header=types.Header(stamp=types.Time(sec=sec, nanosec=nanosec), frame_id=frame_id),
        height=grid.shape[0], width=grid.shape[1], fields=fields, is_bigendian=False,
        point_step=points.dtype.itemsize, row_step=points.dtype.itemsize * grid.shape[1],
        data=types.data(np.ascontiguousarray(grid).tobytes()), is_dense=points.ndim == 1)  # fmt: skip


def write_driver_bag(path: str | Path, frames: list[tuple[int, np.ndarray]], layout: str, frame_id: str = "lidar") -> Path:
    """A rosbag2 of ``frames`` ((stamp ns, project points) each) in ``layout`` on the driver's topic, no /tf."""
    _, topic, organised = LAYOUTS[layout]
    with BagWriter(path) as bag:
        for stamp_ns, points in frames:
            cloud = to_driver(points, layout, stamp_ns)
            if organised:
                cloud = organise(cloud, points["channel"].astype(np.int64), np.nan if layout.startswith("velodyne") else 0.0)
            bag.write(topic, cloud_message(cloud, stamp_ns, frame_id), stamp_ns)
    return Path(path)


def simulated_frames(scenario: str, profile: str, frames: int) -> list[tuple[int, np.ndarray]]:
    """(stamp ns, points) of ``frames`` frames of ``scenario`` seen by ``profile`` (simulated in a temporary bag)."""
    import tempfile

    from lidar_weather_sim.io.bags import read_clouds
    from lidar_weather_sim.scenario.schema import load_scenario
    from lidar_weather_sim.sim.offline import run_scenario

    with tempfile.TemporaryDirectory() as tmp:
        run_scenario(load_scenario(scenario), Path(tmp) / "bag", frames=frames, profile=profile)
        return [(f.stamp_ns, f.points) for f in read_clouds(Path(tmp) / "bag")]


def thinned(points: np.ndarray, keep_every: int) -> np.ndarray:
    """``points`` of every ``keep_every``-th column of a 0.2 deg azimuth grid (VLP-16 at 10 Hz)."""
    column = np.rint(np.degrees(points["azimuth"].astype(np.float64)) / 0.2).astype(np.int64)
    return points[column % keep_every == 0]


def samples() -> dict[str, list[tuple[int, np.ndarray]]]:
    """The committed samples: layout -> frames (stamp ns, project points). Three VLP-16 frames of
    highway_clear at an epoch-like stamp; every layout holds the first (every 16th column), the velodyne
    layout without per-point time all three (every 4th column: enough for KISS-ICP and a twin)."""
    epoch = 1_700_000_000_000_000_000
    frames = [(epoch + stamp, points) for stamp, points in simulated_frames("highway_clear", "vlp16", 3)]
    out = {layout: [(frames[0][0], thinned(frames[0][1], 16))] for layout in LAYOUTS}
    out["velodyne_no_time"] = [(stamp, thinned(points, 4)) for stamp, points in frames]
    return out


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("out", type=Path, help="directory for one bag per layout")
    args = parser.parse_args(argv)
    for layout, frames in samples().items():
        write_driver_bag(args.out / layout, frames, layout)
    return 0


if __name__ == "__main__":
    sys.exit(main())
