"""Small synthetic bags for tests: given clouds on ``/lidar/points`` (frame ``lidar``) and, optionally,
``/tf`` with the sensor and actors in ``map`` (no ROS)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from lidar_weather_sim.core.geometry import FrameTransform, yaw_quaternions
from lidar_weather_sim.core.names import FRAME_LIDAR, FRAME_MAP, TOPIC_POINTS, TOPIC_TF, actor_frame
from lidar_weather_sim.core.points import empty_points, fill_polar
from lidar_weather_sim.io.bags import BagWriter, tf_message


def points_at(xyz, **fields) -> np.ndarray:
    """Points (project layout, ground truth) at ``xyz`` ((N, 3) m, sensor frame) with polar fields
    filled and the given fields set (scalars or arrays), e.g. ``label=2, channel=[0, 1]``."""
    xyz = np.asarray(xyz, float).reshape(-1, 3)
    points = empty_points(len(xyz))
    points["x"], points["y"], points["z"] = xyz.T
    fill_polar(points)
    points["echo"] = 1
    for name, value in fields.items():
        points[name] = value
    return points


def write_cloud_bag(path: str | Path, clouds: list[np.ndarray], period_ns: int = 100_000_000,
                    actors: dict[int, tuple[float, float, float]] | None = None, topic: str = TOPIC_POINTS) -> Path:  # fmt: skip
    """A bag of ``clouds`` stamped ``k * period_ns``; with ``actors`` (id -> x, y (m), yaw (rad) in map)
    also ``/tf``: map -> lidar at the origin and map -> actor_<id> standing still, every frame."""
    with BagWriter(path) as bag:
        for k, cloud in enumerate(clouds):
            ns = k * period_ns
            if actors is not None:
                moving = [FrameTransform(FRAME_MAP, FRAME_LIDAR, (0.0, 0.0, 0.0), (0.0, 0.0, 0.0, 1.0))]
                for actor_id, (x, y, yaw) in actors.items():
                    q = tuple(yaw_quaternions(np.array([yaw]))[0].tolist())
                    moving.append(FrameTransform(FRAME_MAP, actor_frame(actor_id), (x, y, 0.0), q))
                bag.write(TOPIC_TF, tf_message(ns, moving), ns)
            bag.write_cloud(topic, cloud, ns, FRAME_LIDAR, log_time_ns=ns)
    return Path(path)
