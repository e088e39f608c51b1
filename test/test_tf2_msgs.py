"""tf2_msgs as used here has the upstream type hash, so real /tf traffic matches."""

import numpy as np
from geometry_msgs.msg import TransformStamped
from rosbags.typesys import Stores, get_typestore
from tf2_msgs.msg import TFMessage

from lidar_weather_sim.core.names import TOPIC_TF
from lidar_weather_sim.poses.tf_buffer import TransformBuffer

PUBLISH_TF = """
import math, sys, time
import rclpy
from geometry_msgs.msg import TransformStamped
from tf2_msgs.msg import TFMessage
rclpy.init()
node = rclpy.create_node("tf_publisher")
pub = node.create_publisher(TFMessage, "/tf", 100)
for i in range(400):
    t = TransformStamped()
    t.header.stamp.sec, t.header.stamp.nanosec = 100 + i // 10, (i % 10) * 100_000_000
    t.header.frame_id, t.child_frame_id = "map", "base_link"
    t.transform.translation.x = 0.1 * i
    yaw = 0.01 * i
    t.transform.rotation.z, t.transform.rotation.w = math.sin(yaw / 2), math.cos(yaw / 2)
    pub.publish(TFMessage(transforms=[t]))
    time.sleep(0.01)
"""


def test_advertised_type_hash_equals_upstream_kilted(ros):
    ros.node.create_publisher(TFMessage, "/hash_probe/tf", 10)
    infos = ros.node.get_publishers_info_by_topic("/hash_probe/tf")
    assert len(infos) == 1
    upstream = get_typestore(Stores.ROS2_KILTED).hash_rihs01("tf2_msgs/msg/TFMessage")
    assert str(infos[0].topic_type_hash) == upstream


def test_tf_from_another_process_feeds_the_transform_buffer(processes, ros):
    import sys

    buffer = TransformBuffer()
    received = []

    def on_tf(msg: TFMessage) -> None:
        received.append(msg)
        buffer.add_tf_message(msg)

    ros.node.create_subscription(TFMessage, TOPIC_TF, on_tf, 100)
    processes.start(sys.executable, "-c", PUBLISH_TF)
    assert ros.spin_until(lambda: len(received) >= 50, timeout_s=30)
    stamps = [m.transforms[0].header.stamp.sec * 10**9 + m.transforms[0].header.stamp.nanosec for m in received]
    # halfway between two consecutive samples i and i+1: x = 0.1 i + 0.05, yaw = 0.01 i + 0.005
    i = (stamps[10] - 100 * 10**9) // 100_000_000
    transform = buffer.lookup("map", "base_link", stamps[10] + 50_000_000)
    np.testing.assert_allclose(transform.translation, [0.1 * i + 0.05, 0.0, 0.0], atol=1e-9)
    yaw = 0.01 * i + 0.005
    expected = np.array([0, 0, np.sin(yaw / 2), np.cos(yaw / 2)])
    # q and -q are the same rotation; the buffer may return either (yaw passes pi if the first messages are missed)
    sign = np.sign(np.dot(transform.rotation, expected))
    np.testing.assert_allclose(sign * np.asarray(transform.rotation), expected, atol=1e-9)
    assert isinstance(received[0].transforms[0], TransformStamped)
