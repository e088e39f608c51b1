"""``pattern_node``: publishes the synthetic wiring-check sweep on /lidar/points.

Parameters: ``rate_hz`` (double, Hz), ``frame_id`` (string), ``ground_truth``
(bool: include ``label``/``object_id``), ``max_frames`` (int, 0 = forever).
Topic ``/lidar/points`` (remap it), SensorDataQoS. Honours ``use_sim_time``.
"""

from __future__ import annotations

import rclpy
from rcl_interfaces.msg import FloatingPointRange, IntegerRange, ParameterDescriptor
from rclpy.node import Node
from rclpy.qos import qos_profile_sensor_data
from sensor_msgs.msg import PointCloud2

from lidar_weather_sim.core.names import FRAME_LIDAR, TOPIC_POINTS
from lidar_weather_sim.io.synthetic_pattern import synthetic_frame
from lidar_weather_sim.ros.conversions import cloud_to_msg
from lidar_weather_sim.ros.node_main import POLL_S, run_node, stop_requested


class PatternNode(Node):
    def __init__(self) -> None:
        super().__init__("pattern_node")
        self.declare_parameter(
            "rate_hz",
            10.0,
            ParameterDescriptor(
                description="Frames per second (Hz)",
                floating_point_range=[FloatingPointRange(from_value=0.1, to_value=100.0)],
            ),
        )
        self.declare_parameter("frame_id", FRAME_LIDAR, ParameterDescriptor(description="Sensor frame"))
        self.declare_parameter(
            "ground_truth", True, ParameterDescriptor(description="Publish label and object_id fields")
        )
        self.declare_parameter(
            "max_frames",
            0,
            ParameterDescriptor(
                description="Stop after this many frames (0 = forever)",
                integer_range=[IntegerRange(from_value=0, to_value=2**31 - 1, step=1)],
            ),
        )
        self._frame = 0
        self._publisher = self.create_publisher(PointCloud2, TOPIC_POINTS, qos_profile_sensor_data)
        period_s = 1.0 / self.get_parameter("rate_hz").value
        self._timer = self.create_timer(period_s, self._publish)
        self.get_logger().info(f"publishing a synthetic sweep on {self._publisher.topic_name} every {period_s:.3f} s")

    @property
    def finished(self) -> bool:
        limit = self.get_parameter("max_frames").value
        return 0 < limit <= self._frame

    def _publish(self) -> None:
        if self.finished:
            return
        points = synthetic_frame(self._frame, ground_truth=self.get_parameter("ground_truth").value)
        stamp_ns = self.get_clock().now().nanoseconds
        msg, _ = cloud_to_msg(points, stamp_ns, self.get_parameter("frame_id").value)
        self._publisher.publish(msg)
        self._frame += 1


def _spin(node: PatternNode) -> None:
    while not stop_requested() and not node.finished:
        rclpy.spin_once(node, timeout_sec=POLL_S)


def main(args: list[str] | None = None) -> None:
    run_node("pattern_node", PatternNode, _spin, args=args)


if __name__ == "__main__":
    main()
