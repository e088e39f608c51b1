"""Tests for lidar_weather_sim.poses.sources (messages duck-typed with SimpleNamespace; no ROS)."""

import math
from types import SimpleNamespace as NS

import numpy as np
import pytest

from lidar_weather_sim.core.geometry import matrix_quaternion
from lidar_weather_sim.poses.sources import (
    TfPoseSource,
    add_odometry,
    add_tf_message,
    mount_transform,
    set_static_mount,
    stamp_ns,
)
from lidar_weather_sim.poses.tf_buffer import TransformBuffer
from lidar_weather_sim.scenario.schema import load_scenario
from lidar_weather_sim.scenario.world import World
from lidar_weather_sim.sim.simulator import LidarSimulator

S = 1_000_000_000
EPOCH = 1_700_000_000 * S  # a wall-clock-like origin: float64 seconds would lose the nanoseconds here


def stamp(ns):
    return NS(sec=ns // S, nanosec=ns % S)


def tf(parent, child, ns, t=(0.0, 0.0, 0.0), q=(0.0, 0.0, 0.0, 1.0)):
    return NS(header=NS(stamp=stamp(ns), frame_id=parent), child_frame_id=child,
              transform=NS(translation=NS(x=t[0], y=t[1], z=t[2]), rotation=NS(x=q[0], y=q[1], z=q[2], w=q[3])))  # fmt: skip


def odometry(ns, t, q=(0.0, 0.0, 0.0, 1.0), frame="", child=""):
    pose = NS(position=NS(x=t[0], y=t[1], z=t[2]), orientation=NS(x=q[0], y=q[1], z=q[2], w=q[3]))
    return NS(header=NS(stamp=stamp(ns), frame_id=frame), child_frame_id=child, pose=NS(pose=pose))


@pytest.fixture(scope="module")
def world():
    return World.build(load_scenario("highway_clear"))


def buffer_from_player(world, origin_ns, duration_s=0.5, rate_hz=100):
    """/tf of the scenario's base_link at ``rate_hz`` plus the mount on /tf_static, as a bag would hold them."""
    player = world.player
    buffer = TransformBuffer(extrapolation_tolerance_s=0.0)
    times = np.arange(round(duration_s * rate_hz) + 1) / rate_hz
    pos, quat = player.base_link_poses(times)
    for t, p, q in zip(times, pos, quat):
        stored, problems = add_tf_message(buffer, NS(transforms=[tf("map", "base_link", origin_ns + round(t * S), p, q)]))
        assert len(stored) == 1 and not problems
    m = player.mount
    add_tf_message(buffer, NS(transforms=[tf("base_link", "lidar", 0, m[:3, 3], matrix_quaternion(m[:3, :3]))]), True)
    return buffer


def test_tf_pose_source_reproduces_the_player_poses(world):
    source = TfPoseSource(buffer_from_player(world, EPOCH), "map", "lidar", world.player.actor_poses, EPOCH)
    times = np.linspace(0.0, 0.5, 997)  # between and on the 10 ms samples
    t, q = source.sensor_poses(times)
    t_ref, q_ref = world.player.sensor_poses(times)
    assert t.shape == (997, 3) and q.shape == (997, 4)
    # straight lane at constant speed: linear interpolation is exact (up to float64 rounding of x ~ 100 m)
    np.testing.assert_allclose(t, t_ref, atol=1e-9)
    np.testing.assert_allclose(np.abs(np.einsum("nk,nk->n", q, q_ref)), 1.0, atol=1e-12)
    assert source.actor_poses(0.3).keys() == world.player.actor_poses(0.3).keys() == {100, 101}
    np.testing.assert_array_equal(source.actor_poses(0.3)[100], world.player.actor_poses(0.3)[100])
    assert TfPoseSource(source.buffer, "map", "lidar").actor_poses(0.3) == {}


def test_simulator_casts_the_same_frames_from_tf_as_from_the_player(world):
    source = TfPoseSource(buffer_from_player(world, EPOCH), "map", "lidar", world.player.actor_poses, EPOCH)
    frames = {}
    for name, poses in (("player", world.player), ("tf", source)):
        sim = LidarSimulator(world.profile, world.scene, seed=3, regions=world.regions())
        frames[name] = [f for k in range(31) for f in sim.advance(k * 0.01, poses)]
    # frames start every 40 ms and their sweep ends 16 ms in: frame 7 (0.28 s) is complete at 0.296 s <= 0.30 s
    assert [f.index for f in frames["tf"]] == list(range(8))
    for a, b in zip(frames["player"], frames["tf"]):
        assert a.stamp_s == b.stamp_s and len(a.points) == len(b.points) > 500
        for field in ("x", "y", "z"):
            np.testing.assert_allclose(a.points[field], b.points[field], atol=1e-4)
        for field in ("channel", "time_stamp", "echo", "label", "object_id"):
            np.testing.assert_array_equal(a.points[field], b.points[field])


def test_time_origin_keeps_nanoseconds():
    source = TfPoseSource(TransformBuffer(), "map", "lidar", time_origin_ns=EPOCH + 123)
    assert source.to_stamp_ns(0.04) == EPOCH + 123 + 40_000_000
    np.testing.assert_array_equal(source.to_stamp_ns(np.array([0.0, 1e-9, 2.5])), EPOCH + 123 + np.array([0, 1, 2_500_000_000]))
    assert source.to_time_s(EPOCH + 123 + 7 * S // 100) == pytest.approx(0.07, abs=1e-15)
    assert stamp_ns(stamp(EPOCH + 5)) == EPOCH + 5


def test_ready_stamp_is_the_latest_time_the_whole_chain_is_known():
    buffer = TransformBuffer(extrapolation_tolerance_s=0.0)
    source = TfPoseSource(buffer, "map", "lidar")
    assert source.ready_stamp_ns([S]) is None
    assert "'map' does not exist" in source.why_not_ready(S).detail and source.why_not_ready(S).cause.startswith("UnknownFrameError")
    for k in range(11):  # odom -> base_link at 100 Hz, map -> odom at 20 Hz (lags like a localiser)
        add_tf_message(buffer, NS(transforms=[tf("odom", "base_link", S + k * S // 100, (0.25 * k, 0, 0))]))
    add_tf_message(buffer, NS(transforms=[tf("map", "odom", S), tf("map", "odom", S + S // 20)]))
    assert source.ready_stamp_ns([S + S // 10]) is None  # no mount yet
    set_static_mount(buffer, "base_link", "lidar", mount_transform([3.7, 0, 0.5], [0, 0, 0]))
    assert source.ready_stamp_ns([S + S // 10]) is None  # map -> odom known up to 50 ms only
    assert source.why_not_ready(S + S // 10).cause == "ExtrapolationError map -> lidar"
    assert source.ready_stamp_ns([S + S // 10, S + S // 20, S]) == S + S // 20
    assert source.why_not_ready(S + S // 20) is None
    t, _ = source.sensor_poses(np.array([(S + S // 40) / S]))  # origin 0: absolute seconds
    np.testing.assert_allclose(t, [[0.25 * 2.5 + 3.7, 0.0, 0.5]], atol=1e-6)


def test_bad_transforms_are_skipped_with_a_stable_cause():
    buffer = TransformBuffer()
    msg = NS(transforms=[
        tf("map", "base_link", 1 * S, q=(0.0, 0.0, 0.0, 0.0)),  # zero quaternion
        tf("map", "base_link", 2 * S, t=(math.nan, 0.0, 0.0)),
        tf("map", "base_link", 3 * S, t=(1.0, 0.0, 0.0)),
        tf("base_link", "map", 3 * S),  # loop
        tf("", "x", 3 * S),
    ])  # fmt: skip
    stored, problems = add_tf_message(buffer, msg)
    assert stored == [3 * S]
    assert [p.cause for p in problems] == [
        "map -> base_link: invalid transform",
        "map -> base_link: invalid transform",
        "base_link -> map: 'base_link' -> 'map' would create a loop in the tree",
        " -> x: empty frame name",
    ]
    assert "rotation (x, y, z, w) [0. 0. 0. 0.]" in problems[0].detail and "nan" in problems[1].detail
    np.testing.assert_allclose(buffer.lookup("map", "base_link", 3 * S).translation, [1, 0, 0])
    assert add_tf_message(buffer, NS(foo=1)) == ([], [("not a TFMessage", "not a TFMessage: 'types.SimpleNamespace' object has no attribute 'transforms'")])  # fmt: skip
    stored, problems = add_tf_message(buffer, NS(transforms=[NS(child_frame_id="y")]))
    assert stored == [] and problems[0].cause == "? -> y: AttributeError"


def test_mount_transform_follows_rep103_roll_pitch_yaw():
    m = mount_transform([1.0, 2.0, 3.0], [0.0, 0.0, 90.0])
    np.testing.assert_allclose(m.apply([[1.0, 0.0, 0.0]]), [[1.0, 3.0, 3.0]], atol=1e-12)
    m = mount_transform([0, 0, 0], [0.0, 10.0, 0.0])  # pitch down-positive: x forward tips towards -z
    np.testing.assert_allclose(m.apply([[1.0, 0.0, 0.0]]), [[math.cos(0.1745329), 0, -math.sin(0.1745329)]], atol=1e-6)
    with pytest.raises(ValueError, match="3 values"):
        mount_transform([1.0, 2.0], [0.0, 0.0, 0.0])


def test_odometry_and_parameter_mount_give_the_sensor_pose():
    buffer = TransformBuffer(extrapolation_tolerance_s=0.0)
    set_static_mount(buffer, "base_link", "lidar", mount_transform([3.7, 0.0, 0.5], [0, 0, 0]))
    h = math.radians(90) / 2
    for k in range(3):
        frame, child = ("odom", "base_link") if k == 1 else ("", "")  # empty ids mean the node's frames
        assert add_odometry(buffer, odometry(EPOCH + k * S // 10, (k, 0.0, 0.0), (0, 0, math.sin(h), math.cos(h)), frame, child), "odom", "base_link") == EPOCH + k * S // 10  # fmt: skip
    source = TfPoseSource(buffer, "odom", "lidar", time_origin_ns=EPOCH)
    t, q = source.sensor_poses(np.array([0.05, 0.2]))
    np.testing.assert_allclose(t, [[0.5, 3.7, 0.5], [2.0, 3.7, 0.5]], atol=1e-9)  # mount turned by the yaw
    np.testing.assert_allclose(q, [[0, 0, math.sin(h), math.cos(h)]] * 2, atol=1e-12)
    # /tf_static's edge for the sensor replaces the parameter mount
    add_tf_message(buffer, NS(transforms=[tf("base_link", "lidar", 0, (1.0, 0.0, 2.0))]), static=True)
    np.testing.assert_allclose(source.sensor_poses(np.array([0.2]))[0], [[2.0, 1.0, 2.0]], atol=1e-9)


@pytest.mark.parametrize(
    ("msg", "match"),
    [
        (odometry(S, (0, 0, 0), frame="map"), "odometry frame_id 'map' is not the fixed frame 'odom'"),
        (odometry(S, (0, 0, 0), child="base_footprint"), "child_frame_id 'base_footprint' is not the base frame"),
        (odometry(S, (0, 0, 0), q=(0, 0, 0, 0)), "invalid transform"),
        (odometry(S, (math.inf, 0, 0)), "invalid transform"),
        (NS(header=NS(stamp=stamp(S))), "not a nav_msgs/Odometry"),
    ],
)
def test_malformed_odometry_raises_naming_the_problem(msg, match):
    buffer = TransformBuffer()
    with pytest.raises(ValueError, match=match):
        add_odometry(buffer, msg, "odom", "base_link")
    assert buffer.frames() == set()
