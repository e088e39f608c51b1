"""Each node, in its own process over DDS, fed malformed PointCloud2 / odometry interleaved with good messages.

The stream comes from :mod:`lidar_weather_sim.testing.malformed` (seeded: random field
tables, truncated and padded data, NaNs, absurd sizes, big-endian, vector x;
NaN poses, zero quaternions, wrong frames, stamps far off, teleports). Every
good message must still give the output the library computes for it, the node
must keep running, and each cause is logged once, not once per message.
Malformed clouds carry their own stamps (good stamp + 1 ns), so outputs are
matched to good inputs by stamp.
"""

from __future__ import annotations

import copy
import csv
import sys

import numpy as np
import pytest
from rclpy.qos import QoSProfile, ReliabilityPolicy, qos_profile_sensor_data
from sensor_msgs.msg import PointCloud2, PointField

from lidar_weather_sim.control.acc import AccConfig, obstacle_distance
from lidar_weather_sim.ros.conversions import cloud_to_msg, msg_to_cloud, stamp_to_ns
from lidar_weather_sim.testing.malformed import malformed_cloud, malformed_odometry
from weather_filter.filter_methods import make_filter
from weather_filter.synthetic import highway_frame

S = 1_000_000_000
GOOD, BAD_PER_GOOD = 12, 6


def _bad_clouds(good, rng, n):
    out = []
    for _ in range(n):
        _, msg = malformed_cloud(good, rng, copy.deepcopy, PointField)
        msg.header.stamp.nanosec = S // 2  # between the good clouds (whole seconds)
        out.append(msg)
    return out


def _feed(ros, pub, good_msgs, rng, received, proc, processes):
    """Publish each good cloud (re-sent until its output arrives: best effort), then a burst of malformed ones."""
    for msg in good_msgs:
        stamp = stamp_to_ns(msg.header.stamp)
        for _ in range(50):
            pub.publish(msg)
            if ros.spin_until(lambda s=stamp: s in received(), timeout_s=0.4):
                break
        assert stamp in received(), f"no output for the good cloud {stamp}\n{processes.output(proc)}"
        assert proc.poll() is None, processes.output(proc)
        for bad in _bad_clouds(msg, rng, BAD_PER_GOOD):
            pub.publish(bad)
    ros.spin_until(lambda: False, timeout_s=0.5)
    assert proc.poll() is None, processes.output(proc)


@pytest.mark.parametrize("method", ["echo", "learned"])
@pytest.mark.slow
def test_weather_filter_node_keeps_filtering_good_clouds(processes, ros, method):
    """Echo: each good cloud's output is the library's. Learned (stateful: its frame-difference feature
    depends on the clouds filtered before, the accepted malformed ones included): every good cloud is
    filtered and the node survives the clouds that crashed it (a negative channel segfaulted it)."""
    proc = processes.start(sys.executable, "-m", "weather_filter.ros.weather_filter_node", "--ros-args", "-p",
                           f"method:={method}")  # fmt: skip
    filtered = {}
    ros.node.create_subscription(PointCloud2, "/lidar/points/filtered",
                                 lambda m: filtered.setdefault(stamp_to_ns(m.header.stamp), m), qos_profile_sensor_data)  # fmt: skip
    pub = ros.node.create_publisher(PointCloud2, "/lidar/points", qos_profile_sensor_data)
    assert ros.spin_until(lambda: pub.get_subscription_count() > 0, timeout_s=30), processes.output(proc)
    clouds = [highway_frame(("rain", "snow", "fog")[k % 3], seed=k) for k in range(GOOD)]
    good = [cloud_to_msg(c, stamp_ns=(k + 1) * S, frame_id="lidar")[0] for k, c in enumerate(clouds)]
    _feed(ros, pub, good, np.random.default_rng(0), lambda: filtered, proc, processes)
    if method == "echo":
        echo = make_filter("echo")
        for k, cloud in enumerate(clouds):
            got = msg_to_cloud(filtered[(k + 1) * S]).points
            np.testing.assert_array_equal(got, cloud[~echo(cloud).remove])
    out = processes.output(proc)
    skips = out.count("skipped malformed cloud")
    assert 0 < skips < GOOD * BAD_PER_GOOD / 2, out  # once per cause, not per message
    assert "Traceback" not in out


@pytest.mark.slow
def test_ego_controller_node_keeps_commanding_on_good_clouds(processes, ros, tmp_path):
    trace = tmp_path / "trace.csv"
    proc = processes.start(sys.executable, "-m", "lidar_weather_sim.ros.ego_controller_node", "--ros-args",
                           "-p", "cloud_topic:=/lidar/points", "-p", f"trace_csv:={trace}")  # fmt: skip
    pub = ros.node.create_publisher(PointCloud2, "/lidar/points", qos_profile_sensor_data)
    assert ros.spin_until(lambda: pub.get_subscription_count() > 0, timeout_s=30), processes.output(proc)
    clouds = [highway_frame("rain", seed=k, obstacle_in_spray=k % 2 == 0) for k in range(GOOD)]
    good = [cloud_to_msg(c, stamp_ns=(k + 1) * S, frame_id="lidar")[0] for k, c in enumerate(clouds)]

    def rows():
        with open(trace) as f:
            return {round(float(r["stamp_s"]) * S): r for r in csv.DictReader(f)}

    _feed(ros, pub, good, np.random.default_rng(1), rows, proc, processes)
    got, cfg = rows(), AccConfig()
    # a row per good cloud; the others only for malformed clouds that decode (NaN points dropped)
    assert {k % S for k in got} == {0, S // 2} and {k for k in got if k % S == 0} == {(k + 1) * S for k in range(GOOD)}
    for k, cloud in enumerate(clouds):
        expected = obstacle_distance(cloud, cfg)
        row = got[(k + 1) * S]["detected_m"]
        assert (row in ("", "nan") and expected is None) or abs(float(row) - expected) < 6e-4, (k, row, expected)
    assert "Traceback" not in processes.output(proc)


@pytest.mark.slow
def test_lidar_sim_node_casts_the_good_odometry_and_skips_the_rest(processes, ros):
    from nav_msgs.msg import Odometry

    from lidar_weather_sim.poses.sources import TfPoseSource, add_odometry, mount_transform, set_static_mount
    from lidar_weather_sim.poses.tf_buffer import TransformBuffer
    from lidar_weather_sim.scenario.schema import load_scenario
    from lidar_weather_sim.scenario.world import World
    from lidar_weather_sim.sim.session import RuntimeSettings, SimSession

    world = World.build(load_scenario("highway_clear"))
    t0, tick = 1_700_000_000 * S, 10_000_000
    args = ["pose_source:=odometry", "fixed_frame:=odom", "mount_xyz_m:=[3.7, 0.0, 0.5]", "mount_rpy_deg:=[0.0, 0.0, 0.0]"]
    proc = processes.start(sys.executable, "-m", "lidar_weather_sim.ros.lidar_sim_node", "--ros-args",
                           *[a for p in args for a in ("-p", p)])  # fmt: skip
    clouds = []
    ros.node.create_subscription(PointCloud2, "/lidar/points", clouds.append, qos_profile_sensor_data)
    pub = ros.node.create_publisher(Odometry, "/odom", QoSProfile(depth=200, reliability=ReliabilityPolicy.RELIABLE))
    assert ros.spin_until(lambda: pub.get_subscription_count() > 0, timeout_s=40), processes.output(proc)
    start, quat = world.player.base_link_poses(np.array([0.0]))
    rng, good = np.random.default_rng(2), []
    for k in range(22):  # frames 0..4 complete at ticks 2, 6, ..., 18
        msg = Odometry()
        ns = t0 + k * tick
        msg.header.stamp.sec, msg.header.stamp.nanosec = ns // S, ns % S
        msg.header.frame_id, msg.child_frame_id = "odom", "base_link"
        p, o = msg.pose.pose.position, msg.pose.pose.orientation
        p.x, p.y, p.z = (float(v) for v in start[0] + [25.0 * k * tick / S, 0.0, 0.0])
        o.x, o.y, o.z, o.w = (float(v) for v in quat[0])
        good.append(msg)
        pub.publish(msg)
        for _ in range(3):
            pub.publish(malformed_odometry(msg, rng, copy.deepcopy)[1])
        if k % 4 == 2:
            assert ros.spin_until(lambda: len(clouds) > k // 4, timeout_s=30), processes.output(proc)
    ros.spin_until(lambda: False, timeout_s=0.3)
    assert len(clouds) == 5 and proc.poll() is None, processes.output(proc)
    buffer = TransformBuffer(extrapolation_tolerance_s=0.0)
    set_static_mount(buffer, "base_link", "lidar", mount_transform([3.7, 0.0, 0.5], [0.0, 0.0, 0.0]))
    source = TfPoseSource(buffer, "odom", "lidar", world.player.actor_poses, t0)
    session = SimSession(world, RuntimeSettings(tuple(world.scenario.regions), {}, 0.0, world.scenario.seed),
                         backend=None, ground_truth=True)  # fmt: skip
    expected = []
    for msg in good:
        expected += session.advance(source.to_time_s(add_odometry(buffer, msg, "odom", "base_link")), source)
    for msg, frame in zip(clouds, expected):
        points = msg_to_cloud(msg).points
        assert len(points) == len(frame.points)
        for axis in "xyz":
            np.testing.assert_allclose(points[axis], frame.points[axis], atol=1e-5)
    out = processes.output(proc)
    assert "restarting the scan" not in out and "Traceback" not in out
    assert out.count("implausible pose") <= 3, out  # stamp jump, speed: logged once per cause
