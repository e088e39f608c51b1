"""Malformed input without ROS: every malformed cloud decodes or raises CloudFormatError; the odometry gate."""

import copy
from types import SimpleNamespace

import numpy as np
import pytest

from lidar_weather_sim.io.bags import message_types
from lidar_weather_sim.io.cloud_codec import CloudFormatError, build_message, decode_message
from lidar_weather_sim.poses.gate import PoseGate
from lidar_weather_sim.poses.sources import parse_odometry
from lidar_weather_sim.testing.malformed import (
    CLOUD_KINDS,
    DECODABLE_KINDS,
    ODOMETRY_KINDS,
    malformed_cloud,
    malformed_odometry,
)

S = 1_000_000_000


def good_cloud(n=500, seed=0):
    rng = np.random.default_rng(seed)
    pts = np.zeros(n, dtype=[("x", "<f4"), ("y", "<f4"), ("z", "<f4"), ("intensity", "<f4"), ("echo", "u1")])
    for k in ("x", "y", "z", "intensity"):
        pts[k] = rng.uniform(-50, 50, n)
    return pts, build_message(pts, stamp_ns=7 * S, frame_id="lidar", types=message_types())[0]


def test_every_malformed_cloud_is_decoded_or_refused_with_a_reason():
    points, good = good_cloud()
    types = message_types()
    rng = np.random.default_rng(1)
    seen = {}
    for _ in range(2000):
        kind, msg = malformed_cloud(good, rng, copy.deepcopy, types.PointField)
        try:
            out = decode_message(msg).points
        except CloudFormatError as exc:
            assert exc.cause and str(exc)
            seen[kind] = seen.get(kind, 0) + 1
            continue
        assert out.nbytes <= len(bytes(msg.data)), kind  # nothing allocated beyond the data received
        assert np.isfinite(out["x"]).all() and out["x"].ndim == 1, kind
        # only these kinds may decode: the DDS tests rely on every other kind being refused, every draw
        assert kind in {"nonfinite", *DECODABLE_KINDS}, (kind, msg.width, msg.height, msg.point_step, msg.row_step)
    # NaN points are dropped; valid clouds with values no filter can use (weather_filter.points.cloud_check) decode
    assert set(seen) == set(CLOUD_KINDS) - {"nonfinite", *DECODABLE_KINDS}
    np.testing.assert_array_equal(decode_message(good).points, points)  # the good message was not touched


def test_malformed_streams_are_seeded():
    _, good = good_cloud()
    types = message_types()
    a = [malformed_cloud(good, np.random.default_rng(5), copy.deepcopy, types.PointField) for _ in range(3)]
    b = [malformed_cloud(good, np.random.default_rng(5), copy.deepcopy, types.PointField) for _ in range(3)]
    assert [(k, bytes(m.data), m.width, len(m.fields)) for k, m in a] == [(k, bytes(m.data), m.width, len(m.fields)) for k, m in b]


def odometry(ns, x):
    v = SimpleNamespace
    return v(header=v(stamp=v(sec=ns // S, nanosec=ns % S), frame_id="odom"), child_frame_id="base_link",
             pose=v(pose=v(position=v(x=x, y=0.0, z=0.0), orientation=v(x=0.0, y=0.0, z=0.0, w=1.0))))  # fmt: skip


def test_gate_refuses_every_malformed_odometry_kind_and_keeps_the_good_stream():
    rng = np.random.default_rng(3)
    gate, accepted, refused = PoseGate(max_gap_s=1.0, max_speed_m_s=100.0), [], {}
    for k in range(400):
        good = odometry(100 * S + k * 10_000_000, 25.0 * k * 0.01)  # 25 m/s at 100 Hz
        for msg, kind in [(good, None), *[(m, c) for c, m in [malformed_odometry(good, rng, copy.deepcopy)]]]:
            try:
                stamp, pose = parse_odometry(msg, "odom", "base_link")
                why = gate.check(stamp, pose.translation)
            except ValueError as exc:
                why = str(exc)
            if why is None:
                accepted.append((kind, stamp))
            else:
                refused[kind] = refused.get(kind, 0) + 1
    assert {kind for kind, _ in accepted} == {None}, "a malformed pose passed"
    assert len(accepted) == 400 and None not in refused
    assert set(refused) == set(ODOMETRY_KINDS)


def test_gate_accepts_a_jump_that_the_next_sample_confirms():
    gate = PoseGate(max_gap_s=1.0, max_speed_m_s=100.0)
    assert gate.check(0, (0, 0, 0)) is None and gate.check(10_000_000, (0.25, 0, 0)) is None
    assert "stamp jumps +59.990 s" in gate.check(60 * S, (5000, 0, 0))  # a bag seek: refused once ...
    assert gate.check(60 * S + 10_000_000, (5000.25, 0, 0)) is None and gate.jumped  # ... then confirmed
    assert gate.check(60 * S + 20_000_000, (5000.5, 0, 0)) is None and not gate.jumped
    assert "m/s" in gate.check(60 * S + 30_000_000, (0, 0, 0))
    with pytest.raises(ValueError, match="max_gap_s"):
        PoseGate(max_gap_s=0.0)
