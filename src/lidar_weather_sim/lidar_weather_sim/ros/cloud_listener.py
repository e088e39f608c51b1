"""Subscribe to a PointCloud2 topic and summarise each cloud (``lidar-weather-sim listen``).

ros2cli is not installable everywhere; this is the project's ``ros2 topic echo``
/ ``hz`` for clouds. Malformed clouds are reported with their reason and skipped.
"""

from __future__ import annotations

import time
from typing import Callable

import rclpy
from rclpy.executors import ExternalShutdownException
from rclpy.node import Node
from rclpy.qos import qos_profile_sensor_data
from sensor_msgs.msg import PointCloud2

from lidar_weather_sim.io.cloud_codec import CloudFormatError
from lidar_weather_sim.ros.conversions import msg_to_cloud, stamp_to_ns


class CloudListener(Node):
    def __init__(self, topic: str, emit: Callable[[str], None]) -> None:
        super().__init__("cloud_listener")
        self.received = 0
        self.malformed = 0
        self._emit = emit
        self._last_arrival: float | None = None
        self.create_subscription(PointCloud2, topic, self._on_cloud, qos_profile_sensor_data)

    def _on_cloud(self, msg: PointCloud2) -> None:
        arrival = time.monotonic()
        try:
            cloud = msg_to_cloud(msg)
        except CloudFormatError as exc:
            self.malformed += 1
            self._emit(f"skipped malformed cloud: {exc}")
            return
        rate = "" if self._last_arrival is None else f" rate={1.0 / max(arrival - self._last_arrival, 1e-9):.1f}Hz"
        self._last_arrival = arrival
        self.received += 1
        fields = ",".join(cloud.points.dtype.names)
        self._emit(
            f"stamp={stamp_to_ns(msg.header.stamp) / 1e9:.3f}s frame={msg.header.frame_id} "
            f"points={len(cloud.points)} dropped_nonfinite={cloud.dropped_nonfinite} "
            f"point_step={msg.point_step} fields={fields}{rate}"
        )


def listen(topic: str, count: int, timeout_s: float, emit: Callable[[str], None] = print) -> int:
    """Print a line per cloud until ``count`` clouds arrived (0 = forever).

    Returns a process exit code: 0 on success, 1 if fewer than ``count`` clouds
    arrived within ``timeout_s`` seconds.
    """
    try:
        with rclpy.init():
            node = CloudListener(topic, emit)
            deadline = time.monotonic() + timeout_s
            while rclpy.ok() and (count == 0 or node.received < count):
                if timeout_s > 0 and time.monotonic() > deadline:
                    emit(f"timeout: {node.received} of {count} clouds on {topic} within {timeout_s:g} s")
                    return 1
                rclpy.spin_once(node, timeout_sec=0.1)
    except (KeyboardInterrupt, ExternalShutdownException):
        return 130
    return 0
