"""Recorded frames augmented with synthetic obstacles (paper 4's data augmentation, thesis lines 2618-2819).

Per frame, ``objects`` slots each hold one box (:mod:`~lidar_weather_sim.augment.boxes`) for its
duration (1, 2 or 3 frames in equal shares), then draw a new one inside the cone ROI, again if it
overlaps the car ahead; with ``kinds`` other than the box alone, each new obstacle's kind is drawn first
(equal shares; :mod:`~lidar_weather_sim.augment.kinds`, meshes in
:mod:`~lidar_weather_sim.augment.meshes`). The obstacles are raycast with the recording's scan pattern by the simulator
(:mod:`~lidar_weather_sim.augment.cast`) and merged into the recorded frame with occlusion per
beam and the paper's range noise (:mod:`~lidar_weather_sim.augment.occlusion`). Obstacle points
carry label 3 (``OBSTACLE``) and their box's object id (from :data:`OBJECT_ID_BASE`); a recording
without ground truth gets ``label`` 0 and ``object_id`` 0 on its own points (44-byte layout). With
``epw_match="lead"`` (the paper's step, the default) the inserted points' EPW is matched to the car
ahead's rear over the whole recording (:mod:`~lidar_weather_sim.augment.epw`).

Frames: everything in the sensor frame (REP-103); m, rad. Seeded: the same recording, settings and
seed give the same output.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import NamedTuple

import numpy as np

from lidar_weather_sim.core.points import POINT_DTYPE, Label
from lidar_weather_sim.augment.boxes import (
    Box,
    BoxRanges,
    Footprint,
    ObstacleError,
    Roi,
    augmentation_table,
    check_fits,
    draw_box,
)
from lidar_weather_sim.augment.cast import ObstacleCaster
from lidar_weather_sim.augment.epw import EPW_MATCH, lead_car, match_to_lead, rear_mask
from lidar_weather_sim.augment.kinds import check_kind_fits, kind_ranges, parse_kinds
from lidar_weather_sim.augment.occlusion import merge_obstacles
from lidar_weather_sim.replay import ActorBox, road_level
from lidar_weather_sim.io.bags import BagWriter, read_messages
from lidar_weather_sim.io.recording import Recording
from lidar_weather_sim.sensor.profile import SensorProfile

#: Object id of the first inserted box (counted up per box; far from the simulator's ids).
OBJECT_ID_BASE = 3_000_000
#: Sensor height over the road (m) assumed when a recording shows no road.
DEFAULT_MOUNT_HEIGHT_M = 1.5
_ELEVATION_TOLERANCE_RAD = math.radians(0.5)  # median |elevation - the channel's| of a matching profile


def added_noise_sigma(profile: SensorProfile) -> float:
    """Range noise sigma (m) added to obstacle points so that with the profile's own range noise it
    totals the paper's ``noise_sigma_m``."""
    total = float(augmentation_table()["noise_sigma_m"])
    return math.sqrt(max(total**2 - float(profile.range.noise_sigma_m) ** 2, 0.0))


def with_ground_truth(points: np.ndarray) -> np.ndarray:
    """``points`` in a layout that has ``label`` and ``object_id``: their own fields plus those two at the
    project's offsets (44 bytes). A field the cloud lacks stays absent (a sensor without EPW keeps having
    none: a missing field, not a fill value, tells readers EPW is unknown)."""
    if "label" in points.dtype.names and "object_id" in points.dtype.names:
        return points
    names = [n for n in points.dtype.names if n in POINT_DTYPE.names]
    names += [n for n in ("label", "object_id") if n not in names]
    dtype = np.dtype({"names": names, "formats": [POINT_DTYPE.fields[n][0] for n in names],
                      "offsets": [POINT_DTYPE.fields[n][1] for n in names], "itemsize": POINT_DTYPE.itemsize})  # fmt: skip
    out = np.zeros(len(points), dtype)
    for name in names:
        if name in points.dtype.names:
            out[name] = points[name]
    return out


def check_profile(points: np.ndarray, profile: SensorProfile, name: str) -> None:
    """:class:`ObstacleError` unless the cloud's channels and elevations are the profile's."""
    from lidar_weather_sim.sensor.scan import ScanPattern

    if not len(points):
        return
    pattern = ScanPattern(profile)
    top = int(points["channel"].max())
    if top >= pattern.n_channels:
        raise ObstacleError(f"profile {name} has {pattern.n_channels} channels but the cloud has channel {top}")
    off = np.abs(points["elevation"].astype(np.float64) - pattern.elevation[points["channel"].astype(np.int64)])
    if float(np.median(off)) > _ELEVATION_TOLERANCE_RAD:
        raise ObstacleError(f"profile {name} does not match the cloud: median elevation off its channels' by "
                            f"{math.degrees(float(np.median(off))):.2f} deg")  # fmt: skip


def profile_for_cloud(points: np.ndarray) -> str:
    """The shipped profile (``config/sensors``) whose channels and elevations match the cloud; of several,
    the one whose column count is nearest the cloud's most first echoes on one channel."""
    from lidar_weather_sim.sensor.profile import load_profile, profiles_dir

    matching = []
    for path in sorted(profiles_dir().glob("*.yaml")):
        try:
            check_profile(points, load_profile(path), path.stem)
        except ObstacleError:
            continue
        matching.append(path.stem)
    if not matching:
        raise ObstacleError("no shipped sensor profile matches the cloud's channels and elevations: give --profile")
    first = points["channel"][points["echo"] <= 1]
    columns = int(np.bincount(first.astype(np.int64)).max(initial=0)) if len(first) else 0
    return min(matching, key=lambda name: abs(load_profile(name).scan.columns - columns))


@dataclass
class _Slot:
    box: Box
    left: int  # frames the box is still held, this one included


@dataclass
class ObstacleAugmenter:
    """Adds ``objects`` boxes per frame to consecutive frames of one recording (see module doc)."""

    profile: SensorProfile
    objects: int = 1
    size_m: tuple[float, float] | None = None
    seed: int = 0
    backend: str | None = None
    roi: Roi = field(default_factory=Roi.paper)
    kinds: tuple[str, ...] = ("box",)

    def __post_init__(self) -> None:
        if self.objects < 0:
            raise ObstacleError(f"--objects {self.objects}: need 0 or more")
        self.kinds = parse_kinds(self.kinds)
        self.ranges = BoxRanges.paper(self.size_m)
        check_fits(self.ranges, self.roi)
        self.kind_ranges = {k: kind_ranges(k, self.size_m) for k in self.kinds}
        for ranges in self.kind_ranges.values():
            check_kind_fits(ranges, self.roi)
        self.caster = ObstacleCaster(self.profile, self.backend)
        self.noise_sigma_m = added_noise_sigma(self.profile)
        self._rng = np.random.default_rng([int(self.seed) & 0xFFFFFFFF, 0x617567])  # "aug"
        self._slots: list[_Slot] = []
        self._next_id = OBJECT_ID_BASE
        self.frames = 0

    def boxes(self, road_z_m: float, avoid: tuple[Footprint, ...] = ()) -> list[Box]:
        """The boxes of the next frame: held ones, and new ones for slots whose box expired (of several
        kinds, the kind drawn first, equal shares: a single kind draws nothing more)."""
        slots = [s for s in self._slots if s.left > 0]
        while len(slots) < self.objects:
            taken = tuple(s.box.footprint for s in slots)
            kind = self.kinds[int(self._rng.integers(len(self.kinds)))] if len(self.kinds) > 1 else self.kinds[0]
            box = draw_box(self._rng, self.kind_ranges[kind], self.roi, road_z_m, self._next_id, avoid + taken)
            self._next_id += 1
            slots.append(_Slot(box, box.duration))
        for s in slots:
            s.left -= 1
        self._slots = slots
        return [s.box for s in slots]

    def frame(self, points: np.ndarray, frame_index: int, road_z_m: float,
              avoid: tuple[Footprint, ...] = ()) -> tuple[np.ndarray, list[Box]]:  # fmt: skip
        """``points`` (a recorded frame, sensor frame) with the next frame's boxes; scan ``frame_index``
        decides alternating layers; ``road_z_m``: road height (m, sensor frame); ``avoid``: the car ahead."""
        boxes = self.boxes(road_z_m, avoid)
        cast_seed = int(self._rng.integers(0, 2**31))
        obstacle = self.caster.cast(boxes, frame_index, cast_seed)
        merged = merge_obstacles(with_ground_truth(points), obstacle, self.caster.pattern,
                                 self.profile.detection.max_echoes, self.noise_sigma_m, self._rng)  # fmt: skip
        self.frames += 1
        return merged, boxes


def car_ahead(recording: Recording, frame) -> tuple[Footprint, ...]:
    """Footprints (sensor frame at the frame's stamp) of the recording's ``actor_<id>`` vehicles
    (a mid-size car's size: bags carry no actor sizes)."""
    to_sensor = recording.sensor_from_fixed(frame)
    if to_sensor is None:
        return ()
    out = []
    size = ActorBox(0, np.eye(4))
    for pose in recording.actor_poses(recording.time_s(frame.stamp_ns)).values():
        m = to_sensor @ pose
        out.append(Footprint(float(m[0, 3]), float(m[1, 3]), math.atan2(m[1, 0], m[0, 0]), size.length_m, size.width_m))
    return tuple(out)


class AugmentSummary(NamedTuple):
    """What :func:`augment_bag` did: frames written, obstacles inserted, the EPW matching's one line."""

    frames: int
    boxes: int
    epw: str


def lead_rear_epw(recording: Recording, road_z_m: float) -> tuple[np.ndarray | None, str]:
    """EPWs (m) of the recorded points on the car ahead's rear over every frame
    (:func:`~lidar_weather_sim.augment.epw.rear_mask`), or None and why not."""
    if "epw" not in recording.frames[0].points.dtype.names:
        return None, "the cloud has no EPW field"
    if not recording.actor_ids():
        return None, "the bag has no car ahead (no actor_<id> transform in /tf)"
    epw, seen = [], False
    for frame in recording.frames:
        car = lead_car(car_ahead(recording, frame))
        if car is not None:
            seen = True
            epw.append(frame.points["epw"][rear_mask(frame.points, car, road_z_m)])
    if not seen:
        return None, "no actor_<id> is ahead of the sensor (x > 0) in any frame"
    return np.concatenate(epw).astype(np.float64), ""


def augment_bag(path: str | Path, output: str | Path, profile: SensorProfile, profile_name: str, *,
                topic: str | None = None, objects: int = 1, size_m: tuple[float, float] | None = None,
                seed: int = 0, backend: str | None = None, overwrite: bool = False,
                kinds: tuple[str, ...] | str = ("box",), epw_match: str = "lead") -> AugmentSummary:  # fmt: skip
    """Write ``path`` with obstacles in every frame of its cloud topic to ``output``; every other
    message is copied. ``kinds``: obstacle kinds drawn in equal shares; ``epw_match``: ``lead`` (the
    paper) matches the inserted points' EPW to the car ahead's rear, ``none`` keeps the sensor
    model's. Checks everything before writing anything."""
    if epw_match not in EPW_MATCH:
        raise ObstacleError(f"--epw-match {epw_match}: choose from {', '.join(EPW_MATCH)}")
    recording = Recording.load(path, topic)
    check_profile(recording.frames[0].points, profile, profile_name)
    augmenter = ObstacleAugmenter(profile, objects, size_m, seed, backend, kinds=parse_kinds(kinds))
    road_z = road_level(recording)
    if road_z < -100.0:  # no returns: the road is not in view
        road_z = -DEFAULT_MOUNT_HEIGHT_M
    period = profile.period_s
    frames = [augmenter.frame(f.points, recording.scan_index(f, period), road_z, car_ahead(recording, f))[0]
              for f in recording.frames]  # fmt: skip
    epw_note = "EPW from the sensor model (--epw-match none)"
    if epw_match == "lead":
        inserted = [(p["label"] == Label.OBSTACLE) & (p["object_id"] >= OBJECT_ID_BASE) for p in frames]
        rear, reason = lead_rear_epw(recording, road_z)
        epw_note = match_to_lead(frames, inserted, rear, reason)
    with BagWriter(output, overwrite=overwrite) as bag:
        for m in read_messages(path):
            if m.topic != recording.topic:
                bag.write(m.topic, m.msg, m.log_time_ns)
        for frame, points in zip(recording.frames, frames):
            bag.write_cloud(recording.topic, points, frame.stamp_ns, frame.frame_id, log_time_ns=frame.log_time_ns)
    return AugmentSummary(len(frames), augmenter._next_id - OBJECT_ID_BASE, epw_note)
