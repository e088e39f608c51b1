"""``lidar-weather-sim run``: a scenario simulated as fast as possible into a rosbag2 (MCAP).

The recording holds what a live run publishes: ``/clock`` and ``/tf``
(map -> base_link and map -> actor_<id>) at every pose step, ``/tf_static``
(base_link -> lidar) once, and the clouds on ``/lidar/points`` stamped with
their scan start. Simulated time starts at 0 s.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Callable

import numpy as np

from lidar_weather_sim.core.geometry import matrix_quaternion
from lidar_weather_sim.core.names import (
    FRAME_BASE_LINK,
    FRAME_LIDAR,
    FRAME_MAP,
    TOPIC_CLOCK,
    TOPIC_POINTS,
    TOPIC_TF,
    TOPIC_TF_STATIC,
    actor_frame,
)
from lidar_weather_sim.io.bags import BagWriter, typestore
from lidar_weather_sim.scenario.player import NoEgoError
from lidar_weather_sim.scenario.schema import Scenario
from lidar_weather_sim.scenario.world import World
from lidar_weather_sim.sim.simulator import Frame, LidarSimulator

POSE_STEP_S = 0.01  # poses advance at 100 Hz of simulated time


@dataclass(frozen=True)
class RunReport:
    output: Path
    frames: int  # frames simulated, the dropped ones included
    points: int
    simulated_s: float
    dropped: int = 0  # frames the postprocess dropped (not in the bag)


class _Messages:
    """rosbags message builders for /tf, /tf_static and /clock."""

    def __init__(self) -> None:
        t = typestore().types
        self.Time = t["builtin_interfaces/msg/Time"]
        self.Header = t["std_msgs/msg/Header"]
        self.Vector3 = t["geometry_msgs/msg/Vector3"]
        self.Quaternion = t["geometry_msgs/msg/Quaternion"]
        self.Transform = t["geometry_msgs/msg/Transform"]
        self.TransformStamped = t["geometry_msgs/msg/TransformStamped"]
        self.TFMessage = t["tf2_msgs/msg/TFMessage"]
        self.Clock = t["rosgraph_msgs/msg/Clock"]

    def time(self, ns: int):
        sec, nanosec = divmod(int(ns), 1_000_000_000)
        return self.Time(sec=sec, nanosec=nanosec)

    def transform(self, ns: int, parent: str, child: str, translation, quaternion):
        x, y, z = (float(v) for v in translation)
        qx, qy, qz, qw = (float(v) for v in quaternion)
        return self.TransformStamped(
            header=self.Header(stamp=self.time(ns), frame_id=parent),
            child_frame_id=child,
            transform=self.Transform(
                translation=self.Vector3(x=x, y=y, z=z), rotation=self.Quaternion(x=qx, y=qy, z=qz, w=qw)
            ),
        )

    def tf(self, transforms):
        return self.TFMessage(transforms=list(transforms))

    def clock(self, ns: int):
        return self.Clock(clock=self.time(ns))


def run_scenario(
    scenario: Scenario,
    output: str | Path,
    *,
    frames: int | None = None,
    seed: int | None = None,
    profile: str | None = None,
    overwrite: bool = False,
    progress: Callable[[int, int], None] | None = None,
    postprocess: Callable[[Frame], np.ndarray | None] | None = None,
) -> RunReport:
    """Simulate ``frames`` frames (default: the scenario's duration) and record them to ``output``.

    ``postprocess(frame)`` may replace a frame's points before they are written, or return
    None to drop the frame (it still counts towards ``frames``). A mesh-only scenario (no ego)
    raises :class:`NoEgoError`: it has no poses to run."""
    if scenario.ego is None:
        raise NoEgoError(
            f"scenario '{scenario.name}' has no ego (mesh-only, no map): it cannot be run; use it with "
            "gap/compare on a recording or the sim node's /tf mode"
        )
    world = World.build(scenario, profile)
    sim = LidarSimulator(
        world.profile,
        world.scene,
        regions=world.regions(),
        seed=scenario.seed if seed is None else seed,
        sun_irradiance_w_m2=scenario.weather.sun.irradiance_w_m2,
    )
    total = frames if frames is not None else max(1, int(round(scenario.duration_s * world.profile.scan.frame_rate_hz)))
    msgs = _Messages()
    player = world.player
    mount_q = matrix_quaternion(player.mount[:3, :3])
    done = points = dropped = 0
    t = 0.0
    with BagWriter(output, overwrite=overwrite) as bag:
        bag.write(TOPIC_TF_STATIC, msgs.tf([msgs.transform(0, FRAME_BASE_LINK, FRAME_LIDAR, player.mount[:3, 3], mount_q)]), 0)
        while done < total:
            ns = int(round(t * 1e9))
            bag.write(TOPIC_CLOCK, msgs.clock(ns), ns)
            translation, quaternion = player.base_link_poses(np.array([t]))
            transforms = [msgs.transform(ns, FRAME_MAP, FRAME_BASE_LINK, translation[0], quaternion[0])]
            for actor_id, pose in player.actor_poses(t).items():
                transforms.append(msgs.transform(ns, FRAME_MAP, actor_frame(actor_id), pose[:3, 3], matrix_quaternion(pose[:3, :3])))
            bag.write(TOPIC_TF, msgs.tf(transforms), ns)
            for frame in sim.advance(t, player):
                if done == total:
                    break
                stamp_ns = int(round(frame.stamp_s * 1e9))
                cloud = frame.points if postprocess is None else postprocess(frame)
                done += 1
                if cloud is not None:
                    bag.write_cloud(TOPIC_POINTS, cloud, stamp_ns, FRAME_LIDAR, log_time_ns=ns)
                    points += len(cloud)
                else:
                    dropped += 1
                if progress:
                    progress(done, total)
            t = round(t + POSE_STEP_S, 9)
    return RunReport(Path(output), done, points, t, dropped)
