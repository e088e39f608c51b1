"""Actors placed the way the thesis measured them: by the gap from the ego's sensor.

Paper 3 gives the car ahead relative to the ego's LiDAR, "(17.5 +- 0.3) m in x and (3.7 +- 0.1) m
in y" (thesis line 2176), and paper 4 says where on that car: "the middle of the lower side of its
bounding box (considering bird's eye view)" (line 2868), i.e. the middle of its rear. An actor with
``lead_gap_m`` is placed so that this point lies ``lead_gap_m`` ahead of the sensor and
``lead_offset_y_m`` (default 3.7) to its left, both along the ego's axes (REP-103: x forward, y left) at
simulated time 0. The actor drives the lane whose centre is nearest that point; its rear middle then
lies on that lane's centre (3.75 m beside the ego's lane on ``highway_straight.xodr``, within the
thesis' 3.7 +- 0.1 m). The result is an ordinary actor (road, lane, s_m), so everything after this
(the player, ground truth, spray) sees no difference.
"""

from __future__ import annotations

import numpy as np

from lidar_weather_sim.core.config import ConfigError
from lidar_weather_sim.scenario.schema import Actor, Mount, Mover
from lidar_weather_sim.scene.opendrive import RoadNetwork

#: The thesis' lateral offset of the car ahead's rear middle from the sensor (m, left; line 2176).
THESIS_LEAD_OFFSET_Y_M = 3.7

#: Newton steps projecting the rear middle onto a lane centre (converges in 1 on straight roads).
_PROJECTION_STEPS = 6


def _direction(network: RoadNetwork, road: str, lane: int, s_m: float) -> float:
    """+1 if ``lane`` drives towards larger s at ``s_m``, else -1."""
    along = network.lane_pose(road, lane, s_m)[3]
    reference = network.lane_pose(road, lane, s_m, along_reference=True)[3]
    return 1.0 if np.cos(along - reference) > 0 else -1.0


def _xy(network: RoadNetwork, road: str, lane: int, s_m: float) -> tuple[np.ndarray, float]:
    """Lane centre (x, y) in map (m) and the reference line's heading (rad) at ``s_m``."""
    x, y, _, _ = network.lane_pose(road, lane, s_m)
    heading = network.lane_pose(road, lane, s_m, along_reference=True)[3]
    return np.array([float(x), float(y)]), float(heading)


def _nearest_s(network: RoadNetwork, road: str, lane: int, target: np.ndarray, s_m: float) -> float:
    """s (m) of the point of ``lane``'s centre nearest ``target`` (map x, y), starting at ``s_m``."""
    length = network.road_length(road)
    for _ in range(_PROJECTION_STEPS):
        point, heading = _xy(network, road, lane, s_m)
        step = float(np.dot(target - point, [np.cos(heading), np.sin(heading)]))
        s_m = min(max(s_m + step, 0.0), length)
        if abs(step) < 1e-6:
            break
    return s_m


def rear_middle_target(ego: Mover, mount: Mount, network: RoadNetwork, gap_m: float, offset_y_m: float) -> np.ndarray:
    """Map (x, y) of the point ``gap_m`` ahead of and ``offset_y_m`` left of the ego's sensor at time 0 (m)."""
    x, y, _, heading = network.lane_pose(ego.road, ego.lane, ego.s_m)
    forward = np.array([np.cos(heading), np.sin(heading)])
    left = np.array([-forward[1], forward[0]])
    sensor = np.array([float(x), float(y)]) + mount.x_m * forward + mount.y_m * left
    return sensor + gap_m * forward + offset_y_m * left


def place_lead(actor: Actor, ego: Mover, mount: Mount, network: RoadNetwork) -> Actor:
    """``actor`` with ``lane`` and ``s_m`` resolved from its ``lead_gap_m`` / ``lead_offset_y_m``
    (unchanged if it has no ``lead_gap_m``). Raises ConfigError naming the actor if no lane of the
    ego's road has its centre within half a lane width of the rear middle."""
    if actor.lead_gap_m is None:
        return actor
    offset_y = THESIS_LEAD_OFFSET_Y_M if actor.lead_offset_y_m is None else actor.lead_offset_y_m
    where = f"actor {actor.id}: lead_gap_m {actor.lead_gap_m} m, lead_offset_y_m {offset_y} m"
    if actor.road != ego.road:
        raise ConfigError(f"{where}: road '{actor.road}' is not the ego's road '{ego.road}' (the gap is measured on it)")
    target = rear_middle_target(ego, mount, network, actor.lead_gap_m, offset_y)
    guess = ego.s_m + _direction(network, ego.road, ego.lane, ego.s_m) * (mount.x_m + actor.lead_gap_m)
    guess = min(max(guess, 0.0), network.road_length(ego.road))
    best = None
    for lane in network.lane_ids(ego.road):
        try:
            s_m = _nearest_s(network, ego.road, lane, target, guess)
            miss = float(np.linalg.norm(_xy(network, ego.road, lane, s_m)[0] - target))
            width = float(network.lane_width(ego.road, lane, s_m)[()])
        except (KeyError, ValueError):  # the lane ends before the target
            continue
        if best is None or miss < best[0]:
            best = (miss, lane, s_m, width)
    if best is None or best[0] > 0.5 * best[3]:
        detail = "no lane there" if best is None else f"nearest lane {best[1]} centre is {best[0]:.2f} m away"
        raise ConfigError(f"{where}: the rear middle is on no lane of road '{ego.road}' ({detail})")
    _, lane, rear_s, _ = best
    centre_s = rear_s + _direction(network, ego.road, lane, rear_s) * 0.5 * actor.size.length_m
    length = network.road_length(ego.road)
    if not 0.0 <= centre_s <= length:
        raise ConfigError(f"{where}: its centre would be at s = {centre_s:.2f} m, off road '{ego.road}' (0-{length:.1f} m)")
    return actor.model_copy(update={"lane": lane, "s_m": float(centre_s)})
