"""The tf tree of a scenario run: map -> base_link (the ego), base_link -> lidar (the mount) and
map -> actor_<id> (each actor present), from a :class:`~lidar_weather_sim.scenario.player.ScenarioPlayer`.

The sim node publishes these as rclpy messages, the offline run writes them as rosbags messages;
both only convert them. Frame names default to REP-105 (:mod:`lidar_weather_sim.core.names`).
"""

from __future__ import annotations

import numpy as np

from lidar_weather_sim.core.geometry import FrameTransform, pose_transform
from lidar_weather_sim.core.names import FRAME_BASE_LINK, FRAME_LIDAR, FRAME_MAP, actor_frame
from lidar_weather_sim.scenario.player import ScenarioPlayer


def static_transforms(player: ScenarioPlayer, base_frame: str = FRAME_BASE_LINK,
                      sensor_frame: str = FRAME_LIDAR) -> list[FrameTransform]:  # fmt: skip
    """The /tf_static edge: the sensor on base_link (the scenario's mount)."""
    return [pose_transform(base_frame, sensor_frame, player.mount)]


def moving_transforms(player: ScenarioPlayer, time_s: float, fixed_frame: str = FRAME_MAP,
                      base_frame: str = FRAME_BASE_LINK) -> list[FrameTransform]:  # fmt: skip
    """The /tf edges at simulated time ``time_s`` (s): base_link in the fixed frame, then actor_<id> of
    every actor present, in the scenario's order. Raises NoEgoError for a scenario without an ego."""
    translation, quaternion = player.base_link_poses(np.array([time_s]))
    ego = FrameTransform(fixed_frame, base_frame, tuple(translation[0].tolist()), tuple(quaternion[0].tolist()))
    actors = [pose_transform(fixed_frame, actor_frame(i), pose) for i, pose in player.actor_poses(time_s).items()]
    return [ego, *actors]
