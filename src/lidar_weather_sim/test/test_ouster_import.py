"""The real OS1-128 street recording of the ouster-sdk 1.0.1 sdist: decoding, bag, mesh, profile.

Needs ``.venv/cache/ouster_sdk-1.0.1.tar.gz`` (downloaded by scripts/setup.sh); skipped without it.
"""

import contextlib
import io
import math
import tarfile

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from lidar_weather_sim.cli import main
from lidar_weather_sim.core.names import FRAME_LIDAR, FRAME_MAP, TOPIC_TF, TOPIC_TF_STATIC
from lidar_weather_sim.core.points import POINT_DTYPE_NO_EPW
from lidar_weather_sim.io.bags import read_clouds, read_messages
from lidar_weather_sim.io.ouster_import import MEMBERS, default_sdist, load_recording
from lidar_weather_sim.io.ouster_pcap import OusterFormatError
from lidar_weather_sim.poses.sources import add_tf_message
from lidar_weather_sim.poses.tf_buffer import TransformBuffer
from lidar_weather_sim.scene.scene import load_static_mesh
from lidar_weather_sim.sensor.profile import load_profile

PIXELS = 128 * 1024
RNG15_MAX_M = (2**15 - 1) * 0.008  # largest range the low-bandwidth profile encodes


@pytest.fixture(scope="module")
def sdist():
    path = default_sdist()
    if not path.is_file():
        pytest.skip(f"{path} absent: scripts/setup.sh downloads the ouster-sdk 1.0.1 sdist")
    return path


@pytest.fixture(scope="module")
def recording(sdist):
    return load_recording(sdist)


@pytest.fixture(scope="module")
def imported(sdist, tmp_path_factory):
    """``lidar-weather-sim import-ouster`` into a temporary directory: (bag, mesh, stdout)."""
    out = tmp_path_factory.mktemp("ouster")
    stdout = io.StringIO()
    with contextlib.redirect_stdout(stdout):
        rc = main(["import-ouster", "--sdist", str(sdist), "--out", str(out / "bag"), "--mesh-out", str(out / "street.ply")])
    assert rc == 0
    return out / "bag", out / "street.ply", stdout.getvalue()


@pytest.mark.slow
def test_every_complete_scan_becomes_one_frame(recording, imported):
    # 192 lidar packets of 16 columns in the pcap: exactly three 1024-column scans
    assert [s.frame_id for s in recording.scans] == [1795, 1796, 1797]
    frames = list(read_clouds(imported[0]))
    assert len(frames) == len(recording.scans) == len(recording.poses) == 3
    assert [f.stamp_ns for f in frames] == [int(s.timestamp_ns[0]) for s in recording.scans]
    assert np.diff([f.stamp_ns for f in frames]) * 1e-9 == pytest.approx([0.1, 0.1], abs=1e-3)  # 10 Hz
    assert all(f.frame_id == FRAME_LIDAR for f in frames)


def test_points_per_frame_and_layout(imported):
    for frame in read_clouds(imported[0]):
        pts = frame.points
        assert pts.dtype == POINT_DTYPE_NO_EPW and "epw" not in pts.dtype.names  # no EPW: filters fall back
        assert 0.75 * PIXELS < len(pts) < 0.9 * PIXELS  # 107 357-107 647 returns of 131 072 beams
        assert frame.dropped_nonfinite == 0
        assert np.all(pts["echo"] == 1) and np.all(pts["return_type"] == 3)
        assert 0 <= pts["time_stamp"].min() and pts["time_stamp"].max() < 0.1e9  # one 10 Hz rotation


def test_ranges_within_the_sensor_limits(recording):
    limits = load_profile("os1_128_1024").range
    for k in range(len(recording.scans)):
        r = recording.points(k)["distance"]
        assert limits.min_m <= r.min() and r.max() <= RNG15_MAX_M
        assert np.mean(r <= limits.max_m) > 0.999  # a handful of returns up to 247 m
        assert 10.0 < np.median(r) < 13.0


def test_128_channels_numbered_from_the_lowest_beam(recording):
    pts = recording.points(0)
    assert np.unique(pts["channel"]).tolist() == list(range(128))
    by_channel = [np.median(pts["elevation"][pts["channel"] == c]) for c in (0, 64, 127)]
    assert by_channel == sorted(by_channel)


def test_xyz_follows_ouster_formula(recording):
    """A few pixels recomputed one by one from the metadata (the module does it vectorised)."""
    meta, scan = recording.meta, recording.scans[1]
    pts = recording.points(1)
    rows, cols = np.nonzero(scan.range_mm > 0)
    for row, col in zip(rows[:: len(rows) // 7], cols[:: len(rows) // 7]):
        r, n = scan.range_mm[row, col], meta.beam_origin_mm[0]
        theta = 2 * math.pi * (1 - col / meta.columns)
        azimuth, altitude = theta - math.radians(meta.azimuth_deg[row]), math.radians(meta.altitude_deg[row])
        lidar = np.array([(r - n) * math.cos(azimuth) * math.cos(altitude) + n * math.cos(theta),
                          (r - n) * math.sin(azimuth) * math.cos(altitude) + n * math.sin(theta),
                          (r - n) * math.sin(altitude)])  # fmt: skip
        expected = (meta.lidar_to_sensor[:3, :3] @ lidar + meta.lidar_to_sensor[:3, 3]) * 1e-3
        stamp = scan.timestamp_ns[col] - scan.timestamp_ns[0]
        match = pts[(pts["time_stamp"] == stamp) & np.isclose(pts["distance"], np.linalg.norm(expected), atol=1e-4)]
        assert len(match) == 1
        assert [match["x"][0], match["y"][0], match["z"][0]] == pytest.approx(expected, abs=1e-5)


def test_tf_carries_the_kitti_poses_at_mid_scan(recording, imported):
    tf = [m.msg.transforms[0] for m in read_messages(imported[0], [TOPIC_TF])]
    static = [m.msg.transforms[0] for m in read_messages(imported[0], [TOPIC_TF_STATIC])]
    assert [(s.header.frame_id, s.child_frame_id) for s in static] == [("base_link", "lidar")]
    assert static[0].transform.rotation.w == 1.0 and static[0].transform.translation.x == 0.0
    stamps = {t.header.stamp.sec * 10**9 + t.header.stamp.nanosec: t.transform for t in tf}
    assert {(t.header.frame_id, t.child_frame_id) for t in tf} == {(FRAME_MAP, "base_link")}
    assert min(stamps) <= recording.scans[0].timestamp_ns[0] and max(stamps) >= recording.scans[-1].timestamp_ns[-1]
    for key, pose in zip(recording.pose_ns.tolist(), recording.poses):
        t = stamps[key]
        assert [t.translation.x, t.translation.y, t.translation.z] == pytest.approx(pose[:3, 3], abs=1e-12)
        q = [t.rotation.x, t.rotation.y, t.rotation.z, t.rotation.w]
        assert Rotation.from_quat(q).as_matrix() == pytest.approx(pose[:3, :3], abs=1e-9)


def test_mesh_loads_and_every_frame_lies_on_it(imported):
    """Each point placed with the bag's /tf at its firing time: median distance to the mesh a few cm."""
    import open3d as o3d

    bag, mesh_path, stdout = imported
    mesh = load_static_mesh(mesh_path, material=0, object_id=1)
    assert len(mesh.triangles) > 100_000
    scene = o3d.t.geometry.RaycastingScene()
    scene.add_triangles(o3d.core.Tensor(mesh.vertices.astype(np.float32)), o3d.core.Tensor(mesh.triangles.astype(np.uint32)))
    buffer = TransformBuffer(cache_time_s=60.0, extrapolation_tolerance_s=0.0)
    for m in read_messages(bag, [TOPIC_TF, TOPIC_TF_STATIC]):
        add_tf_message(buffer, m.msg, static=m.topic == TOPIC_TF_STATIC)
    medians = []
    for frame in read_clouds(bag):
        p = frame.points
        t, q = buffer.lookup_many(FRAME_MAP, frame.frame_id, frame.stamp_ns + p["time_stamp"].astype(np.int64))
        xyz = Rotation.from_quat(q).apply(np.column_stack([p["x"], p["y"], p["z"]]).astype(np.float64)) + t
        medians.append(float(np.median(scene.compute_distance(o3d.core.Tensor(xyz.astype(np.float32))).numpy())))
    assert max(medians) < 0.03  # 1.1, 1.1, 1.3 cm
    assert "median point-to-mesh distance per frame: " + ", ".join(f"{d * 100:.1f} cm" for d in medians) in stdout


def test_elevation_per_channel_matches_the_generated_profile(recording):
    """config/sensors/os1_128_1024.yaml (scripts/make_sensor_profiles.py, same metadata) against the points.

    Elevations are taken from the lidar origin (36 mm above the sensor origin) and the beam
    origin (16 mm out): seen from there every point lies on its beam to well under 0.01 deg.
    """
    profile = load_profile("os1_128_1024")
    beams = [profile.beams[i] for i in profile.channel_order]
    lift, out = recording.meta.lidar_to_sensor[2, 3] * 1e-3, np.hypot(*recording.meta.beam_origin_mm) * 1e-3
    pts = np.concatenate([recording.points(k) for k in range(len(recording.scans))])
    elevation = np.degrees(np.arctan2(pts["z"] - lift, np.hypot(pts["x"], pts["y"]) - out))
    expected = np.array([b.elevation_deg for b in beams])[pts["channel"]]
    assert np.abs(elevation - expected).max() < 0.005
    # azimuth offsets (REP-103 sign) against each point's column direction, returns beyond 5 m
    scan, pts = recording.scans[0], recording.points(0)
    column = np.searchsorted(scan.timestamp_ns - scan.timestamp_ns[0], pts["time_stamp"])
    offset = np.degrees(np.angle(np.exp(1j * (pts["azimuth"] - 2 * np.pi * (1 - column / 1024) - np.pi))))
    far = pts["distance"] > 5.0
    measured = [np.median(offset[far & (pts["channel"] == c)]) for c in range(128)]
    assert measured == pytest.approx([b.azimuth_offset_deg for b in beams], abs=0.02)


def _copy_sdist(sdist, target, pcap: bytes | None = None):
    """An uncompressed tar with the four members of ``sdist``, the pcap optionally replaced."""
    with tarfile.open(sdist) as src, tarfile.open(target, "w") as dst:
        for key, name in MEMBERS.items():
            data = src.extractfile(f"ouster_sdk-1.0.1/{name}").read()
            data = pcap if key == "pcap" and pcap is not None else data
            info = tarfile.TarInfo(f"ouster_sdk-1.0.1/{name}")
            info.size = len(data)
            dst.addfile(info, io.BytesIO(data))
    return target


@pytest.fixture(scope="module")
def pcap_bytes(sdist):
    with tarfile.open(sdist) as tar:
        return tar.extractfile(f"ouster_sdk-1.0.1/{MEMBERS['pcap']}").read()


@pytest.mark.parametrize("cut, reason", [(-1000, "truncated packet record"), (0, "not a libpcap file")])
def test_malformed_pcap_is_named_in_one_line_errors(sdist, pcap_bytes, tmp_path, capsys, cut, reason):
    data = pcap_bytes[:cut] if cut else b"\x00" * 100
    bad = _copy_sdist(sdist, tmp_path / "bad.tar", data)
    with pytest.raises(OusterFormatError, match=reason) as err:
        load_recording(bad)
    assert f"{bad}:{MEMBERS['pcap']}" in str(err.value)
    assert main(["import-ouster", "--sdist", str(bad), "--out", str(tmp_path / "out")]) == 2
    message = capsys.readouterr().err
    assert message.count("\n") == 1 and f"{bad}:{MEMBERS['pcap']}" in message and reason in message
    assert not (tmp_path / "out").exists()


def test_a_pcap_missing_a_scan_does_not_match_its_poses(sdist, pcap_bytes, tmp_path):
    """Drop the last 64 lidar packets (one scan) at record boundaries: two scans for three poses."""
    records, offset = [], 24
    while offset < len(pcap_bytes):
        size = int.from_bytes(pcap_bytes[offset + 8 : offset + 12], "little")
        records.append(pcap_bytes[offset : offset + 16 + size])
        offset += 16 + size
    lidar = [i for i, r in enumerate(records) if len(r) > 1000]
    kept = pcap_bytes[:24] + b"".join(r for i, r in enumerate(records) if i not in set(lidar[-64:]))
    with pytest.raises(OusterFormatError, match="3 poses of 12 values for 2 complete scans"):
        load_recording(_copy_sdist(sdist, tmp_path / "short.tar", kept))
