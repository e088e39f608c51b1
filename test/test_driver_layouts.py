"""Clouds of the common ROS 2 drivers read into the project's point layout (io/layouts.py).

The samples under test/data/driver_layouts are one VLP-16 frame of highway_clear written as each driver
writes it (``python -m lidar_weather_sim.testing.driver_layouts test/data/driver_layouts``); the ``nebula``
sample holds the simulator's own azimuth, elevation, distance, channel and point times, which every other
layout, read, must give back.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from lidar_weather_sim.cli import main as cli_main
from lidar_weather_sim.io.bags import bag_info, read_clouds
from lidar_weather_sim.io.layouts import CloudReader, elevation_clusters, nearest_channel
from lidar_weather_sim.io.recording import Recording
from lidar_weather_sim.testing.driver_layouts import LAYOUTS, write_driver_bag

DATA = Path(__file__).parent / "data" / "driver_layouts"

#: layout -> (topic, PointCloud2 fields (name, offset, datatype, count), point_step) as the drivers write them
EXPECTED = {
    "velodyne": ("/velodyne_points", [("x", 0, 7, 1), ("y", 4, 7, 1), ("z", 8, 7, 1), ("intensity", 12, 7, 1),
                                      ("ring", 16, 4, 1), ("time", 18, 7, 1)], 22),
    "velodyne_no_time": ("/velodyne_points", [("x", 0, 7, 1), ("y", 4, 7, 1), ("z", 8, 7, 1),
                                              ("intensity", 12, 7, 1), ("ring", 16, 4, 1)], 18),
    "ouster": ("/ouster/points", [("x", 0, 7, 1), ("y", 4, 7, 1), ("z", 8, 7, 1), ("intensity", 16, 7, 1),
                                  ("t", 20, 6, 1), ("reflectivity", 24, 4, 1), ("ring", 26, 4, 1),
                                  ("ambient", 28, 4, 1), ("range", 32, 6, 1)], 48),
    "hesai": ("/lidar_points", [("x", 0, 7, 1), ("y", 4, 7, 1), ("z", 8, 7, 1), ("intensity", 12, 7, 1),
                                ("ring", 16, 4, 1), ("timestamp", 18, 8, 1)], 26),
    "livox": ("/livox/lidar", [("x", 0, 7, 1), ("y", 4, 7, 1), ("z", 8, 7, 1), ("intensity", 12, 7, 1),
                               ("tag", 16, 2, 1), ("line", 17, 2, 1), ("timestamp", 18, 8, 1)], 26),
    "nebula": ("/pandar_points", [("x", 0, 7, 1), ("y", 4, 7, 1), ("z", 8, 7, 1), ("intensity", 12, 2, 1),
                                  ("return_type", 13, 2, 1), ("channel", 14, 4, 1), ("azimuth", 16, 7, 1),
                                  ("elevation", 20, 7, 1), ("distance", 24, 7, 1), ("time_stamp", 28, 6, 1)], 32),
}  # fmt: skip
EXPECTED["velodyne_organised"] = EXPECTED["velodyne"]
DRIVER = {"velodyne": "velodyne_pointcloud XYZIRT", "velodyne_organised": "velodyne_pointcloud XYZIRT",
          "velodyne_no_time": "velodyne_pointcloud XYZIR", "ouster": "ouster-ros", "hesai": "Hesai",
          "livox": "livox_ros_driver2", "nebula": "Nebula"}  # fmt: skip


@pytest.fixture(autouse=True)
def _notes_said_afresh(monkeypatch):
    """A command says each recording's note once per process; each test here is a fresh command."""
    from lidar_weather_sim.io import layouts

    monkeypatch.setattr(layouts, "_NOTED", set())


def _xy_key(points: np.ndarray) -> np.ndarray:
    return (points["x"].view(np.uint32).astype(np.uint64) << np.uint64(32)) | points["y"].view(np.uint32)


def _sorted(points: np.ndarray) -> np.ndarray:
    return points[np.lexsort((points["distance"], points["azimuth"], points["channel"]))]


@pytest.fixture(scope="module")
def reference():
    (frame,) = read_clouds(DATA / "nebula", reader=CloudReader("nebula", None))
    return frame.stamp_ns, _sorted(frame.points)


def test_the_samples_hold_each_drivers_layout():
    assert set(EXPECTED) == set(LAYOUTS)
    for layout, (topic, fields, step) in EXPECTED.items():
        (info,) = [t for t in bag_info(DATA / layout).topics if t.msgtype == "sensor_msgs/msg/PointCloud2"]
        assert info.name == topic and info.pointcloud_fields == fields, layout
        assert LAYOUTS[layout][0].itemsize == step, layout


@pytest.mark.parametrize("layout", sorted(set(LAYOUTS) - {"nebula"}))
def test_each_layout_reads_back_the_simulators_values(layout, reference, capsys):
    stamp, ref = reference
    recording = Recording.load(DATA / layout)  # the bag's only PointCloud2 topic, no --topic
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("note: ") and DRIVER[layout] in err[0], err
    frame = recording.frames[0]
    got = frame.points
    if layout == "velodyne_no_time":  # every 4th column of 3 frames: the points of the reference's 16th columns
        got = got[np.isin(_xy_key(got), _xy_key(ref))]
    got = _sorted(got)
    assert recording.topic == EXPECTED[layout][0] and len(got) == len(ref)
    for name in ("azimuth", "elevation", "distance"):  # recomputed from x, y, z (rad, rad, m)
        np.testing.assert_allclose(got[name], ref[name], atol=1e-5, rtol=0, err_msg=f"{layout} {name}")
    np.testing.assert_array_equal(got["channel"], ref["channel"])  # ouster's ring counts from the top: reversed
    np.testing.assert_array_equal(got["intensity"], ref["intensity"])  # ouster: its reflectivity, not photons
    assert (got["echo"] == 1).all() and "epw" not in got.dtype.names
    if layout == "velodyne_no_time":
        assert (got["time_stamp"] == 0).all() and "no per-point time" in err[0] and not recording.layout.has_time
    else:  # velodyne float32 s, ouster uint32 ns, hesai float64 epoch s, livox float64 epoch ns
        assert frame.stamp_ns == stamp
        assert np.abs(got["time_stamp"].astype(np.int64) - ref["time_stamp"]).max() <= 1000
    if layout == "ouster":
        assert "intensity from reflectivity" in err[0] and "counted down from the top beam" in err[0]


def test_the_project_layout_is_read_as_it_is(capsys):
    (frame,) = read_clouds(DATA / "nebula")
    assert "one echo per beam" in capsys.readouterr().err  # Nebula's 32 bytes lack the echo field
    points = frame.points
    again = CloudReader("same", None).read(points, 5)
    assert again.points is points and again.stamp_ns == 5  # already the project's layout: untouched


def test_channel_from_the_elevation_clusters_equals_the_ring():
    (frame,) = read_clouds(DATA / "velodyne", reader=CloudReader("v", None))
    points = frame.points
    xyzi = np.zeros(len(points), dtype=[("x", "<f4"), ("y", "<f4"), ("z", "<f4"), ("intensity", "<f4")])
    for name in ("x", "y", "z", "intensity"):
        xyzi[name] = points[name]
    reader = CloudReader("no ring", None)
    got = reader.read(xyzi, 0).points
    channels = len(np.unique(points["channel"]))
    assert channels == 10  # the VLP-16's 6 upper beams see the sky over the highway
    np.testing.assert_array_equal(got["channel"], points["channel"])
    assert f"channel from {channels} elevation clusters" in reader.line()
    table = elevation_clusters(points["elevation"])
    assert len(table) == channels and (nearest_channel(table, table) == np.arange(channels)).all()


def test_intensity_scale_is_noted():
    cloud = np.zeros(3, dtype=[("x", "<f4"), ("y", "<f4"), ("z", "<f4"), ("intensity", "<f4")])
    cloud["x"] = [1, 2, 3]
    cloud["intensity"] = [0.0, 0.5, 1.0]  # a driver that normalises to 0-1
    reader = CloudReader("scaled", None)
    assert reader.read(cloud, 0).points["intensity"].tolist() == [0, 128, 255]
    assert "intensity from intensity float32 x255" in reader.line()
    cloud["intensity"] = [10, 300, 70000]  # photon counts
    reader = CloudReader("photons", None)
    assert reader.read(cloud, 0).points["intensity"].tolist() == [10, 255, 255]
    assert "clipped to 0-255" in reader.line()


def test_placeholders_and_early_times(tmp_path):
    """Ouster's zero placeholders are dropped; velodyne times before the header stamp move the stamp."""
    cloud = np.zeros(4, dtype=[("x", "<f4"), ("y", "<f4"), ("z", "<f4"), ("time", "<f4")])
    cloud["x"] = [0, 5, 6, 7]
    cloud["time"] = [0.0, -0.05, -0.02, 0.0]
    reader = CloudReader("early", None)
    frame = reader.read(cloud, 1_000_000_000)
    assert len(frame.points) == 3 and frame.placeholders == 1
    assert abs(frame.stamp_ns - 950_000_000) <= 2  # float32 s: -0.05 is -0.0500000007
    np.testing.assert_allclose(frame.points["time_stamp"], [0, 30_000_000, 50_000_000], atol=4)
    assert "stamp moved" in reader.line() and "placeholders" in reader.line()


def test_a_malformed_time_is_one_line_naming_file_field_and_value(tmp_path, capsys):
    from lidar_weather_sim.io.bags import BagWriter
    from lidar_weather_sim.testing.driver_layouts import cloud_message, to_driver

    (frame,) = read_clouds(DATA / "nebula", reader=CloudReader("n", None))
    cloud = to_driver(frame.points, "velodyne", frame.stamp_ns)
    cloud["time"][3] = np.nan
    with BagWriter(tmp_path / "nan") as writer:
        writer.write("/velodyne_points", cloud_message(cloud, frame.stamp_ns, "lidar"), frame.stamp_ns)
    code = cli_main(["twin", str(tmp_path / "nan"), "--out", str(tmp_path / "twin")])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and len(err) == 1, err
    assert str(tmp_path / "nan") in err[0] and "'time'" in err[0] and "nan" in err[0], err


def test_kiss_icp_takes_a_recording_without_point_times(capsys):
    """Velodyne XYZIR, no /tf: KISS-ICP registers the frames without deskewing (no native abort)."""
    from lidar_weather_sim.twin.poses import twin_poses

    recording = Recording.load(DATA / "velodyne_no_time")
    poses = twin_poses(recording, 100.0)
    assert poses.source == "kiss-icp" and not poses.deskewed
    assert np.isfinite(poses.track.poses).all() and len(poses.track.poses) == 3
    np.testing.assert_allclose(poses.track.poses[0], np.eye(4), atol=1e-9)


def test_kiss_icp_refuses_a_frame_it_cannot_register(tmp_path):
    from lidar_weather_sim.twin.poses import twin_poses

    recording = Recording.load(DATA / "velodyne_no_time", note=None)
    recording.frames[1] = type(recording.frames[1])(0, recording.frames[1].stamp_ns, "lidar",
                                                     recording.frames[1].points[:20], 0)  # fmt: skip
    with pytest.raises(ValueError, match="frame 1 has 20 points within 0.5-100 m, fewer than the 100"):
        twin_poses(recording, 100.0)


@pytest.mark.slow
def test_twin_of_a_velodyne_recording_without_point_times(tmp_path, capsys):
    out = tmp_path / "twin"
    assert cli_main(["twin", str(DATA / "velodyne_no_time"), "--out", str(out)]) == 0
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "velodyne_pointcloud XYZIR" in err[0] and "not deskewed" in err[0], err
    report = json.loads((out / "report.json").read_text())
    assert report["poses"] == "kiss-icp" and report["deskewed"] is False
    assert report["coverage"]["calibration"] >= 0.9


def test_weather_filter_eval_takes_the_only_cloud_topic(capsys):
    from weather_filter.cli import main as wf_main

    assert wf_main(["eval", str(DATA / "velodyne"), "--method", "dror"]) == 0
    result = json.loads(capsys.readouterr().out)
    assert result["frames"] == 1
