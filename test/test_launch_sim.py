"""launch_testing for launch/sim.launch.py (full ROS 2 install: colcon test / launch_test).

Starts the sim graph (lidar_sim_node in scenario mode, weather_filter_node) with
ros2 launch and checks: clouds on /lidar/points with every field at the
profile's rate on sim time, filtered clouds on /lidar/points/filtered, and a
region swap by a parameter set taking effect from the next frame. Skipped where
launch_testing is not installed (here: the same graph is covered over DDS by
test/test_graphs.py through `lidar-weather-sim up`, which reads the same description).
"""

import os
import unittest

import pytest

pytest.importorskip("launch_testing", reason="launch_testing is not installed (no full ROS 2 install); "
                    "test/test_graphs.py covers the same graph through `lidar-weather-sim up`")
pytest.importorskip("launch_ros", reason="launch_ros is not installed (no full ROS 2 install)")

import launch_testing.actions  # noqa: E402
import launch_testing.asserts  # noqa: E402
import rclpy  # noqa: E402
from launch.actions import IncludeLaunchDescription  # noqa: E402
from launch.launch_description_sources import PythonLaunchDescriptionSource  # noqa: E402

import launch  # noqa: E402

LAUNCH = os.path.join(os.path.dirname(__file__), "..", "launch", "sim.launch.py")
FIELDS = ["x", "y", "z", "intensity", "return_type", "channel", "azimuth", "elevation", "distance", "time_stamp",
          "echo", "label", "epw", "object_id"]  # fmt: skip


@pytest.mark.launch_test
def generate_test_description():
    sim = IncludeLaunchDescription(
        PythonLaunchDescriptionSource(LAUNCH),
        launch_arguments={"scenario": "highway_spray", "regions": "[spray]", "filter": "true"}.items(),
    )
    return launch.LaunchDescription([sim, launch_testing.actions.ReadyToTest()])


class TestSimGraph(unittest.TestCase):
    @classmethod
    def setUpClass(cls):
        rclpy.init()
        cls.node = rclpy.create_node("launch_test_sim")

    @classmethod
    def tearDownClass(cls):
        cls.node.destroy_node()
        rclpy.shutdown()

    def _collect(self, topic, count, timeout_s=60.0):
        import time

        from rclpy.qos import qos_profile_sensor_data
        from sensor_msgs.msg import PointCloud2

        got = []
        sub = self.node.create_subscription(PointCloud2, topic, got.append, qos_profile_sensor_data)
        deadline = time.monotonic() + timeout_s
        while len(got) < count and time.monotonic() < deadline:
            rclpy.spin_once(self.node, timeout_sec=0.1)
        self.node.destroy_subscription(sub)
        return got

    def test_clouds_fields_and_rate(self):
        clouds = self._collect("/lidar/points", 10)
        self.assertGreaterEqual(len(clouds), 10)
        self.assertEqual([f.name for f in clouds[0].fields], FIELDS)
        stamps = [c.header.stamp.sec * 10**9 + c.header.stamp.nanosec for c in clouds]
        steps = [b - a for a, b in zip(stamps, stamps[1:])]
        self.assertTrue(all(s % 40_000_000 == 0 and s > 0 for s in steps), steps)  # scala4: 25 Hz on sim time

    def test_filter_output(self):
        self.assertGreaterEqual(len(self._collect("/lidar/points/filtered", 3)), 3)

    def test_region_swap_from_the_next_frame(self):
        from rclpy.parameter import Parameter
        from rclpy.parameter_client import AsyncParameterClient

        from lidar_weather_sim.ros.conversions import msg_to_cloud

        client = AsyncParameterClient(self.node, "lidar_sim_node")
        self.assertTrue(client.wait_for_services(timeout_sec=30))
        future = client.set_parameters([Parameter("regions", value=["atmosphere", "spray"])])
        rclpy.spin_until_future_complete(self.node, future, timeout_sec=30)
        self.assertTrue(future.result().results[0].successful)
        clouds = self._collect("/lidar/points", 3)[1:]  # the frame in progress may be the old one
        self.assertTrue(all((msg_to_cloud(c).points["label"] == 11).sum() > 0 for c in clouds))


@launch_testing.post_shutdown_test()
class TestShutdown(unittest.TestCase):
    def test_exit_codes(self, proc_info):
        launch_testing.asserts.assertExitCodes(proc_info, allowable_exit_codes=[0])
