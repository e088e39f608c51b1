"""rosbags messages of the ``/tf``, ``/tf_static`` and ``/clock`` topics, for :class:`~lidar_weather_sim.io.bags.BagWriter`.

Transforms are :class:`~lidar_weather_sim.core.geometry.FrameTransform` (parent, child, translation
x, y, z in m, unit quaternion x, y, z, w). Stamps are integer nanoseconds.
"""

from __future__ import annotations

from typing import Iterable

from lidar_weather_sim.core.geometry import FrameTransform
from lidar_weather_sim.io.bags import typestore


def time_message(ns: int):
    """builtin_interfaces/Time of ``ns`` nanoseconds."""
    sec, nanosec = divmod(int(ns), 1_000_000_000)
    return typestore().types["builtin_interfaces/msg/Time"](sec=sec, nanosec=nanosec)


def tf_message(ns: int, transforms: Iterable[FrameTransform]):
    """tf2_msgs/TFMessage of ``transforms``, each stamped ``ns``."""
    t = typestore().types
    stamped = []
    for parent, child, translation, quaternion in transforms:
        x, y, z = (float(v) for v in translation)
        qx, qy, qz, qw = (float(v) for v in quaternion)
        transform = t["geometry_msgs/msg/Transform"](translation=t["geometry_msgs/msg/Vector3"](x=x, y=y, z=z),
                                                    rotation=t["geometry_msgs/msg/Quaternion"](x=qx, y=qy, z=qz, w=qw))  # fmt: skip
        header = t["std_msgs/msg/Header"](stamp=time_message(ns), frame_id=parent)
        stamped.append(t["geometry_msgs/msg/TransformStamped"](header=header, child_frame_id=child, transform=transform))
    return t["tf2_msgs/msg/TFMessage"](transforms=stamped)


def clock_message(ns: int):
    """rosgraph_msgs/Clock at ``ns`` nanoseconds."""
    return typestore().types["rosgraph_msgs/msg/Clock"](clock=time_message(ns))
