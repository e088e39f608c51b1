"""launch_testing for launch/closed_loop.launch.py (full ROS 2 install: colcon test / launch_test).

Starts the closed loop without the filter (lidar_sim_node in scenario mode ->
ego_controller_node -> /ego/cmd_speed) and checks: clouds on /lidar/points at
the profile's rate on sim time, one speed command per cloud stamped with that
cloud's stamp (synchronous mode), within the controller's limits. Skipped where launch_testing is not installed (here:
test/test_closed_loop.py runs the same graph through the project's own runner).
"""

import os
import unittest

import pytest

pytest.importorskip("launch_testing", reason="launch_testing is not installed (no full ROS 2 install); "
                    "test/test_closed_loop.py covers the same graph through lidar_weather_sim.ros.graph.run")
pytest.importorskip("launch_ros", reason="launch_ros is not installed (no full ROS 2 install)")

import launch_testing.actions  # noqa: E402
import launch_testing.asserts  # noqa: E402
import rclpy  # noqa: E402
from launch.actions import IncludeLaunchDescription  # noqa: E402
from launch.launch_description_sources import PythonLaunchDescriptionSource  # noqa: E402

import launch  # noqa: E402

LAUNCH = os.path.join(os.path.dirname(__file__), "..", "launch", "closed_loop.launch.py")


@pytest.mark.launch_test
def generate_test_description():
    loop = IncludeLaunchDescription(PythonLaunchDescriptionSource(LAUNCH), launch_arguments={"filter": "false"}.items())
    return launch.LaunchDescription([loop, launch_testing.actions.ReadyToTest()])


class TestClosedLoop(unittest.TestCase):
    @classmethod
    def setUpClass(cls):
        rclpy.init()
        cls.node = rclpy.create_node("launch_test_closed_loop")

    @classmethod
    def tearDownClass(cls):
        cls.node.destroy_node()
        rclpy.shutdown()

    def test_clouds_and_speed_commands(self):
        import time

        from rclpy.qos import qos_profile_sensor_data
        from sensor_msgs.msg import PointCloud2
        from geometry_msgs.msg import TwistStamped

        clouds, commands = [], []
        self.node.create_subscription(PointCloud2, "/lidar/points", clouds.append, qos_profile_sensor_data)
        self.node.create_subscription(TwistStamped, "/ego/cmd_speed", commands.append, 10)
        deadline = time.monotonic() + 90.0
        while (len(clouds) < 25 or len(commands) < 25) and time.monotonic() < deadline:
            rclpy.spin_once(self.node, timeout_sec=0.1)
        self.assertGreaterEqual(len(clouds), 25)
        self.assertGreaterEqual(len(commands), 25)
        stamps = [c.header.stamp.sec * 10**9 + c.header.stamp.nanosec for c in clouds]
        self.assertTrue(all((b - a) % 40_000_000 == 0 and b > a for a, b in zip(stamps, stamps[1:])), stamps)
        self.assertTrue(all(0.0 <= c.twist.linear.x <= 24.72 + 1e-6 for c in commands))  # 0 .. the cruise speed (m/s)
        answered = {c.header.stamp.sec * 10**9 + c.header.stamp.nanosec for c in commands}
        self.assertTrue(set(stamps[5:20]) <= answered)  # synchronous mode: every cloud answered (after discovery)


@launch_testing.post_shutdown_test()
class TestShutdown(unittest.TestCase):
    def test_exit_codes(self, proc_info):
        launch_testing.asserts.assertExitCodes(proc_info, allowable_exit_codes=[0])
