"""Tests for lidar_weather_sim.poses.tf_buffer (expected values computed by hand)."""

import math
import threading
from types import SimpleNamespace

import numpy as np
import pytest

from lidar_weather_sim.poses.tf_buffer import (
    ConnectivityError,
    ExtrapolationError,
    Transform,
    TransformBuffer,
    TransformError,
    UnknownFrameError,
)

S = 1_000_000_000  # ns per second


def yaw_q(deg):
    h = math.radians(deg) / 2
    return (0.0, 0.0, math.sin(h), math.cos(h))


def pitch_q(rad):
    return (0.0, math.sin(rad / 2), 0.0, math.cos(rad / 2))


def same_rotation(q, expected):
    """Quaternions q and -q are the same rotation."""
    return np.allclose(q, expected, atol=1e-9) or np.allclose(q, -np.asarray(expected), atol=1e-9)


# -- Transform ---------------------------------------------------------------
def test_transform_compose_order_inverse_and_matrix():
    a = Transform((1.0, 0.0, 0.0), (0, 0, 0, 1))
    b = Transform((0.0, 0.0, 0.0), yaw_q(90))
    # a * b applies b first: (1,0,0) -> b -> (0,1,0) -> a -> (1,1,0)
    np.testing.assert_allclose((a * b).apply([[1.0, 0.0, 0.0]]), [[1.0, 1.0, 0.0]], atol=1e-12)
    np.testing.assert_allclose(b.compose(a).apply([[1.0, 0.0, 0.0]]), [[0.0, 2.0, 0.0]], atol=1e-12)

    c = Transform((1.0, 2.0, 3.0), yaw_q(90))
    np.testing.assert_allclose(c.as_matrix(), [[0, -1, 0, 1], [1, 0, 0, 2], [0, 0, 1, 3], [0, 0, 0, 1]],
                               atol=1e-12)
    np.testing.assert_allclose(c.inverse().translation, [-2.0, 1.0, -3.0], atol=1e-12)
    np.testing.assert_allclose((c * c.inverse()).as_matrix(), np.eye(4), atol=1e-12)
    d = Transform.from_matrix(c.as_matrix())
    np.testing.assert_allclose(d.translation, [1, 2, 3])
    assert same_rotation(d.rotation, yaw_q(90))
    np.testing.assert_allclose(Transform.identity().as_matrix(), np.eye(4))
    # rotation is normalised, output is float64 (N, 3)
    e = Transform([0, 0, 0], [0, 0, 2, 2])
    assert same_rotation(e.rotation, yaw_q(90))
    out = e.apply(np.array([[1, 0, 0], [0, 1, 0]], dtype=np.float32))
    assert out.dtype == np.float64 and out.shape == (2, 3)
    np.testing.assert_allclose(out, [[0, 1, 0], [-1, 0, 0]], atol=1e-7)


# -- interpolation -----------------------------------------------------------
def two_pose_buffer(**kw):
    buf = TransformBuffer(**kw)
    buf.set_transform("map", "base_link", 1 * S, (0, 0, 0), yaw_q(0))
    buf.set_transform("map", "base_link", 2 * S, (2, 4, -6), yaw_q(90))
    return buf


def test_interpolation_halfway_and_quarter():
    buf = two_pose_buffer()
    half = buf.lookup("map", "base_link", 1_500_000_000)
    np.testing.assert_allclose(half.translation, [1, 2, -3], atol=1e-12)
    assert same_rotation(half.rotation, (0, 0, math.sin(math.radians(22.5)), math.cos(math.radians(22.5))))
    c45 = math.cos(math.radians(45))
    np.testing.assert_allclose(Transform.identity().compose(half).apply([[1, 0, 0]]),
                               [[1 + c45, 2 + c45, -3]], atol=1e-12)
    rot_only = Transform((0, 0, 0), half.rotation)
    np.testing.assert_allclose(rot_only.apply([[1, 0, 0]]), [[c45, c45, 0]], atol=1e-12)

    quarter = buf.lookup("map", "base_link", 1_250_000_000)
    np.testing.assert_allclose(quarter.translation, [0.5, 1, -1.5], atol=1e-12)
    assert same_rotation(quarter.rotation, yaw_q(22.5))
    np.testing.assert_allclose(Transform((0, 0, 0), quarter.rotation).apply([[1, 0, 0]]),
                               [[math.cos(math.radians(22.5)), math.sin(math.radians(22.5)), 0]], atol=1e-12)
    # exactly on the samples
    np.testing.assert_allclose(buf.lookup("map", "base_link", 2 * S).translation, [2, 4, -6])


def test_slerp_takes_shortest_arc():
    buf = TransformBuffer()
    buf.set_transform("map", "a", 1 * S, (0, 0, 0), yaw_q(0))
    buf.set_transform("map", "a", 2 * S, (0, 0, 0), -np.array(yaw_q(90)))  # same rotation as +q
    assert same_rotation(buf.lookup("map", "a", 1_500_000_000).rotation, yaw_q(45))

    buf.set_transform("map", "b", 1 * S, (0, 0, 0), yaw_q(170))
    buf.set_transform("map", "b", 2 * S, (0, 0, 0), yaw_q(-170))  # 20 deg apart through 180
    mid = buf.lookup("map", "b", 1_500_000_000)
    assert same_rotation(mid.rotation, yaw_q(180))
    np.testing.assert_allclose(mid.apply([[1, 0, 0]]), [[-1, 0, 0]], atol=1e-12)
    quarter = buf.lookup("map", "b", 1_250_000_000)
    assert same_rotation(quarter.rotation, yaw_q(175))


# -- chains ------------------------------------------------------------------
PITCH = math.radians(5.0)


def robot_buffer():
    buf = TransformBuffer()
    buf.set_transform("map", "base_link", 1 * S, (10, 0, 0), yaw_q(0))
    buf.set_transform("map", "base_link", 3 * S, (20, 0, 0), yaw_q(90))
    buf.set_transform("base_link", "lidar", 0, (1.5, 0, 1.8), pitch_q(PITCH), static=True)
    buf.set_transform("base_link", "imu", 0, (0.2, -0.1, 0.3), (0, 0, 0, 1), static=True)
    return buf


def test_chain_map_base_link_lidar():
    buf = robot_buffer()
    tf = buf.lookup("map", "lidar", 2 * S)  # base_link at (15, 0, 0), yaw 45 deg
    p_lidar = np.array([[10.0, 0.0, 2.0]])
    # lidar -> base_link: pitch about y maps (x, z) to (x cos + z sin, -x sin + z cos)
    c, s = math.cos(PITCH), math.sin(PITCH)
    bx, bz = 1.5 + 10 * c + 2 * s, 1.8 - 10 * s + 2 * c
    # base_link -> map: yaw 45 deg, then + (15, 0, 0)
    c45 = math.cos(math.radians(45))
    expected = [[15 + bx * c45, bx * c45, bz]]
    np.testing.assert_allclose(tf.apply(p_lidar), expected, atol=1e-9)

    inv = buf.lookup("lidar", "map", 2 * S)
    np.testing.assert_allclose(inv.apply(expected), p_lidar, atol=1e-9)
    np.testing.assert_allclose((inv * tf).as_matrix(), np.eye(4), atol=1e-12)


def test_siblings_go_through_common_parent_and_ignore_time():
    buf = robot_buffer()
    c, s = math.cos(PITCH), math.sin(PITCH)
    expected = [[1.5 + 10 * c - 0.2, 0.1, 1.8 - 10 * s - 0.3]]
    for t in (2 * S, 100 * S):  # map->base_link has no data at 100 s; it is not on the path
        tf = buf.lookup("imu", "lidar", t)
        np.testing.assert_allclose(tf.apply([[10.0, 0, 0]]), expected, atol=1e-12)


def test_same_frame_is_identity_and_leading_slash_stripped():
    buf = TransformBuffer()
    buf.set_transform("/map", "/base_link", 1 * S, (1, 2, 3), yaw_q(30))
    assert buf.frames() == {"map", "base_link"}
    np.testing.assert_allclose(buf.lookup("base_link", "/base_link", 5 * S).as_matrix(), np.eye(4))
    np.testing.assert_allclose(buf.lookup("/map", "base_link", 1 * S).translation, [1, 2, 3])
    with pytest.raises(UnknownFrameError):
        buf.lookup("nowhere", "nowhere", 1 * S)


def test_reparenting_replaces_the_parent_and_loops_are_rejected():
    buf = TransformBuffer()
    buf.set_transform("map", "base_link", 1 * S, (1, 0, 0), yaw_q(0))
    buf.set_transform("odom", "base_link", 1 * S, (2, 0, 0), yaw_q(0))
    np.testing.assert_allclose(buf.lookup("odom", "base_link", 1 * S).translation, [2, 0, 0])
    with pytest.raises(TransformError):
        buf.lookup("map", "base_link", 1 * S)
    with pytest.raises(ValueError):
        buf.set_transform("base_link", "odom", 1 * S, (0, 0, 0), yaw_q(0))
    with pytest.raises(ValueError):
        buf.set_transform("odom", "odom", 1 * S, (0, 0, 0), yaw_q(0))


# -- errors ------------------------------------------------------------------
def test_unknown_frame_error_names_frame_and_known_frames():
    buf = robot_buffer()
    with pytest.raises(UnknownFrameError) as err:
        buf.lookup("map", "radar", 2 * S)
    msg = str(err.value)
    assert "radar" in msg and "lidar" in msg and "base_link" in msg
    assert isinstance(err.value, LookupError)
    assert not buf.can_transform("map", "radar", 2 * S)


def test_disjoint_trees_raise_connectivity_error():
    buf = robot_buffer()
    buf.set_transform("world2", "cam", 0, (0, 0, 0), (0, 0, 0, 1), static=True)
    with pytest.raises(ConnectivityError) as err:
        buf.lookup("cam", "lidar", 2 * S)
    assert "cam" in str(err.value) and "lidar" in str(err.value)
    assert buf.can_transform("map", "lidar", 2 * S)


def test_extrapolation_error_and_clamping_within_tolerance():
    buf = two_pose_buffer(extrapolation_tolerance_s=0.05)
    with pytest.raises(ExtrapolationError) as err:
        buf.lookup("map", "base_link", 2_200_000_000)
    msg = str(err.value)
    assert "2.200000000" in msg and "1.000000000" in msg and "2.000000000" in msg
    assert "map" in msg and "base_link" in msg and "0.05" in msg
    with pytest.raises(ExtrapolationError, match="0.900000000"):
        buf.lookup("map", "base_link", 900_000_000)
    late = buf.lookup("map", "base_link", 2_040_000_000)  # clamped to the 2 s sample
    np.testing.assert_allclose(late.translation, [2, 4, -6])
    assert same_rotation(late.rotation, yaw_q(90))
    np.testing.assert_allclose(buf.lookup("map", "base_link", 960_000_000).translation, [0, 0, 0])
    # one bad time in a batch fails the batch
    with pytest.raises(ExtrapolationError, match="2.100000000"):
        buf.lookup_many("map", "base_link", np.array([1_500_000_000, 2_100_000_000]))


def test_single_sample_dynamic_edge_only_within_tolerance():
    buf = TransformBuffer(extrapolation_tolerance_s=0.05)
    buf.set_transform("map", "base_link", 5 * S, (1, 2, 3), yaw_q(10))
    np.testing.assert_allclose(buf.lookup("map", "base_link", 5 * S + 40_000_000).translation, [1, 2, 3])
    np.testing.assert_allclose(buf.lookup("map", "base_link", 5 * S - 40_000_000).translation, [1, 2, 3])
    assert not buf.can_transform("map", "base_link", 5 * S + 60_000_000)
    assert not buf.can_transform("map", "base_link", 4 * S)


def test_stamp_zero_is_latest_common_time():
    buf = TransformBuffer()
    for k in range(1, 6):  # map->base_link has 1..5 s, base_link->lidar only 1..3 s
        buf.set_transform("map", "base_link", k * S, (k, 0, 0), yaw_q(0))
    for k in range(1, 4):
        buf.set_transform("base_link", "lidar", k * S, (0, 0, k), yaw_q(0))
    np.testing.assert_allclose(buf.lookup("map", "lidar", 0).translation, [3, 0, 3])
    np.testing.assert_allclose(buf.lookup("map", "base_link", 0).translation, [5, 0, 0])
    t, _ = buf.lookup_many("map", "lidar", np.array([0, 2 * S]))
    np.testing.assert_allclose(t, [[3, 0, 3], [2, 0, 2]])
    static = robot_buffer()  # only static edges between lidar and imu
    np.testing.assert_allclose(static.lookup("base_link", "imu", 0).translation, [0.2, -0.1, 0.3])


# -- storage -----------------------------------------------------------------
def test_cache_pruning_keeps_cache_time_of_history():
    buf = TransformBuffer(cache_time_s=2.0, extrapolation_tolerance_s=0.05)
    for k in range(11):
        buf.set_transform("map", "base_link", k * S, (k, 0, 0), yaw_q(0))
    assert buf.time_range("base_link") == (8 * S, 10 * S)
    np.testing.assert_allclose(buf.lookup("map", "base_link", 8_500_000_000).translation, [8.5, 0, 0])
    with pytest.raises(ExtrapolationError):
        buf.lookup("map", "base_link", 7_500_000_000)
    buf.set_transform("map", "base_link", 3 * S, (3, 0, 0), yaw_q(0))  # too old: dropped
    assert buf.time_range("base_link") == (8 * S, 10 * S)
    buf.set_transform("map", "base_link", 9_500_000_000, (100, 0, 0), yaw_q(0))  # inside the window
    np.testing.assert_allclose(buf.lookup("map", "base_link", 9_500_000_000).translation, [100, 0, 0])
    buf.set_transform("map", "base_link", 9_500_000_000, (9.5, 0, 0), yaw_q(0))  # same stamp: replaced
    for t in (9_250_000_000, 9_500_000_000, 9_750_000_000):
        np.testing.assert_allclose(buf.lookup("map", "base_link", t).translation, [t / S, 0, 0])


def random_samples(rng, n):
    stamps = np.sort(rng.choice(np.arange(1, 20 * S, 1_000_000), n, replace=False))
    trans = rng.normal(size=(n, 3)) * 5
    quats = rng.normal(size=(n, 4))
    return stamps, trans, quats / np.linalg.norm(quats, axis=1, keepdims=True)


def test_out_of_order_insertion_matches_in_order():
    rng = np.random.default_rng(1)
    stamps, trans, quats = random_samples(rng, 50)
    ordered, shuffled = TransformBuffer(cache_time_s=100), TransformBuffer(cache_time_s=100)
    for i in range(50):
        ordered.set_transform("map", "base_link", int(stamps[i]), trans[i], quats[i])
    for i in rng.permutation(50):
        shuffled.set_transform("map", "base_link", int(stamps[i]), trans[i], quats[i])
    query = rng.integers(stamps[0], stamps[-1], 500)
    ta, qa = ordered.lookup_many("map", "base_link", query)
    tb, qb = shuffled.lookup_many("map", "base_link", query)
    np.testing.assert_array_equal(ta, tb)
    np.testing.assert_array_equal(qa, qb)
    assert shuffled.time_range("base_link") == (int(stamps[0]), int(stamps[-1]))


def test_single_edge_matches_scipy_slerp_and_numpy_interp():
    from scipy.spatial.transform import Rotation, Slerp

    rng = np.random.default_rng(2)
    stamps, trans, quats = random_samples(rng, 40)
    buf = TransformBuffer(cache_time_s=100)
    for i in range(40):
        buf.set_transform("odom", "base_link", int(stamps[i]), trans[i], quats[i])
    query = rng.integers(stamps[0], stamps[-1], 1000)
    t, q = buf.lookup_many("odom", "base_link", query)
    ref_t = np.stack([np.interp(query, stamps, trans[:, k]) for k in range(3)], axis=1)
    ref_r = Slerp(stamps.astype(float), Rotation.from_quat(quats))(query.astype(float))
    np.testing.assert_allclose(t, ref_t, atol=1e-9)
    np.testing.assert_allclose(Rotation.from_quat(q).as_matrix(), ref_r.as_matrix(), atol=1e-9)


def test_lookup_many_equals_lookup_per_element():
    rng = np.random.default_rng(3)
    buf = TransformBuffer(cache_time_s=100)
    for child, parent in (("odom", "map"), ("base_link", "odom")):
        stamps, trans, quats = random_samples(rng, 30)
        stamps[0], stamps[-1] = 1, 20 * S  # both edges cover the query range
        for i in range(30):
            buf.set_transform(parent, child, int(stamps[i]), trans[i], quats[i])
    buf.set_transform("base_link", "lidar", 0, (1.5, 0, 1.8), pitch_q(PITCH), static=True)
    buf.set_transform("odom", "gps", 0, (0.3, 0.2, 2.0), yaw_q(-30), static=True)
    query = rng.integers(1, 20 * S, 1000)
    for target, source in (("map", "lidar"), ("lidar", "map"), ("gps", "lidar")):
        t, q = buf.lookup_many(target, source, query)
        assert t.shape == (1000, 3) and q.shape == (1000, 4) and t.dtype == np.float64
        for k in range(1000):
            tf = buf.lookup(target, source, int(query[k]))
            np.testing.assert_allclose(t[k], tf.translation, rtol=0, atol=1e-12)
            assert same_rotation(q[k], tf.rotation)


# -- messages ----------------------------------------------------------------
def ns_transform(parent, child, sec, nanosec, xyz, xyzw):
    v = SimpleNamespace
    return v(header=v(stamp=v(sec=sec, nanosec=nanosec), frame_id=parent), child_frame_id=child,
             transform=v(translation=v(x=xyz[0], y=xyz[1], z=xyz[2]),
                         rotation=v(x=xyzw[0], y=xyzw[1], z=xyzw[2], w=xyzw[3])))


def test_add_tf_message_duck_typed():
    buf = TransformBuffer()
    buf.add_tf_message(SimpleNamespace(transforms=[
        ns_transform("/map", "base_link", 1, 0, (0, 0, 0), yaw_q(0)),
        ns_transform("map", "base_link", 2, 0, (2, 0, 0), yaw_q(90))]))
    buf.add_tf_message(SimpleNamespace(transforms=[
        ns_transform("base_link", "lidar", 0, 0, (1.5, 0, 1.8), yaw_q(0))]), static=True)
    np.testing.assert_allclose(buf.lookup("map", "base_link", 1_500_000_000).translation, [1, 0, 0])
    tf = buf.lookup("map", "lidar", 2 * S)  # (1.5, 0, 1.8) yawed 90 deg + (2, 0, 0)
    np.testing.assert_allclose(tf.translation, [2, 1.5, 1.8], atol=1e-12)
    assert buf.time_range("lidar") is None and buf.time_range("base_link") == (1 * S, 2 * S)


def test_add_tf_message_skips_only_the_bad_transform():
    buf = TransformBuffer()
    rejected = buf.add_tf_message(SimpleNamespace(transforms=[
        ns_transform("map", "base_link", 1, 0, (0, 0, 0), (0, 0, 0, 0)),
        ns_transform("map", "odom", 1, 0, (3, 0, 0), yaw_q(0))]))
    assert len(rejected) == 1 and rejected[0].startswith("map -> base_link")
    np.testing.assert_allclose(buf.lookup("map", "odom", S).translation, [3, 0, 0])


def test_add_tf_message_rclpy():
    tf2_msgs = pytest.importorskip("tf2_msgs.msg")
    from geometry_msgs.msg import TransformStamped

    def stamped(parent, child, sec, nanosec, xyz, xyzw):
        m = TransformStamped()
        m.header.frame_id, m.child_frame_id = parent, child
        m.header.stamp.sec, m.header.stamp.nanosec = sec, nanosec
        m.transform.translation.x, m.transform.translation.y, m.transform.translation.z = map(float, xyz)
        r = m.transform.rotation
        r.x, r.y, r.z, r.w = map(float, xyzw)
        return m

    buf = TransformBuffer()
    buf.add_tf_message(tf2_msgs.TFMessage(transforms=[
        stamped("map", "base_link", 1, 500_000_000, (0, 0, 0), yaw_q(0)),
        stamped("map", "base_link", 2, 500_000_000, (4, 0, 0), yaw_q(90))]))
    buf.add_tf_message(tf2_msgs.TFMessage(transforms=[
        stamped("base_link", "lidar", 0, 0, (1, 0, 0), (0, 0, 0, 1))]), static=True)
    tf = buf.lookup("map", "lidar", 2 * S)  # halfway: (2, 0, 0), yaw 45 deg
    c45 = math.cos(math.radians(45))
    np.testing.assert_allclose(tf.translation, [2 + c45, c45, 0], atol=1e-12)
    assert buf.time_range("base_link") == (1_500_000_000, 2_500_000_000)


# -- misc --------------------------------------------------------------------
def test_concurrent_writers_and_readers():
    buf = TransformBuffer(cache_time_s=0.5)
    buf.set_transform("map", "base_link", 1, (0, 0, 0), yaw_q(0))
    errors = []

    def write():
        for k in range(2, 2000):
            buf.set_transform("map", "base_link", k * 1_000_000, (k, 0, 0), yaw_q(0))

    writer = threading.Thread(target=write)
    writer.start()
    while writer.is_alive():
        try:
            t, _ = buf.lookup_many("map", "base_link", np.array([0, 0]))
            assert t[0, 0] == t[1, 0] and t[0, 0] >= 0
        except Exception as e:  # pragma: no cover - only on failure
            errors.append(e)
    writer.join()
    assert not errors
    np.testing.assert_allclose(buf.lookup("map", "base_link", 0).translation, [1999, 0, 0])

