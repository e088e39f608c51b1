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

from lidar_weather_sim.core.names import FRAME_LIDAR, TOPIC_CLOCK, TOPIC_POINTS, TOPIC_TF, TOPIC_TF_STATIC
from lidar_weather_sim.io.bags import BagWriter, clock_message, tf_message
from lidar_weather_sim.scenario.player import NoEgoError, moving_transforms, static_transforms
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
    stopped: str | None = None  # why the run ended before its frames (the ego reached the end of its road)


def run_scenario(
    scenario: Scenario,
    output: str | Path,
    *,
    frames: int | None = None,
    seed: int | None = None,
    profile: str | None = None,
    return_mode: str | None = None,
    overwrite: bool = False,
    progress: Callable[[int, int], None] | None = None,
    postprocess: Callable[[Frame], np.ndarray | None] | None = None,
) -> RunReport:
    """Simulate ``frames`` frames (default: the scenario's duration) and record them to ``output``.

    ``postprocess(frame)`` may replace a frame's points before they are written, or return
    None to drop the frame (it still counts towards ``frames``). ``return_mode`` overrides the scenario's and
    the profile's (:data:`~lidar_weather_sim.core.names.RETURN_MODES`). A mesh-only scenario (no ego)
    without a ``trajectory`` raises :class:`NoEgoError`: it has no poses to run."""
    if scenario.ego is None and not scenario.trajectory:
        raise NoEgoError(
            f"scenario '{scenario.name}' has no ego (mesh-only, no map): it cannot be run; use it with "
            "gap/compare on a recording or the sim node's /tf mode, or give it a 'trajectory'"
        )
    world = World.build(scenario, profile, return_mode)
    sim = LidarSimulator.of_world(world, seed=seed)
    total = frames if frames is not None else max(1, int(round(scenario.duration_s * world.profile.scan.frame_rate_hz)))
    player = world.player
    done = points = dropped = 0
    t = 0.0
    stopped = None
    with BagWriter(output, overwrite=overwrite) as bag:
        bag.write(TOPIC_TF_STATIC, tf_message(0, static_transforms(player)), 0)
        while done < total:
            if player.ego is not None and player.ego.at_road_end(t):
                stopped = (f"the ego reached the end of road {scenario.ego.road!r} at {t:.2f} s (it would leave the "
                           f"map): stopped after {done} of {total} frames")  # fmt: skip
                break
            ns = int(round(t * 1e9))
            bag.write(TOPIC_CLOCK, clock_message(ns), ns)
            bag.write(TOPIC_TF, tf_message(ns, moving_transforms(player, t)), ns)
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
    return RunReport(Path(output), done, points, t, dropped, stopped)
