"""PointCloud2 and time conversion for rclpy's message classes."""

from __future__ import annotations

import importlib
from functools import lru_cache

import numpy as np

from lidar_weather_sim.io.cloud_codec import DecodedCloud, MessageTypes, NanPolicy, build_message, decode_message


def message_class(msgtype: str):
    """rclpy message class of ``pkg/msg/Name``."""
    package, _, name = msgtype.split("/")
    return getattr(importlib.import_module(f"{package}.msg"), name)


@lru_cache(maxsize=1)
def rclpy_message_types() -> MessageTypes:
    """Message classes of rclpy's sensor_msgs (``uint8[]`` accepts bytes directly)."""
    from builtin_interfaces.msg import Time
    from sensor_msgs.msg import PointCloud2, PointField
    from std_msgs.msg import Header

    return MessageTypes(PointCloud2=PointCloud2, PointField=PointField, Header=Header, Time=Time, data=bytes)


def cloud_to_msg(points: np.ndarray, stamp_ns: int, frame_id: str, drop_nonfinite: bool = True):
    """sensor_msgs/PointCloud2 of ``points``; returns (message, number of non-finite points dropped)."""
    return build_message(
        points, stamp_ns=stamp_ns, frame_id=frame_id, types=rclpy_message_types(), drop_nonfinite=drop_nonfinite
    )


def msg_to_cloud(msg, nan_policy: NanPolicy = "drop") -> DecodedCloud:
    """Decode a sensor_msgs/PointCloud2; raises CloudFormatError naming the problem."""
    return decode_message(msg, nan_policy=nan_policy)


def stamp_to_ns(stamp) -> int:
    """builtin_interfaces/Time -> integer nanoseconds."""
    return int(stamp.sec) * 1_000_000_000 + int(stamp.nanosec)
