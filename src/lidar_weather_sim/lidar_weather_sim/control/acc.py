"""A minimal adaptive cruise controller on a LiDAR cloud, and the fixed definition of "brakes".

No ROS import. Obstacles: clusters of at least ``min_points`` points inside
the ego's lane corridor (|y| <= ``half_width_m``, between ``min_height_m`` and
``max_height_m`` above the road, ``min_range_m`` to ``max_range_m`` ahead,
sensor frame: x forward, y left, z up, the road ``sensor_height_m`` below the
sensor), a cluster being the points within ``cluster_length_m`` in x of its
nearest one (:func:`clusters`, nearest first). As in a radar or LiDAR ACC's
track management (:class:`ObstacleTrack`), every cluster starts or continues a
track, and the controller acts on the nearest confirmed one: seen in
``confirm_frames`` consecutive clouds, its distance changing by at most
``track_gate_m`` from one cloud to the next; a confirmed track coasts through
up to ``coast_frames`` clouds without a cluster (an obstacle hidden for a moment
by spray). Near-field clutter that appears at random ranges in single clouds
(rain drops 0-5 m in front of the sensor) is not confirmed, and it does not
interrupt the track of an obstacle behind it; a spray cloud that follows a
vehicle, or a real obstacle, is confirmed. The controller treats the
obstacle as standing still (conservative): the deceleration needed to stop
``standstill_m`` before it is a = v^2 / (2 (d - standstill_m)); it brakes with
that when a >= ``min_brake_m_s2`` (capped at ``max_brake_m_s2``), otherwise
it returns to ``cruise_speed_m_s`` at ``accel_m_s2``.

Braking (fixed before any run): the commanded deceleration exceeds
2 m/s^2 for at least 0.3 s (:func:`braking_events` on the commanded speed trace).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from pydantic import Field

from lidar_weather_sim.core.config import ConfigModel

BRAKE_DECEL_M_S2 = 2.0
BRAKE_MIN_DURATION_S = 0.3


class AccConfig(ConfigModel):
    cruise_speed_m_s: float = Field(24.72, ge=0, description="Set speed (m/s)")
    half_width_m: float = Field(1.3, gt=0, description="Lane corridor half width around the sensor axis (m)")
    sensor_height_m: float = Field(0.5, ge=0, description="Sensor above the road (m)")
    min_height_m: float = Field(0.25, description="Lowest obstacle point above the road (m)")
    max_height_m: float = Field(2.5, description="Highest obstacle point above the road (m)")
    min_range_m: float = Field(2.0, ge=0, description="Nearest x considered (m)")
    max_range_m: float = Field(100.0, gt=0, description="Farthest x considered (m)")
    min_points: int = Field(5, ge=1, description="Points a cluster needs to count as an obstacle")
    cluster_length_m: float = Field(1.0, gt=0, description="Cluster extent in x from its nearest point (m)")
    confirm_frames: int = Field(3, ge=1, description="Consecutive clouds an obstacle needs before the controller reacts")
    coast_frames: int = Field(2, ge=0, description="Clouds a confirmed obstacle may be missing before its track ends")
    track_gate_m: float = Field(1.0, gt=0, description="Largest distance change of one obstacle between clouds (m)")
    standstill_m: float = Field(5.0, ge=0, description="Distance to stop before an obstacle (m)")
    min_brake_m_s2: float = Field(0.5, ge=0, description="Below this needed deceleration: no braking (m/s^2)")
    max_brake_m_s2: float = Field(8.0, gt=0, description="Deceleration limit (m/s^2)")
    accel_m_s2: float = Field(1.0, gt=0, description="Acceleration back to the set speed (m/s^2)")


def clusters(points: np.ndarray, cfg: AccConfig) -> list[np.ndarray]:
    """Point indices of every in-lane cluster of >= min_points points, nearest first; each starts at the
    nearest in-lane point beyond the previous cluster whose ``cluster_length_m`` window holds enough points."""
    x, y, z = (np.asarray(points[k], dtype=np.float64) for k in ("x", "y", "z"))
    h = z + cfg.sensor_height_m
    inside = (np.abs(y) <= cfg.half_width_m) & (h >= cfg.min_height_m) & (h <= cfg.max_height_m)
    idx = np.flatnonzero(inside & (x >= cfg.min_range_m) & (x <= cfg.max_range_m))
    idx = idx[np.argsort(x[idx], kind="stable")]
    xs = x[idx]
    counts = np.searchsorted(xs, xs + cfg.cluster_length_m, side="right") - np.arange(len(xs))
    found, start = [], 0
    for i in np.flatnonzero(counts >= cfg.min_points):
        if i >= start:
            found.append(idx[i : i + counts[i]])
            start = i + counts[i]
    return found


def nearest_cluster(points: np.ndarray, cfg: AccConfig) -> np.ndarray:
    """Indices of the points of the nearest in-lane cluster of >= min_points points (empty: none)."""
    found = clusters(points, cfg)
    return found[0] if found else np.zeros(0, np.int64)


def obstacle_distance(points: np.ndarray, cfg: AccConfig) -> float | None:
    """x (m) of the nearest in-lane cluster of >= min_points points, or None."""
    cluster = nearest_cluster(points, cfg)
    return float(points["x"][cluster[0]]) if len(cluster) else None


@dataclass
class Track:
    """One obstacle hypothesis: last distance (m), clouds seen in a row, clouds missed since, and the tag
    (e.g. the label) of its last cluster."""

    distance_m: float
    hits: int = 1
    misses: int = 0
    tag: object = None


class ObstacleTrack:
    """Track management over the clusters of each cloud (see the module docstring)."""

    def __init__(self, cfg: AccConfig) -> None:
        self.cfg, self.tracks = cfg, []

    def update(self, distances_m, tags=None) -> Track | None:
        """Call once per cloud with its clusters' distances (m, any order) and optional tags; returns the
        nearest confirmed track (its distance is the last seen while it coasts), or None."""
        cfg, distances = self.cfg, [float(d) for d in distances_m]
        tags = list(tags) if tags is not None else [None] * len(distances)
        free = set(range(len(distances)))
        for track in sorted(self.tracks, key=lambda tr: (-tr.hits, tr.distance_m)):  # established tracks first
            near = [i for i in free if abs(distances[i] - track.distance_m) <= cfg.track_gate_m]
            if near:
                i = min(near, key=lambda i: (abs(distances[i] - track.distance_m), i))
                free.discard(i)
                track.distance_m, track.hits, track.misses, track.tag = distances[i], track.hits + 1, 0, tags[i]
            else:
                track.misses += 1
        confirmed = cfg.confirm_frames
        self.tracks = [tr for tr in self.tracks if tr.misses == 0 or (tr.hits >= confirmed and tr.misses <= cfg.coast_frames)]
        self.tracks += [Track(distances[i], tag=tags[i]) for i in sorted(free)]
        ready = [tr for tr in self.tracks if tr.hits >= confirmed]
        return min(ready, key=lambda tr: tr.distance_m) if ready else None


@dataclass
class AccState:
    speed_m_s: float
    time_s: float | None = None


def step(state: AccState, time_s: float, distance_m: float | None, cfg: AccConfig) -> tuple[float, float]:
    """Advance to ``time_s`` given the obstacle distance; returns (commanded speed m/s, deceleration m/s^2)."""
    dt = 0.0 if state.time_s is None else max(0.0, time_s - state.time_s)
    v = state.speed_m_s
    decel = 0.0
    if distance_m is not None:
        gap = distance_m - cfg.standstill_m
        need = cfg.max_brake_m_s2 if gap <= 0.1 else v * v / (2.0 * gap)
        if need >= cfg.min_brake_m_s2:
            decel = min(need, cfg.max_brake_m_s2)
    if decel > 0:
        v = max(0.0, v - decel * dt)
    elif distance_m is None or v < cfg.cruise_speed_m_s:
        v = min(cfg.cruise_speed_m_s, v + cfg.accel_m_s2 * dt)
    state.speed_m_s, state.time_s = v, time_s
    return v, decel


def commanded_deceleration(times_s: np.ndarray, speeds_m_s: np.ndarray) -> np.ndarray:
    """-dv/dt between consecutive commands (m/s^2), one value per interval."""
    t, v = np.asarray(times_s, float), np.asarray(speeds_m_s, float)
    return -np.diff(v) / np.maximum(np.diff(t), 1e-9)


def braking_events(times_s, speeds_m_s, threshold_m_s2: float = BRAKE_DECEL_M_S2,
                   min_duration_s: float = BRAKE_MIN_DURATION_S) -> list[tuple[float, float]]:  # fmt: skip
    """(start, end) s of every stretch where the commanded deceleration > threshold for >= min_duration."""
    t = np.asarray(times_s, float)
    above = commanded_deceleration(t, speeds_m_s) > threshold_m_s2
    events, start = [], None
    for i, on in enumerate(np.append(above, False)):
        if on and start is None:
            start = t[i]
        elif not on and start is not None:
            if t[i] - start >= min_duration_s - 1e-9:
                events.append((float(start), float(t[i])))
            start = None
    return events
