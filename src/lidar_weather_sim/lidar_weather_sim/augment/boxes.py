"""Synthetic obstacle boxes of paper 4 (thesis lines 2618-2819): what they are and where they go.

Every value comes from ``thesis_tables.yaml``, key ``augmentation`` (:func:`augmentation_table`),
read at run time: the cone ROI (``roi``: x from ``x_min_m`` to ``x_max_m`` m ahead of the
sensor, ``|atan2(y, x)| <= half_angle_deg``), the box ranges (``box``: sides ``size_m``,
yaw ``rotation_deg``, Lambertian ``reflectivity``, ``duration_frames`` held in equal shares)
and the range noise ``noise_sigma_m``.

Frames: boxes are placed in the sensor frame of the frame they appear in (REP-103: x forward,
y left, z up; m, rad). "Inside the ROI" means the whole footprint (its four corners), so an
obstacle side longer than the ROI allows is an error (:class:`ObstacleError`), not a box that
sticks out. A box whose footprint overlaps the car ahead (any :class:`Footprint` given) is drawn
again (line 2745).
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass
from functools import cache
from pathlib import Path

import numpy as np
import yaml

from lidar_weather_sim.core.paths import config_dir

_MAX_DRAWS = 1000  # draws per box before giving up (the car ahead fills the ROI)


class ObstacleError(ValueError):
    """Obstacle settings that cannot be met (one line, for the CLI)."""


def thesis_tables_path() -> Path:
    """``LWS_THESIS_TABLES``, else ``shared/data/thesis_tables.yaml`` beside the workspace."""
    if os.environ.get("LWS_THESIS_TABLES"):
        return Path(os.environ["LWS_THESIS_TABLES"])
    return config_dir().parent.parent / "shared" / "data" / "thesis_tables.yaml"


@cache
def augmentation_table() -> dict:
    """The ``augmentation`` entry of the thesis tables (paper 4's values), read once."""
    path = thesis_tables_path()
    if not path.is_file():
        raise ObstacleError(f"thesis tables not found at {path} (set LWS_THESIS_TABLES)")
    return yaml.safe_load(path.read_text())["augmentation"]


@dataclass(frozen=True)
class Roi:
    """The cone ROI in the sensor frame: x_min_m <= x <= x_max_m (m), |atan2(y, x)| <= half_angle_rad."""

    x_min_m: float
    x_max_m: float
    half_angle_rad: float

    @classmethod
    def paper(cls) -> "Roi":
        roi = augmentation_table()["roi"]
        return cls(float(roi["x_min_m"]), float(roi["x_max_m"]), math.radians(float(roi["half_angle_deg"])))

    def contains(self, x: np.ndarray, y: np.ndarray) -> np.ndarray:
        """Points (m, sensor frame) inside the cone."""
        x, y = np.asarray(x, np.float64), np.asarray(y, np.float64)
        return (x >= self.x_min_m) & (x <= self.x_max_m) & (np.abs(y) <= x * math.tan(self.half_angle_rad))

    def largest_side_m(self) -> float:
        """The longest box side that fits at every yaw of 0-90 deg: its footprint diagonal is at most the
        ROI's depth (a square of side s at 45 deg spans s sqrt 2 in x)."""
        return (self.x_max_m - self.x_min_m) / math.sqrt(2.0)


@dataclass(frozen=True)
class BoxRanges:
    """Ranges the boxes are drawn from (uniform): sides (m), yaw (rad), reflectivity (0-1), and the
    durations (frames) drawn in equal shares."""

    size_m: tuple[float, float]
    yaw_rad: tuple[float, float]
    reflectivity: tuple[float, float]
    durations: tuple[int, ...]

    kind = "box"

    @property
    def dims_m(self) -> tuple[tuple[float, float, float], tuple[float, float, float]]:
        """Lowest and highest (length, width, height) (m): every side in ``size_m``."""
        return (self.size_m[0],) * 3, (self.size_m[1],) * 3

    @classmethod
    def paper(cls, size_m: tuple[float, float] | None = None) -> "BoxRanges":
        box = augmentation_table()["box"]
        lo, hi = size_m if size_m is not None else box["size_m"]
        if not 0.0 < float(lo) <= float(hi):
            raise ObstacleError(f"obstacle sides {lo}:{hi} m: need 0 < min <= max")
        return cls((float(lo), float(hi)), tuple(math.radians(float(v)) for v in box["rotation_deg"]),
                   tuple(float(v) for v in box["reflectivity"]), tuple(int(v) for v in box["duration_frames"]))  # fmt: skip


@dataclass(frozen=True)
class Footprint:
    """Oriented rectangle on the road (sensor frame, m, rad): centre, length along yaw, width across."""

    x: float
    y: float
    yaw: float
    length: float
    width: float

    def corners(self) -> np.ndarray:
        """(4, 2) corners (m)."""
        c, s = math.cos(self.yaw), math.sin(self.yaw)
        hl, hw = 0.5 * self.length, 0.5 * self.width
        local = np.array([[hl, hw], [-hl, hw], [-hl, -hw], [hl, -hw]])
        return local @ np.array([[c, s], [-s, c]]) + [self.x, self.y]


def footprints_overlap(a: Footprint, b: Footprint) -> bool:
    """Separating-axis test of two oriented rectangles."""
    ca, cb = a.corners(), b.corners()
    for yaw in (a.yaw, b.yaw):
        for axis in (np.array([math.cos(yaw), math.sin(yaw)]), np.array([-math.sin(yaw), math.cos(yaw)])):
            pa, pb = ca @ axis, cb @ axis
            if pa.max() < pb.min() or pb.max() < pa.min():
                return False
    return True


@dataclass(frozen=True)
class Box:
    """One synthetic obstacle in the sensor frame of the frame it first appears in: footprint centre
    (x, y) m, bottom z_bottom m, sides (length along yaw, width, height) m, yaw rad, reflectivity,
    ``duration`` frames, ``object_id``; ``kind``: the paper's box or a mesh of
    :mod:`~lidar_weather_sim.augment.meshes` whose bounding box these sides are."""

    x: float
    y: float
    z_bottom: float
    length: float
    width: float
    height: float
    yaw: float
    reflectivity: float
    duration: int
    object_id: int
    kind: str = "box"

    @property
    def footprint(self) -> Footprint:
        return Footprint(self.x, self.y, self.yaw, self.length, self.width)

    def pose(self) -> np.ndarray:
        """4x4 body-to-sensor transform (body: footprint centre on the box bottom, x along ``length``)."""
        c, s = math.cos(self.yaw), math.sin(self.yaw)
        m = np.eye(4)
        m[:2, :2] = [[c, -s], [s, c]]
        m[:3, 3] = [self.x, self.y, self.z_bottom]
        return m


def check_fits(ranges: BoxRanges, roi: Roi) -> None:
    """:class:`ObstacleError` when the largest side cannot fit in the ROI at every yaw."""
    if ranges.size_m[1] > roi.largest_side_m():
        raise ObstacleError(f"obstacle sides up to {ranges.size_m[1]:g} m do not fit the ROI "
                            f"(x {roi.x_min_m:g}-{roi.x_max_m:g} m): at most {roi.largest_side_m():.2f} m")  # fmt: skip


def draw_box(rng: np.random.Generator, ranges: BoxRanges, roi: Roi, road_z_m: float, object_id: int,
             avoid: tuple[Footprint, ...] = ()) -> Box:  # fmt: skip
    """One box: sides, yaw, reflectivity uniform in ``ranges``, duration one of ``ranges.durations``,
    centre uniform in the ROI's bounding box, drawn again until its footprint is inside the ROI and
    clear of every footprint in ``avoid`` (the car ahead). Bottom on the road (``road_z_m``, sensor frame).
    ``ranges`` may be any kind's (:class:`~lidar_weather_sim.augment.kinds.KindRanges`: its
    ``kind``, ``dims_m``, ``yaw_rad``, ``reflectivity``, ``durations``); the draws are the same in number
    and order for every kind, so boxes alone give what they always gave."""
    if ranges.kind == "box":
        check_fits(ranges, roi)
    y_max = roi.x_max_m * math.tan(roi.half_angle_rad)
    low, high = ranges.dims_m
    for _ in range(_MAX_DRAWS):
        length, width, height = rng.uniform(low, high)
        yaw = rng.uniform(*ranges.yaw_rad)
        refl = rng.uniform(*ranges.reflectivity)
        duration = int(rng.choice(ranges.durations))
        x, y = rng.uniform(roi.x_min_m, roi.x_max_m), rng.uniform(-y_max, y_max)
        box = Box(float(x), float(y), float(road_z_m), float(length), float(width), float(height), float(yaw),
                  float(refl), duration, int(object_id), ranges.kind)  # fmt: skip
        corners = box.footprint.corners()
        if roi.contains(corners[:, 0], corners[:, 1]).all() and not any(footprints_overlap(box.footprint, a) for a in avoid):
            return box
    raise ObstacleError(f"no obstacle fits the ROI clear of the car ahead after {_MAX_DRAWS} draws")
