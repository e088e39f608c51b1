"""Clouds through rclpy's own sensor_msgs classes and CDR serialisation."""

import numpy as np
import pytest
from rclpy.serialization import deserialize_message, serialize_message
from sensor_msgs.msg import PointCloud2

from lidar_weather_sim.core.points import empty_points
from lidar_weather_sim.ros.conversions import cloud_to_msg, msg_to_cloud, stamp_to_ns


@pytest.mark.parametrize("ground_truth", [True, False])
def test_every_field_survives_rclpy_serialisation(ground_truth):
    rng = np.random.default_rng(7)
    points = empty_points(5000, ground_truth)
    for name in points.dtype.names:
        dt = points.dtype.fields[name][0]
        points[name] = rng.normal(0, 30, len(points)) if dt.kind == "f" else rng.integers(0, np.iinfo(dt).max, len(points))
    msg, dropped = cloud_to_msg(points, stamp_ns=1_700_000_000_123_456_789, frame_id="lidar")
    assert dropped == 0
    wire = serialize_message(msg)
    back = deserialize_message(wire, PointCloud2)
    assert stamp_to_ns(back.header.stamp) == 1_700_000_000_123_456_789
    assert back.header.frame_id == "lidar"
    assert (back.height, back.width, back.point_step, back.is_dense) == (1, 5000, 44 if ground_truth else 40, True)
    assert [(f.name, f.offset, f.datatype) for f in back.fields][:3] == [("x", 0, 7), ("y", 4, 7), ("z", 8, 7)]
    cloud = msg_to_cloud(back)
    for name in points.dtype.names:
        np.testing.assert_array_equal(cloud.points[name], points[name], err_msg=name)
