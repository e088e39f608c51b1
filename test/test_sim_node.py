"""lidar_sim_node over real DDS (node in its own process), and its SimSession without ROS.

The tf-mode tests run in lockstep: the test is the simulated clock. It publishes
/clock and /tf every 10 ms of simulated time and, after the tick that completes a
sweep, waits for that cloud before publishing the next tick, so no /tf message
can be dropped and no assertion depends on wall-clock speed.

scala4 timing: a frame every 40 ms (25 Hz); the mirror sweeps the field of view
in the first 16 ms (columns fire from 0 to 15.97 ms after the scan start). The
node starts frame 0 at the first /tf stamp t0, so frame i starts at t0 + 40 i ms
and is complete at the tick t0 + 40 i + 20 ms (the first tick after its last
column), i.e. tick k = 4 i + 2.
"""

from __future__ import annotations

import math
import sys
from pathlib import Path

import numpy as np
import pytest
import yaml

from lidar_weather_sim.core.config import ConfigError
from lidar_weather_sim.poses.sources import TfPoseSource, add_tf_message
from lidar_weather_sim.poses.tf_buffer import TransformBuffer
from lidar_weather_sim.scenario.schema import load_scenario
from lidar_weather_sim.scenario.world import World
from lidar_weather_sim.sensor.profile import load_profile, profiles_dir
from lidar_weather_sim.sim.session import RuntimeSettings, SimSession, parse_region_params

S = 1_000_000_000
T0 = 1_700_000_000 * S  # wall-clock-like stamps: nanoseconds must survive (no float64 seconds on the wire)
TICK = 10_000_000  # 100 Hz of simulated time
SPEED = 25.0  # m/s
FIELDS = ["x", "y", "z", "intensity", "return_type", "channel", "azimuth", "elevation", "distance", "time_stamp",
          "echo", "label", "epw", "object_id"]  # fmt: skip
SUN_NOISE = 0.05  # per W/m^2: a sun-sensitive copy of scala4 (its own coefficients are not calibrated yet)


@pytest.fixture(scope="module")
def world():
    return World.build(load_scenario("highway_clear"))


def node_process(processes, **params):
    args = [sys.executable, "-m", "lidar_weather_sim.ros.lidar_sim_node", "--ros-args"]
    for name, value in params.items():
        args += ["-p", f"{name}:={str(value).lower() if isinstance(value, bool) else value}"]
    return processes.start(*args)


def sun_profile(tmp_path: Path) -> Path:
    data = yaml.safe_load((profiles_dir() / "scala4.yaml").read_text())
    data["detection"].update(sun_noise_per_w_m2=SUN_NOISE, sun_sigma_per_w_m2=SUN_NOISE)
    path = tmp_path / "scala4_sun.yaml"
    path.write_text(yaml.safe_dump(data))
    return path


def ego_pose(world, k: int):
    """base_link in map at tick k: the scenario's start pose, then +x at 25 m/s (the highway runs along x)."""
    pos, quat = world.player.base_link_poses(np.array([0.0]))
    return pos[0] + [SPEED * k * TICK / S, 0.0, 0.0], quat[0]


def transform(parent, child, ns, t=(0.0, 0.0, 0.0), q=(0.0, 0.0, 0.0, 1.0)):
    from geometry_msgs.msg import TransformStamped

    msg = TransformStamped()
    msg.header.stamp.sec, msg.header.stamp.nanosec = ns // S, ns % S
    msg.header.frame_id, msg.child_frame_id = parent, child
    tr, rot = msg.transform.translation, msg.transform.rotation
    tr.x, tr.y, tr.z = (float(v) for v in t)
    rot.x, rot.y, rot.z, rot.w = (float(v) for v in q)
    return msg


class Lockstep:
    """The test's side of tf mode: /clock, /tf, /tf_static publishers and the cloud subscription."""

    def __init__(self, ros, world, process, processes):
        from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy, qos_profile_sensor_data
        from rosgraph_msgs.msg import Clock
        from sensor_msgs.msg import PointCloud2
        from tf2_msgs.msg import TFMessage

        self.ros, self.world, self.process, self.processes = ros, world, process, processes
        node = ros.node
        self.clouds = []
        node.create_subscription(PointCloud2, "/lidar/points", self.clouds.append, qos_profile_sensor_data)
        reliable = dict(reliability=ReliabilityPolicy.RELIABLE)
        self.clock = node.create_publisher(Clock, "/clock", QoSProfile(depth=10, **reliable))
        self.tf = node.create_publisher(TFMessage, "/tf", QoSProfile(depth=100, **reliable))
        static = node.create_publisher(
            TFMessage, "/tf_static", QoSProfile(depth=1, durability=DurabilityPolicy.TRANSIENT_LOCAL, **reliable)
        )
        m = world.player.mount
        from lidar_weather_sim.core.geometry import matrix_quaternion

        static.publish(TFMessage(transforms=[transform("base_link", "lidar", T0, m[:3, 3], matrix_quaternion(m[:3, :3]))]))
        self.static = static
        matched = lambda: min(self.tf.get_subscription_count(), static.get_subscription_count()) > 0  # noqa: E731
        assert ros.spin_until(matched, timeout_s=40), processes.output(process)
        ros.spin_until(lambda: False, timeout_s=1.0)  # let the transient-local /tf_static sample arrive first
        self.k = 0

    def publish(self, k: int, extra=()) -> None:
        from builtin_interfaces.msg import Time
        from rosgraph_msgs.msg import Clock
        from tf2_msgs.msg import TFMessage

        ns = T0 + k * TICK
        self.clock.publish(Clock(clock=Time(sec=ns // S, nanosec=ns % S)))
        t, q = ego_pose(self.world, k)
        self.tf.publish(TFMessage(transforms=[transform("map", "base_link", ns, t, q), *extra]))

    def run_until(self, k_end: int, timeout_s: float = 20.0) -> None:
        """Publish ticks self.k .. k_end - 1; after each tick k = 4 i + 2 wait for cloud i."""
        while self.k < k_end:
            self.publish(self.k)
            if self.k % 4 == 2:
                i = self.k // 4
                ok = self.ros.spin_until(lambda: len(self.clouds) > i, timeout_s=timeout_s)
                assert ok, f"no cloud {i} after tick {self.k}\n{self.processes.output(self.process)}"
            self.k += 1

    def set_parameter(self, name, value):
        from rclpy.parameter import Parameter
        from rclpy.parameter_client import AsyncParameterClient

        client = AsyncParameterClient(self.ros.node, "lidar_sim_node")
        assert client.wait_for_services(timeout_sec=20)
        future = client.set_parameters([Parameter(name, value=value)])
        assert self.ros.spin_until(future.done, timeout_s=20)
        return future.result().results[0]


def decode(msg):
    from lidar_weather_sim.ros.conversions import msg_to_cloud, stamp_to_ns

    return stamp_to_ns(msg.header.stamp), msg_to_cloud(msg).points


# -- (a) tf mode with use_sim_time --------------------------------------------------------------
def test_tf_mode_publishes_one_cloud_per_completed_sweep(processes, ros, world):
    proc = node_process(processes, pose_source="tf", use_sim_time=True)
    lock = Lockstep(ros, world, proc, processes)
    # N = 2 s of simulated time at 100 Hz: ticks k = 0..199 (t0 .. t0 + 1.99 s). Frame i is complete at
    # tick 4 i + 2, so frames 0..49 complete (frame 49 at tick 198 = 1.98 s); frame 50 would start at
    # t0 + 2.00 s, outside the interval. Exactly N x 25 Hz = 50 clouds.
    lock.run_until(200)
    ros.spin_until(lambda: False, timeout_s=0.5)  # nothing more may come
    assert len(lock.clouds) == 50
    stamps = []
    for i, msg in enumerate(lock.clouds):
        stamp, points = decode(msg)
        stamps.append(stamp)
        assert msg.header.frame_id == "lidar"
        assert [f.name for f in msg.fields] == FIELDS
        assert len(points) > 500
        assert points["time_stamp"].max() < 16_000_000  # ns after the scan start: the 16 ms sweep
    assert stamps == [T0 + i * 40_000_000 for i in range(50)]  # scan starts, 40 ms apart, exact to the ns
    # actors come from the scenario in every pose mode: the leading vehicle (id 100) is in the clouds
    _, points = decode(lock.clouds[10])
    assert 100 in set(points["object_id"].tolist())
    assert proc.poll() is None


@pytest.mark.slow
def test_tf_mode_actors_and_their_spray_follow_their_tf_frames(processes, ros):
    """actors_from_tf: vehicle 100 on /tf 15 m ahead of base_link in the ego's lane (the scenario has it
    17.5 m ahead in the left lane): its body and the spray its wheels throw are cast there."""
    world = World.build(load_scenario("highway_spray"))
    proc = node_process(processes, scenario="highway_spray", pose_source="tf", use_sim_time=True, actors_from_tf=True,
                        regions="[spray]")  # fmt: skip
    lock = Lockstep(ros, world, proc, processes)
    while lock.k < 160:  # 1.6 s: the spray needs ~0.5 s to fill the wake
        t, q = ego_pose(world, lock.k)
        lead = transform("map", "actor_100", T0 + lock.k * TICK, t + [15.0, 0.0, 0.0], q)
        lock.publish(lock.k, extra=[lead])
        if lock.k % 4 == 2:
            assert ros.spin_until(lambda: len(lock.clouds) > lock.k // 4, timeout_s=20), processes.output(proc)
        lock.k += 1
    from lidar_weather_sim.core.points import Label

    points = np.concatenate([decode(m)[1] for m in lock.clouds[-10:]])
    body = points[(points["label"] == Label.VEHICLE) & (points["object_id"] == 100)]
    spray = points[points["label"] == Label.SPRAY]
    assert len(body) > 50 and abs(np.median(body["y"])) < 1.0 and 8.0 < np.median(body["x"]) < 14.0
    assert len(spray) > 10 and set(np.unique(spray["object_id"])) == {100}
    # both wheel tracks, thrown out beside the car's lane (the scenario's car would put them 1.6-5.6 m left)
    assert np.percentile(np.abs(spray["y"]), 90) < 2.5 and np.median(spray["x"]) < np.median(body["x"]) + 1.0
    assert proc.poll() is None


# -- (b) scenario mode -----------------------------------------------------------------------------
def test_scenario_mode_drives_clock_and_publishes_clouds_and_tf(processes, ros, world):
    from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy, qos_profile_sensor_data
    from rosgraph_msgs.msg import Clock
    from sensor_msgs.msg import PointCloud2
    from geometry_msgs.msg import TwistStamped
    from tf2_msgs.msg import TFMessage

    proc = node_process(processes, pose_source="scenario", time_step_s=0.01, realtime_factor=1.0)
    clocks, clouds, tfs, statics = [], [], [], []
    node = ros.node
    node.create_subscription(Clock, "/clock", clocks.append, QoSProfile(depth=100, reliability=ReliabilityPolicy.BEST_EFFORT))
    node.create_subscription(PointCloud2, "/lidar/points", clouds.append, qos_profile_sensor_data)
    node.create_subscription(TFMessage, "/tf", tfs.append, 100)
    static_qos = QoSProfile(depth=10, durability=DurabilityPolicy.TRANSIENT_LOCAL, reliability=ReliabilityPolicy.RELIABLE)
    node.create_subscription(TFMessage, "/tf_static", statics.append, static_qos)
    assert ros.spin_until(lambda: len(clouds) >= 5 and statics, timeout_s=40), processes.output(proc)

    assert statics[0].transforms[0].header.frame_id == "base_link" and statics[0].transforms[0].child_frame_id == "lidar"
    np.testing.assert_allclose(_xyz(statics[0].transforms[0]), world.player.mount[:3, 3])
    clock_ns = [c.clock.sec * S + c.clock.nanosec for c in clocks]
    assert clock_ns == sorted(clock_ns) and all(ns % TICK == 0 for ns in clock_ns)  # ticks of 10 ms
    stamps = [decode(m)[0] for m in clouds]
    assert all(s % TICK == 0 for s in stamps) and {b - a for a, b in zip(stamps, stamps[1:])} <= {40_000_000 * n for n in range(1, 4)}
    assert all(m.header.frame_id == "lidar" and [f.name for f in m.fields] == FIELDS for m in clouds)
    frames = {ts.child_frame_id: ts for ts in tfs[-1].transforms}
    assert set(frames) == {"base_link", "actor_100", "actor_101"} and frames["base_link"].header.frame_id == "map"
    t = frames["base_link"].header.stamp.sec + frames["base_link"].header.stamp.nanosec * 1e-9
    np.testing.assert_allclose(_xyz(frames["base_link"]), world.player.base_link_poses(np.array([t]))[0][0], atol=1e-6)

    # closed loop: /ego/cmd_speed 0 (unstamped: from now) stops the ego (base_link stops moving on /tf)
    speed = node.create_publisher(TwistStamped, "/ego/cmd_speed", 10)
    assert ros.spin_until(lambda: speed.get_subscription_count() > 0, timeout_s=20)
    speed.publish(TwistStamped())
    ros.spin_until(lambda: False, timeout_s=0.5)
    n = len(tfs)
    assert ros.spin_until(lambda: len(tfs) >= n + 20, timeout_s=20)
    xs = [_xyz(m.transforms[0])[0] for m in tfs[n:]]
    assert max(xs) - min(xs) < 1e-9, "the ego must stand still after /ego/cmd_speed 0"
    assert proc.poll() is None


def _xyz(ts):
    tr = ts.transform.translation
    return np.array([tr.x, tr.y, tr.z])


# -- (c) runtime parameters ------------------------------------------------------------------------
def test_runtime_parameter_sets_are_validated_and_apply_from_the_next_frame(processes, ros, world, tmp_path):
    profile = sun_profile(tmp_path)
    proc = node_process(processes, pose_source="tf", profile=profile, sun_irradiance_w_m2=0.0)
    lock = Lockstep(ros, world, proc, processes)
    lock.run_until(12)  # frames 0..2 complete (ticks 2, 6, 10)
    lock.run_until(14)  # ticks 12 and 13: frame 3 is half cast (its columns up to 10 ms)
    ros.spin_until(lambda: False, timeout_s=0.5)  # let the node take ticks 12 and 13 before the parameter service

    result = lock.set_parameter("regions", ["no_such_region"])
    assert not result.successful and "unknown region 'no_such_region'" in result.reason
    result = lock.set_parameter("regions", ["cover", "cover"])  # would apply the cover twice
    assert not result.successful and "cover listed more than once" in result.reason
    result = lock.set_parameter("region_params", "no_such_plugin: {x: 1}")
    assert not result.successful and "no_such_plugin" in result.reason
    result = lock.set_parameter("region_params", "[1, 2")
    assert not result.successful and "invalid YAML" in result.reason
    result = lock.set_parameter("sun_irradiance_w_m2", 2000.0)  # outside the descriptor's range
    assert not result.successful
    assert lock.set_parameter("regions", []).successful  # an empty list (any array type) clears the regions
    assert lock.set_parameter("sun_irradiance_w_m2", 800.0).successful
    lock.run_until(28)  # frames 3..6

    # reference: the same poses through the library; frame 3 entirely without sun, frames 4.. with it
    reference = {}
    w = World.build(load_scenario("highway_clear"), load_profile(profile))
    buffer = TransformBuffer(extrapolation_tolerance_s=0.0)
    for k in range(28):
        add_tf_message(buffer, _tf_msg(world, k))
    add_tf_message(buffer, _static_msg(world), static=True)
    source = TfPoseSource(buffer, "map", "lidar", w.player.actor_poses, T0)
    for sun in (0.0, 800.0):
        sim = SimSession(w, RuntimeSettings((), {}, sun, 0), backend=None, ground_truth=True)
        reference[sun] = [len(f.points) for k in range(28) for f in sim.advance(source.to_time_s(T0 + k * TICK), source)]
    counts = [len(decode(m)[1]) for m in lock.clouds]
    assert len(counts) == 7
    assert reference[800.0][4] < 0.9 * reference[0.0][4]  # the sun raises the threshold: fewer points
    assert counts == reference[0.0][:4] + reference[800.0][4:], (counts, reference)
    assert proc.poll() is None


def _tf_msg(world, k):
    from tf2_msgs.msg import TFMessage

    t, q = ego_pose(world, k)
    return TFMessage(transforms=[transform("map", "base_link", T0 + k * TICK, t, q)])


def _static_msg(world):
    from tf2_msgs.msg import TFMessage

    from lidar_weather_sim.core.geometry import matrix_quaternion

    m = world.player.mount
    return TFMessage(transforms=[transform("base_link", "lidar", T0, m[:3, 3], matrix_quaternion(m[:3, :3]))])


@pytest.mark.parametrize(
    "module, params, reason",
    [("lidar_weather_sim.ros.lidar_sim_node", ["max_frames:=-5"], "Parameter max_frames out of range"),
     ("lidar_weather_sim.ros.lidar_sim_node", ["sun_irradiance_w_m2:=300"], "of type 'INTEGER', expecting type 'DOUBLE'"),
     ("lidar_weather_sim.ros.lidar_sim_node", ["scenario:=highway_spray", "regions:=[spray,spray]"],
      "spray listed more than once"),
     ("lidar_weather_sim.ros.lidar_sim_node", ["return_mode:=nearest"],
      "return_mode 'nearest' is not one of strongest, last, dual, first, all"),
     ("weather_filter.ros.weather_filter_node", ["method:=foo"], "unknown filter method 'foo'")],
)  # fmt: skip
def test_a_bad_start_parameter_exits_2_with_one_line(module, params, reason):
    """rclpy's range and type checks at declaration used to end in a traceback with status 1."""
    import subprocess

    args = [a for p in params for a in ("-p", p)]
    proc = subprocess.run([sys.executable, "-m", module, "--ros-args", *args], capture_output=True, text=True, timeout=120)
    lines = proc.stderr.strip().splitlines()
    assert proc.returncode == 2 and len(lines) == 1 and reason in lines[0], proc.stderr


# -- (d) malformed input -----------------------------------------------------------------------------
@pytest.mark.slow
def test_malformed_tf_is_logged_once_and_skipped(processes, ros, world):
    proc = node_process(processes, pose_source="tf", use_sim_time=True)
    lock = Lockstep(ros, world, proc, processes)
    lock.run_until(8)
    for k in range(3):  # between ticks: zero quaternion, NaN, a loop
        ns = T0 + (8 + k) * TICK - TICK // 2
        lock.tf.publish(_bad(ns, q=(0.0, 0.0, 0.0, 0.0)))
        lock.tf.publish(_bad(ns, t=(math.nan, 0.0, 0.0)))
        lock.tf.publish(_bad(ns, parent="lidar", child="map"))
    lock.run_until(40)  # frames keep coming: 0..9
    assert len(lock.clouds) == 10
    out = processes.output(proc)
    assert out.count("map -> base_link: invalid transform") == 1, out  # zero quaternion and NaN: one cause
    assert out.count("would create a loop") == 1, out
    assert proc.poll() is None


@pytest.mark.slow
def test_a_silent_region_input_topic_is_logged_once_and_the_clouds_keep_coming(processes):
    """The spray region reads /spray/particles but no spray_node runs: one warning, every cloud published."""
    proc = node_process(processes, scenario="highway_spray", region_params='"spray: {source: topic}"', max_frames=40,
                        realtime_factor=0.0)  # fmt: skip
    assert proc.wait(timeout=120) == 0, processes.output(proc)
    out = processes.output(proc)
    assert "regions read /spray/particles" in out and "published 40 clouds" in out, out
    assert out.count("/spray/particles: nothing received in the 25 clouds since it was subscribed") == 1, out


@pytest.mark.slow
def test_a_topic_no_region_reads_any_more_is_unsubscribed(processes, ros):
    """The spray region reads /spray/particles; after a parameter set to other regions the node drops the
    subscription at the frame boundary where they take over (and never warns that it is silent)."""
    world = World.build(load_scenario("highway_spray"))
    proc = node_process(processes, scenario="highway_spray", pose_source="tf", regions="[spray]",
                        region_params='"spray: {source: topic}"')  # fmt: skip
    lock = Lockstep(ros, world, proc, processes)
    lock.run_until(8)
    assert ros.spin_until(lambda: ros.node.count_subscribers("/spray/particles") == 1, 20.0), processes.output(proc)
    assert lock.set_parameter("regions", ["atmosphere"]).successful
    lock.run_until(160)  # 40 clouds: past the boundary and past the silent-input warning's 25 clouds
    assert ros.spin_until(lambda: ros.node.count_subscribers("/spray/particles") == 0, 20.0), processes.output(proc)
    out = processes.output(proc)
    assert "/spray/particles: no region reads it any more, unsubscribed" in out and "nothing received" not in out, out


@pytest.mark.slow
def test_a_region_input_switched_on_at_runtime_is_given_its_own_25_clouds(processes, ros):
    """The silent-input warning counted every cloud since start-up: right after a switch to a region that reads
    /spray/particles it warned at once. It waits 25 clouds from the subscription."""
    world = World.build(load_scenario("highway_spray"))
    proc = node_process(processes, scenario="highway_spray", pose_source="tf", regions="[atmosphere]")
    lock = Lockstep(ros, world, proc, processes)
    lock.run_until(120)  # 30 clouds
    assert lock.set_parameter("region_params", "spray: {source: topic}").successful
    assert lock.set_parameter("regions", ["spray"]).successful
    lock.run_until(200)  # 20 more clouds with the spray region reading the topic: not yet silent for long
    assert ros.spin_until(lambda: ros.node.count_subscribers("/spray/particles") == 1, 20.0), processes.output(proc)
    assert "nothing received" not in processes.output(proc)
    lock.run_until(240)  # 10 more
    assert ros.spin_until(lambda: "nothing received in the 25 clouds since" in processes.output(proc), 20.0), \
        processes.output(proc)  # fmt: skip


def _bad(ns, t=(0.0, 0.0, 0.0), q=(0.0, 0.0, 0.0, 1.0), parent="map", child="base_link"):
    from tf2_msgs.msg import TFMessage

    return TFMessage(transforms=[transform(parent, child, ns, t, q)])


# -- odometry mode ----------------------------------------------------------------------------------
@pytest.mark.slow
def test_odometry_mode_with_the_parameter_mount(processes, ros, world):
    from nav_msgs.msg import Odometry
    from rclpy.qos import QoSProfile, ReliabilityPolicy, qos_profile_sensor_data
    from sensor_msgs.msg import PointCloud2

    from lidar_weather_sim.poses.sources import add_odometry, mount_transform, set_static_mount

    mount = ([3.7, 0.0, 1.5], [0.0, 2.0, 0.0])  # higher and pitched down: not the scenario's mount
    proc = node_process(processes, pose_source="odometry", fixed_frame="odom", odometry_topic="/ego/odom",
                        mount_xyz_m=mount[0], mount_rpy_deg=mount[1])  # fmt: skip
    clouds = []
    ros.node.create_subscription(PointCloud2, "/lidar/points", clouds.append, qos_profile_sensor_data)
    pub = ros.node.create_publisher(Odometry, "/ego/odom", QoSProfile(depth=50, reliability=ReliabilityPolicy.RELIABLE))
    assert ros.spin_until(lambda: pub.get_subscription_count() > 0, timeout_s=40), processes.output(proc)
    messages = []
    for k in range(22):  # frames 0..4 complete at ticks 2, 6, ..., 18; frame 5 would need tick 22
        msg = Odometry()
        ns = T0 + k * TICK
        msg.header.stamp.sec, msg.header.stamp.nanosec = ns // S, ns % S
        msg.header.frame_id, msg.child_frame_id = "odom", "base_link"
        t, q = ego_pose(world, k)
        pose = msg.pose.pose
        pose.position.x, pose.position.y, pose.position.z = (float(v) for v in t)
        pose.orientation.x, pose.orientation.y, pose.orientation.z, pose.orientation.w = (float(v) for v in q)
        pub.publish(msg)
        messages.append(msg)
        if k % 4 == 2:
            assert ros.spin_until(lambda: len(clouds) > k // 4, timeout_s=20), processes.output(proc)
    ros.spin_until(lambda: False, timeout_s=0.3)
    assert len(clouds) == 5 and all(m.header.frame_id == "lidar" for m in clouds)
    assert [decode(m)[0] for m in clouds] == [T0 + i * 40_000_000 for i in range(5)]
    # the same odometry and mount through the library give the same clouds
    buffer = TransformBuffer(extrapolation_tolerance_s=0.0)
    set_static_mount(buffer, "base_link", "lidar", mount_transform(*mount))
    source = TfPoseSource(buffer, "odom", "lidar", world.player.actor_poses, T0)
    session = SimSession(world, RuntimeSettings((), {}, 0.0, 0), backend=None, ground_truth=True)
    expected = []
    for msg in messages:
        expected += session.advance(source.to_time_s(add_odometry(buffer, msg, "odom", "base_link")), source)
    for msg, frame in zip(clouds, expected):
        points = decode(msg)[1]
        assert len(points) == len(frame.points)
        np.testing.assert_allclose(points["z"], frame.points["z"], atol=1e-5)
    assert proc.poll() is None


# -- in-process (no DDS traffic): a jump back in time restarts the scan ----------------------------------
def test_time_jump_back_restarts_the_scan(ros, world):
    from types import SimpleNamespace

    from rclpy.parameter import Parameter

    from lidar_weather_sim.ros.lidar_sim_node import LidarSimNode

    node = LidarSimNode(context=ros.context, parameter_overrides=[Parameter("pose_source", value="tf")])
    try:
        published = []
        node._points = SimpleNamespace(publish=published.append)
        node._on_tf_static(_static_msg(world))
        for k in range(11):  # frames 0, 1, 2
            node._on_tf(_tf_msg(world, k))
        for k in range(3):  # a bag played again from 5 s earlier: restart, then frames from the new start
            node._on_tf(_tf_msg(world, k - 500))
        for k in range(3, 8):  # up to tick -493: frame 1 of the new scan (start -495) is complete
            node._on_tf(_tf_msg(world, k - 500))
        stamps = [decode(m)[0] for m in published]
        # the jump's first message only restarts; frame 0 of the new scan starts at the second (tick -499)
        assert stamps == [T0, T0 + 40_000_000, T0 + 80_000_000, T0 - 499 * TICK, T0 - 495 * TICK]
    finally:
        node.destroy_node()


@pytest.mark.parametrize("mode, types", [("", None), ("last", {1}), ("strongest", {3})])
def test_the_return_mode_parameter_is_honoured(ros, world, mode, types):
    """'' = the scenario's, else the profile's (scala4: all, up to 3 echoes per beam); a mode reports one point per beam."""
    from types import SimpleNamespace

    from rclpy.parameter import Parameter

    from lidar_weather_sim.ros.lidar_sim_node import LidarSimNode

    overrides = [Parameter("pose_source", value="tf"), Parameter("return_mode", value=mode)]
    node = LidarSimNode(context=ros.context, parameter_overrides=overrides)
    try:
        published = []
        node._points = SimpleNamespace(publish=published.append)
        node._on_tf_static(_static_msg(world))
        for k in range(3):  # frame 0 is complete at tick 2
            node._on_tf(_tf_msg(world, k))
        assert node.session.sim.profile.detection.return_mode == (mode or "all")
        points = decode(published[0])[1]
        beams = np.unique(points[["channel", "time_stamp"]], return_counts=True)[1]
        if types is None:
            assert set(np.unique(points["return_type"]).tolist()) <= {2, 6, 7, 1}  # identical, first, second, last
        else:
            assert set(np.unique(points["return_type"]).tolist()) == types and beams.max() == 1
    finally:
        node.destroy_node()


# -- SimSession (no ROS) ------------------------------------------------------------------------------
@pytest.fixture(scope="module")
def sun_world():
    p = load_profile("scala4")
    p = p.model_copy(update={"detection": p.detection.model_copy(update={"sun_noise_per_w_m2": SUN_NOISE, "sun_sigma_per_w_m2": SUN_NOISE})})
    return World.build(load_scenario("highway_clear"), p)


def _counts(world, times, requests=()):
    """Point counts per frame; ``requests``: {time index: settings} requested before advancing to it."""
    session = SimSession(world, RuntimeSettings((), {}, 0.0, 0), backend=None, ground_truth=True)
    out = []
    for i, t in enumerate(times):
        if i in dict(requests):
            session.request(dict(requests)[i])
        out += [len(f.points) for f in session.advance(t, world.player)]
    return out


def test_session_applies_settings_at_frame_boundaries(sun_world):
    times = np.arange(28) * 0.01
    sunny = RuntimeSettings((), {}, 800.0, 0)
    dark, bright = _counts(sun_world, times), _counts(sun_world, times, {0: sunny})
    assert len(dark) == 7 and all(b < 0.9 * d for b, d in zip(bright, dark))
    # requested at 0.13 s (frame 3 fired 0.12 s): frame 3 stays dark, frame 4 on is sunny
    assert _counts(sun_world, times, {13: sunny}) == dark[:4] + bright[4:]
    # requested at 0.11 s (frame 2 complete at 0.10 s, frame 3 not begun): frame 3 is sunny already
    assert _counts(sun_world, times, {11: sunny}) == dark[:3] + bright[3:]
    # one call spanning several frames still switches at the boundary (same batches as the references:
    # the simulator moves the actors once per batch, so only equal batching gives equal clouds)
    coarse = [0.0, 0.01, 0.27]
    dark, bright = _counts(sun_world, coarse), _counts(sun_world, coarse, {0: sunny})
    assert _counts(sun_world, coarse, {2: sunny}) == dark[:1] + bright[1:]


def test_session_switching_settings_mid_run_gives_the_clouds_of_one_thread(sun_world, monkeypatch):
    """With every batch detected in the background (the threshold of the pipeline lowered to scala4's batches),
    sun, seed and regions requested mid-run take effect at the same frame and give the same bytes as one thread."""
    import lidar_weather_sim.sim.simulator as simulator
    from lidar_weather_sim.core import workers

    monkeypatch.setattr(simulator, "PARALLEL_MIN_RAYS", 100)
    rainy = RuntimeSettings(("atmosphere", "cover"), {"cover": {"texture": "3l"}}, 0.0, 1)
    sunny_other_seed = RuntimeSettings(("atmosphere",), {}, 500.0, 5)

    def clouds(threads: int) -> list[bytes]:
        monkeypatch.setattr(workers, "THREADS", threads)
        session = SimSession(sun_world, rainy, backend=None, ground_truth=True)
        out = []
        for i, t in enumerate(np.arange(1, 30) * 0.01):
            if i == 13:
                session.request(sunny_other_seed)
            out += [f.points.tobytes() for f in session.advance(t, sun_world.player)]
        return out

    one, two = clouds(1), clouds(2)
    assert len(one) == 7 and one == two
    assert one[2] != one[5]  # the switch changed the clouds


def test_session_drops_the_topics_of_replaced_regions(world):
    """A region set reading /spray/particles is replaced at a frame boundary: until then both sets' topics
    are wanted (the new set's data may arrive early), after it only the new set's."""
    topic_spray = RuntimeSettings(("spray",), {"spray": {"source": "topic"}}, 0.0, 0)
    session = SimSession(World.build(load_scenario("highway_spray")), topic_spray, backend=None, ground_truth=True)
    assert session.inputs.topics == ("/spray/particles",)
    session.request(RuntimeSettings(("spray",), {"spray": {"source": "topic", "topic": "/other"}}, 0.0, 0))
    assert session.inputs.topics == ("/spray/particles", "/other")  # requested, not in use yet
    player = session.world.player
    session.advance(0.05, player)
    assert session.inputs.topics == ("/other",)
    session.request(RuntimeSettings((), {}, 0.0, 0))
    session.advance(0.1, player)
    assert session.inputs.topics == ()


def test_session_validation_names_the_problem(world):
    session = SimSession(world, RuntimeSettings((), {}, 0.0, 0), backend=None, ground_truth=True)
    with pytest.raises(ConfigError, match="unknown region 'fogg'"):
        session.build_regions(RuntimeSettings(("fogg",), {}, 0.0, 0))
    with pytest.raises(ConfigError, match="unknown region 'rain_typo'"):
        session.build_regions(RuntimeSettings((), {"rain_typo": {}}, 0.0, 0))
    assert parse_region_params("") == {} and parse_region_params("cover: {dirt: 0.5}\nfog:") == {"cover": {"dirt": 0.5}, "fog": {}}
    for bad, match in (("[1, 2", "invalid YAML"), ("[1, 2]", "must map"), ("cover: 3", "must map")):
        with pytest.raises(ConfigError, match=match):
            parse_region_params(bad)


@pytest.mark.slow
def test_scenario_mode_stops_when_the_ego_reaches_the_end_of_its_road(processes, tmp_path):
    """As `run` does: was, clouds of an empty world published without a word after the ego left the map."""
    from lidar_weather_sim.scenario.schema import load_scenario

    data = load_scenario("highway_clear").model_dump(mode="json")
    data["ego"].update(s_m=990.0, speed_m_s=25.0)  # the 1 km road ends 0.4 s later
    data["actors"] = []
    path = tmp_path / "end.yaml"
    path.write_text(yaml.safe_dump(data))
    proc = node_process(processes, scenario=str(path), realtime_factor=0.0)
    assert proc.wait(timeout=120) == 0, processes.output(proc)
    out = processes.output(proc)
    assert "the ego reached the end of road '1' at 0.40 s" in out and "published 10 clouds" in out, out
