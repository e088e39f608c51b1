"""PointCloud2 between separate processes over real DDS (Fast DDS)."""

import re

import numpy as np
from rclpy.qos import qos_profile_sensor_data
from sensor_msgs.msg import PointCloud2

from lidar_weather_sim.core.points import Label
from lidar_weather_sim.io.synthetic_pattern import synthetic_frame
from lidar_weather_sim.ros.conversions import cloud_to_msg, msg_to_cloud


def test_listener_process_receives_clouds_from_publisher_process(processes, cli):
    processes.start(*cli, "pattern", "--rate", "20", "--topic", "/pubsub/points")
    listener = processes.start(*cli, "listen", "--topic", "/pubsub/points", "--count", "3", "--timeout", "30")
    assert listener.wait(timeout=60) == 0, processes.output(listener)
    lines = [line for line in processes.output(listener).splitlines() if line.startswith("stamp=")]
    assert len(lines) == 3
    assert all("points=11520 " in line and "point_step=44" in line and "frame=lidar" in line for line in lines)
    assert "fields=x,y,z,intensity,return_type,channel,azimuth,elevation,distance,time_stamp,echo,label,epw,object_id" in lines[0]


def test_cloud_from_another_process_decodes_to_the_published_points(processes, cli, ros):
    processes.start(*cli, "pattern", "--rate", "20", "--topic", "/pubsub/exact")
    received = []
    ros.node.create_subscription(PointCloud2, "/pubsub/exact", received.append, qos_profile_sensor_data)
    assert ros.spin_until(lambda: len(received) >= 2, timeout_s=30), "no cloud from the pattern process"
    cloud = msg_to_cloud(received[-1]).points
    expected = synthetic_frame(0)
    for name in ("x", "y", "z", "channel", "azimuth", "distance", "time_stamp", "epw"):
        np.testing.assert_array_equal(cloud[name], expected[name], err_msg=name)
    assert set(np.unique(cloud["label"])) == {Label.STATIC, Label.OBSTACLE}


def test_listener_skips_a_malformed_cloud_and_keeps_running(processes, cli, ros):
    listener = processes.start(*cli, "listen", "--topic", "/pubsub/bad", "--count", "2", "--timeout", "40")
    publisher = ros.node.create_publisher(PointCloud2, "/pubsub/bad", qos_profile_sensor_data)
    assert ros.spin_until(lambda: publisher.get_subscription_count() > 0, timeout_s=30)
    good, _ = cloud_to_msg(synthetic_frame(0), stamp_ns=1, frame_id="lidar")
    bad, _ = cloud_to_msg(synthetic_frame(0), stamp_ns=1, frame_id="lidar")
    bad.fields = [f for f in bad.fields if f.name != "z"]
    truncated, _ = cloud_to_msg(synthetic_frame(0), stamp_ns=1, frame_id="lidar")
    truncated.data = bytes(truncated.data)[:-5]

    def publish_until(messages, done):
        # Best-effort QoS may lose the first messages after discovery: repeat until seen.
        for _ in range(100):
            for msg in messages:
                publisher.publish(msg)
            ros.spin_until(lambda: False, timeout_s=0.1)
            if done():
                return True
        return False

    def both_skipped():
        out = processes.output(listener)
        return "missing field 'z'" in out and "data length" in out

    assert publish_until([bad, truncated], both_skipped), processes.output(listener)
    assert listener.poll() is None, "the listener must keep running after malformed clouds"
    assert publish_until([good], lambda: listener.poll() is not None)
    assert listener.wait(timeout=30) == 0, processes.output(listener)
    out = processes.output(listener)
    assert "skipped malformed cloud: missing field 'z'" in out
    assert re.search(r"skipped malformed cloud: data length \d+ != row_step", out)
    assert len([line for line in out.splitlines() if line.startswith("stamp=")]) == 2


def test_the_large_message_profile_is_set_unless_the_user_chose_one():
    from lidar_weather_sim.ros.dds_profile import PROFILE_VARIABLES, large_message_profile, use_large_message_profile

    env = {"RMW_IMPLEMENTATION": "rmw_fastrtps_cpp"}
    assert use_large_message_profile(env) == large_message_profile() and large_message_profile().is_file()
    assert env[PROFILE_VARIABLES[0]] == str(large_message_profile()) and PROFILE_VARIABLES[1] not in env
    for own in ({"FASTDDS_DEFAULT_PROFILES_FILE": "/mine.xml"}, {"FASTRTPS_DEFAULT_PROFILES_FILE": "/mine.xml"},
                {"FASTDDS_BUILTIN_TRANSPORTS": "UDPv4"}, {"RMW_IMPLEMENTATION": "rmw_cyclonedds_cpp"}):  # fmt: skip
        env = dict(own)
        assert use_large_message_profile(env) is None and env == own


def test_a_dense_cloud_reaches_another_process(processes, cli, ros, tmp_path):
    """An OS1-128 x 2048-sized cloud (6.4 MB) played from a bag arrives: with Fast DDS' default 0.5 MiB
    shared-memory segment none of ~100 such clouds did (UDP fragments dropped), so every node of the
    project starts with config/fastdds_large_messages.xml (lidar_weather_sim.ros.dds_profile)."""
    from lidar_weather_sim.io.bags import BagWriter

    dense = np.zeros(200_000, dtype=[("x", "<f4"), ("y", "<f4"), ("z", "<f4"), ("intensity", "<f4"),
                                       ("distance", "<f4"), ("azimuth", "<f4"), ("elevation", "<f4"), ("epw", "<f4")])  # fmt: skip
    dense["x"] = np.arange(len(dense), dtype=np.float32) * 1e-3
    bag = tmp_path / "dense"
    with BagWriter(bag) as writer:
        for k in range(10):
            writer.write_cloud("/dense/points", dense, stamp_ns=(k + 1) * 100_000_000, frame_id="lidar")
    received = []
    ros.node.create_subscription(PointCloud2, "/dense/points", received.append, qos_profile_sensor_data)
    player = processes.start(*cli, "play", str(bag), "--topics", "/dense/points", "--no-clock", "--wait-for", "/dense/points")
    assert ros.spin_until(lambda: player.poll() is not None and len(received) >= 3, timeout_s=60), (len(received), processes.output(player))
    cloud = msg_to_cloud(received[-1]).points
    assert len(cloud) == len(dense) and len(received[-1].data) == dense.nbytes == 6_400_000
    np.testing.assert_array_equal(cloud["x"], dense["x"])
