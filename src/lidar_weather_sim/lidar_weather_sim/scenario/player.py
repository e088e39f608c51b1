"""Scenario player: poses of the ego, its sensor and the actors over simulated time.

Movers follow OpenDRIVE lane centres at their speed; a lane change blends the
lateral position between the two lane centres with a smoothstep over its
duration. base_link is the ego's origin on the road surface (REP-105), the
sensor is mounted on it with the scenario's mount pose. All poses are in the
map frame: translations in m, quaternions x, y, z, w. The ego speed can be
commanded at run time (closed loop); actors keep their scenario speed.
A mesh-only scenario has no ego: its player has no ego poses
(:class:`NoEgoError`); sensor poses then come from a recording or /tf, or from the
scenario's ``trajectory`` (:class:`TrajectoryTrack`) when it has one. Actors with a ``trajectory``
(those of a mesh-only scenario) follow it instead of a lane.

Actors placed the way the thesis measured them (``lead_gap_m``) get their lane and s here, before any
track is built (:func:`place_lead`); :func:`static_transforms` and :func:`moving_transforms` give the
player's tf tree, which the sim node publishes and the offline run records.
"""

from __future__ import annotations

import numba
import numpy as np

from lidar_weather_sim.core.config import ConfigError
from lidar_weather_sim.core.geometry import (
    FrameTransform,
    matrix_quaternion,
    pose_transform,
    quaternion_matrices,
    quaternion_multiply,
    quaternion_rotate,
    rpy_matrix,
    yaw_quaternions,
)
from lidar_weather_sim.core.names import FRAME_BASE_LINK, FRAME_LIDAR, FRAME_MAP, actor_frame
from lidar_weather_sim.scenario.schema import Actor, Mount, Mover, Scenario
from lidar_weather_sim.scene.opendrive import RoadNetwork


def mount_matrix(mount: Mount) -> np.ndarray:
    """4x4 sensor-to-base_link transform of a mount."""
    m = np.eye(4)
    m[:3, :3] = rpy_matrix(*np.deg2rad([mount.roll_deg, mount.pitch_deg, mount.yaw_deg]))
    m[:3, 3] = [mount.x_m, mount.y_m, mount.z_m]
    return m


# Lead placement: actors placed the way the thesis measured them: by the gap from the ego's sensor.
#
# Paper 3 gives the car ahead relative to the ego's LiDAR, "(17.5 +- 0.3) m in x and (3.7 +- 0.1) m
# in y" (thesis line 2176), and paper 4 says where on that car: "the middle of the lower side of its
# bounding box (considering bird's eye view)" (line 2868), i.e. the middle of its rear. An actor with
# ``lead_gap_m`` is placed so that this point lies ``lead_gap_m`` ahead of the sensor and
# ``lead_offset_y_m`` (default 3.7) to its left, both along the ego's axes (REP-103: x forward, y left) at
# simulated time 0. The actor drives the lane whose centre is nearest that point; its rear middle then
# lies on that lane's centre (3.75 m beside the ego's lane on ``highway_straight.xodr``, within the
# thesis' 3.7 +- 0.1 m). The result is an ordinary actor (road, lane, s_m), so everything after this
# (the player, ground truth, spray) sees no difference.

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


class MoverTrack:
    """Position of one mover along its road over time (s in m, t in s)."""

    def __init__(self, mover: Mover, network: RoadNetwork) -> None:
        """Raises ConfigError naming the key when the road, the start lane or a lane change's target lane
        is not on the map where the mover is (lanes are resolved here, before anything runs)."""
        self.mover = mover
        self.network = network
        who = f"actor {mover.id}" if hasattr(mover, "id") else "ego"
        try:
            self.length = network.road_length(mover.road)
            # lanes driven against the reference line (left lanes in right-hand traffic) move to smaller s
            along = network.lane_pose(mover.road, mover.lane, mover.s_m)[3]
            reference = network.lane_pose(mover.road, mover.lane, mover.s_m, along_reference=True)[3]
        except KeyError as err:
            raise ConfigError(f"{who}: road {mover.road!r}, lane {mover.lane}: {err.args[0]}") from None
        self.direction = 1.0 if np.cos(along - reference) > 0 else -1.0
        for i, change in enumerate(mover.lane_changes):  # where the change starts and ends at the scenario speed
            times = np.array([change.at_s, change.at_s + change.duration_s])
            s = np.clip(mover.s_m + self.direction * mover.speed_m_s * times, 0.0, self.length)
            try:
                network.lane_pose(mover.road, change.to_lane, s)
            except KeyError as err:
                raise ConfigError(f"{who}: key 'lane_changes.{i}.to_lane': value {change.to_lane}: {err.args[0]}") from None
        # speed segments (start time s, start position m, speed m/s); commands append segments
        self._segments = [(0.0, mover.s_m, mover.speed_m_s)]
        self._table: np.ndarray | None = None  # the segments as an array, rebuilt after a command

    def command_speed(self, time_s: float, speed_m_s: float) -> None:
        """From ``time_s`` on, move at ``speed_m_s`` (m/s)."""
        t0, s0, v0 = self._segments[-1]
        if time_s < t0:
            raise ValueError(f"speed command at {time_s:.3f} s is older than the last one ({t0:.3f} s)")
        self._segments.append((time_s, s0 + self.direction * v0 * (time_s - t0), max(0.0, speed_m_s)))
        self._table = None

    def _segment_at(self, times: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        table = self._table
        if table is None:
            table = self._table = np.array(self._segments)
        k = np.clip(np.searchsorted(table[:, 0], times, side="right") - 1, 0, None)
        return table[k, 0], table[k, 1], table[k, 2]

    def s(self, times: np.ndarray) -> np.ndarray:
        """Position along the road (m) at ``times`` (s); stops at the road's end."""
        if len(self._segments) == 1:  # never commanded: the segment's scalars, the same values
            t0, s0, v = self._segments[0]
        else:
            t0, s0, v = self._segment_at(times)
        return np.minimum(np.maximum(s0 + self.direction * v * (times - t0), 0.0), self.length)

    def at_road_end(self, time_s: float) -> bool:
        """Moving, and stopped by the end of its road at ``time_s`` (s): it would leave the map."""
        t = np.array([float(time_s)])
        speed, s = float(self.speeds(t)[0]), float(self.s(t)[0])
        return speed > 0 and (s >= self.length if self.direction > 0 else s <= 0.0)

    def speeds(self, times: np.ndarray) -> np.ndarray:
        """Speed (m/s) at ``times`` (s)."""
        return self._segment_at(times)[2]

    def poses(self, times: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Positions (N, 3) m and headings (N,) rad in the map frame at ``times`` (s)."""
        times = np.atleast_1d(np.asarray(times, dtype=np.float64))
        s = self.s(times)
        road = self.mover.road
        x, y, z, heading = self.network.lane_pose(road, self.mover.lane, s)
        pos = np.stack([x, y, z], axis=-1)
        for change in self.mover.lane_changes:
            u = np.clip((times - change.at_s) / change.duration_s, 0.0, 1.0)
            if not np.any(u > 0):
                continue
            w = u * u * (3.0 - 2.0 * u)
            tx, ty, tz, _ = self.network.lane_pose(road, change.to_lane, s)
            target = np.stack([tx, ty, tz], axis=-1)
            lateral = target - pos
            pos = pos + w[:, None] * lateral
            # heading turns towards the target lane while the lateral speed is non-zero
            dw_dt = 6.0 * u * (1.0 - u) / change.duration_s
            speed = self.speeds(times)
            left = np.stack([-np.sin(heading), np.cos(heading)], axis=-1)
            lateral_speed = dw_dt * np.einsum("nk,nk->n", lateral[:, :2], left)
            heading = heading + np.arctan2(lateral_speed, np.maximum(speed, 1e-3))
        return pos, heading


class TrajectoryTrack:
    """base_link poses in the map frame from a scenario's ``trajectory``: translation interpolated linearly,
    rotation by slerp between the neighbouring poses, held before the first and after the last (s, m)."""

    def __init__(self, poses) -> None:
        from scipy.spatial.transform import Rotation, Slerp

        self.times = np.array([p.t_s for p in poses], dtype=np.float64)
        self.translation = np.array([[p.x_m, p.y_m, p.z_m] for p in poses], dtype=np.float64)
        q = np.array([[p.qx, p.qy, p.qz, p.qw] for p in poses], dtype=np.float64)
        self._rotations = Rotation.from_quat(q / np.linalg.norm(q, axis=1, keepdims=True))
        self._slerp = Slerp(self.times, self._rotations) if len(self.times) > 1 else None

    def poses(self, times_s) -> tuple[np.ndarray, np.ndarray]:
        """base_link in map at ``times_s`` (s): translations (N, 3) m, quaternions (N, 4) x, y, z, w."""
        t = np.clip(np.atleast_1d(np.asarray(times_s, dtype=np.float64)), self.times[0], self.times[-1])
        if self._slerp is None:
            return np.tile(self.translation[0], (len(t), 1)), np.tile(self._rotations.as_quat(), (len(t), 1))
        xyz = np.stack([np.interp(t, self.times, self.translation[:, k]) for k in range(3)], axis=-1)
        return xyz, self._slerp(t).as_quat()


def appear_time(actor) -> float:
    """Simulated time (s) from which ``actor`` is present: its ``appear_s``; for an actor with a trajectory that
    does not set it, the trajectory's first time (which may be before 0)."""
    if actor.trajectory and "appear_s" not in actor.model_fields_set:
        return actor.trajectory[0].t_s
    return actor.appear_s


class NoEgoError(ValueError):
    """Ego or sensor poses asked of a scenario without an ego (a mesh-only scenario)."""


class ScenarioPlayer:
    """Implements the simulator's PoseSource for a scenario."""

    def __init__(self, scenario: Scenario, network: RoadNetwork) -> None:
        self.scenario = scenario
        self.network = network
        self.ego = None if scenario.ego is None else MoverTrack(scenario.ego, network)
        self.trajectory = TrajectoryTrack(scenario.trajectory) if scenario.trajectory else None
        actors = [a for a in scenario.actors if not a.trajectory]
        if self.ego is not None:  # actors placed by their gap to the sensor get their lane and s_m
            actors = [place_lead(a, scenario.ego, scenario.sensor.mount, network) for a in actors]
        self.actors = {a.id: (a, MoverTrack(a, network)) for a in actors}
        self.trajectory_actors = {a.id: (a, TrajectoryTrack(a.trajectory)) for a in scenario.actors if a.trajectory}
        tracks = [t for _, t in self.actors.values()]
        # per actor (scenario order): appearance time, first speed segment, direction, road length, road, lane
        self._appear = np.array([a.appear_s for a, _ in self.actors.values()]).reshape(-1, 1)
        self._first = np.array([(*t._segments[0], t.direction, t.length) for t in tracks]).reshape(-1, 5).T
        # the actors' roads (first appearance order), each actor's index into them, its lane
        self._roads = list(dict.fromkeys(t.mover.road for t in tracks))
        self._road_lane = (np.array([self._roads.index(t.mover.road) for t in tracks], int),
                           np.array([t.mover.lane for t in tracks], int))  # fmt: skip
        self.mount = mount_matrix(scenario.sensor.mount)
        self._mount_quaternion = matrix_quaternion(self.mount[:3, :3])

    def base_link_poses(self, times_s: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """base_link in map: translations (N, 3) m, quaternions (N, 4)."""
        if self.trajectory is not None:
            return self.trajectory.poses(times_s)
        pos, heading = self._ego().poses(times_s)
        return pos, yaw_quaternions(heading)

    def sensor_poses(self, times_s: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Sensor frame in map at each time (rolling shutter: one pose per firing time)."""
        if self.trajectory is not None:  # base_link pose then the mount: T_map_sensor = T_map_base T_base_sensor
            translation, q = self.trajectory.poses(times_s)
            return (translation + quaternion_rotate(q, np.broadcast_to(self.mount[:3, 3], translation.shape)),
                    quaternion_multiply(q, np.broadcast_to(self._mount_quaternion, q.shape)))  # fmt: skip
        return self._sensor(*self._ego().poses(times_s))

    def _sensor(self, pos: np.ndarray, heading: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Sensor translations (N, 3) m and quaternions (N, 4) at base_link positions (N, 3) m and headings (rad)."""
        half = 0.5 * heading
        translation, q = np.empty_like(pos), np.empty((len(half), 4))
        _mount(pos, np.cos(heading), np.sin(heading), np.sin(half), np.cos(half), self.mount[:3, 3],
               self._mount_quaternion, translation, q)  # fmt: skip
        return translation, q

    def poses_at(self, sensor_times_s, actor_times_s) -> tuple[np.ndarray, np.ndarray, list[dict[int, np.ndarray]]]:
        """``sensor_poses(sensor_times_s)`` and ``actor_poses_at(actor_times_s)`` at once: an ego that
        keeps its lane and speed joins the actors' lane-pose call on its road (the same values)."""
        if self.trajectory is not None:
            return (*self.sensor_poses(sensor_times_s), self.actor_poses_at(actor_times_s))
        ego = self._ego()
        if ego.mover.lane_changes or len(ego._segments) > 1:
            return (*self.sensor_poses(sensor_times_s), self.actor_poses_at(actor_times_s))
        times = np.atleast_1d(np.asarray(sensor_times_s, dtype=np.float64))
        actors, (x, y, z, heading) = self._actor_poses(actor_times_s, (ego.mover.road, ego.mover.lane, ego.s(times)))
        return (*self._sensor(np.stack([x, y, z], axis=-1), heading), actors)

    def _ego(self) -> MoverTrack:
        if self.ego is None:
            raise NoEgoError(
                f"scenario '{self.scenario.name}' has no ego (mesh-only, no map): its sensor poses must come "
                "from a recording (gap, compare) or from /tf, not from the scenario"
            )
        return self.ego

    def actor_poses(self, time_s: float) -> dict[int, np.ndarray]:
        """Body-to-map 4x4 of every actor present at ``time_s``."""
        return self.actor_poses_at([time_s])[0]

    def actor_poses_at(self, times_s) -> list[dict[int, np.ndarray]]:
        """``actor_poses`` at each of ``times_s``, evaluated together: the positions along the
        road of all actors that keep their lane and speed at once, then one lane-pose call per
        road (the same values, elementwise); actors changing lanes follow their track, actors with a
        trajectory theirs."""
        return self._actor_poses(times_s)[0]

    def _actor_poses(self, times_s, ego: tuple | None = None) -> tuple[list[dict[int, np.ndarray]], tuple | None]:
        """``actor_poses_at(times_s)``; with ``ego`` (road, lane, positions s (N,) m) also the lane
        pose (x, y, z, heading) at those s, from the lane-pose call of the actors on that road."""
        times = np.atleast_1d(np.asarray(times_s, dtype=np.float64))
        actors = list(self.actors.values())
        present = times[None, :] >= self._appear
        who, when = np.nonzero(present)  # (actor, time) pairs, actor-major like the dicts' order
        pos, heading = np.empty((len(who), 3)), np.empty(len(who))
        k = np.arange(len(who))  # the pairs of the actors that keep their lane and speed
        steady = [not a.lane_changes and len(t._segments) == 1 for a, t in actors]
        if not all(steady):
            changing = ~np.array(steady)[who]
            for i in np.unique(who[changing]):
                m = np.flatnonzero(who == i)
                pos[m], heading[m] = actors[i][1].poses(times[when[m]])
            k = k[~changing]
        i = who[k]  # MoverTrack.s of each with its segment's scalars, the same expression
        t0, s0, v, direction, length = self._first[:, i]
        s = np.minimum(np.maximum(s0 + direction * v * (times[when[k]] - t0), 0.0), length)
        roads, lanes = self._road_lane[0][i], self._road_lane[1][i]
        ego_pose = None
        ego_road = [] if ego is None or ego[0] in self._roads else [ego[0]]
        for r, road in enumerate(self._roads + ego_road):
            m = roads == r
            road_s, road_lanes, n = s[m], lanes[m], 0
            with_ego = ego is not None and road == ego[0]
            if not len(road_s) and not with_ego:
                continue
            if with_ego:  # the ego first
                n = len(ego[2])
                road_s, road_lanes = np.concatenate([ego[2], road_s]), np.concatenate([np.full(n, ego[1]), road_lanes])
            x, y, z, h = self.network.lane_pose(road, road_lanes, road_s)
            ego_pose = (x[:n], y[:n], z[:n], h[:n]) if with_ego else ego_pose
            km = k[m]
            heading[km] = h[n:]
            pos[km, 0], pos[km, 1], pos[km, 2] = x[n:], y[n:], z[n:]
        matrices = np.zeros((len(who), 4, 4))
        _yaw_poses(np.cos(heading), np.sin(heading), pos, matrices)
        out: list[dict[int, np.ndarray]] = [{} for _ in times]
        ids = list(self.actors)
        for k, (i, t) in enumerate(zip(who.tolist(), when.tolist())):
            out[t][ids[i]] = matrices[k]
        for actor_id, (actor, track) in self.trajectory_actors.items():
            translation, q = track.poses(times)
            body = np.tile(np.eye(4), (len(times), 1, 1))
            body[:, :3, :3], body[:, :3, 3] = quaternion_matrices(q), translation
            for t in np.flatnonzero(times >= appear_time(actor)):
                out[t][actor_id] = body[t]
        return out, ego_pose


# The tf tree of a scenario run: map -> base_link (the ego), base_link -> lidar (the mount) and
# map -> actor_<id> (each actor present), from a :class:`ScenarioPlayer`.
#
# The sim node publishes these as rclpy messages, the offline run writes them as rosbags messages;
# both only convert them. Frame names default to REP-105 (:mod:`lidar_weather_sim.core.names`).


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


#: cos and sin of roll and pitch 0 as numpy computes them (rpy_matrix's cr, sr, cp, sp).
_LEVEL = (float(np.cos(0.0)), float(np.sin(0.0)), float(np.cos(0.0)), float(np.sin(0.0)))


@numba.njit(cache=True)
def _yaw_poses(cy, sy, pos, out):
    """Body-to-map 4x4 poses (N, 4, 4), zeroed, of yaws with cosines ``cy`` and sines ``sy`` at
    positions ``pos`` (N, 3) m: ``rpy_matrix(0, 0, yaw)`` and ``pos``, the same expressions."""
    cr, sr, cp, sp = _LEVEL
    for k in range(len(cy)):
        c, s, m = cy[k], sy[k], out[k]
        m[0, 0], m[0, 1], m[0, 2] = c * cp, c * sp * sr - s * cr, c * sp * cr + s * sr
        m[1, 0], m[1, 1], m[1, 2] = s * cp, s * sp * sr + c * cr, s * sp * cr - c * sr
        m[2, 0], m[2, 1], m[2, 2] = -sp, cp * sr, cp * cr
        m[0, 3], m[1, 3], m[2, 3], m[3, 3] = pos[k, 0], pos[k, 1], pos[k, 2], 1.0


@numba.njit(cache=True)
def _mount(pos, c, s, az, aw, mount, b, translation, q):
    """Sensor poses of base_link poses (positions ``pos`` (N, 3) m, heading cosines ``c`` and sines
    ``s``, half-heading sines ``az`` and cosines ``aw``) with the mount (translation ``mount`` (3,)
    m, quaternion ``b`` x, y, z, w): ``translation`` (N, 3) and the Hamilton products
    yaw_quaternions(heading) * b, all their terms (the yaw quaternion's x and y are 0), into ``q`` (N, 4)."""
    mx, my, mz = mount[0], mount[1], mount[2]
    bx, by, bz, bw = b[0], b[1], b[2], b[3]
    ax = ay = 0.0
    for k in range(len(c)):
        translation[k, 0] = (c[k] * mx - s[k] * my) + pos[k, 0]
        translation[k, 1] = (s[k] * mx + c[k] * my) + pos[k, 1]
        translation[k, 2] = mz + pos[k, 2]
        z, w = az[k], aw[k]
        q[k, 0] = w * bx + ax * bw + ay * bz - z * by
        q[k, 1] = w * by - ax * bz + ay * bw + z * bx
        q[k, 2] = w * bz + ax * by - ay * bx + z * bw
        q[k, 3] = w * bw - ax * bx - ay * by - z * bz
