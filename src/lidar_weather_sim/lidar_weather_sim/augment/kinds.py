"""Obstacle kinds of ``augment --kinds``: the paper's box, and a car, a pedestrian and tyre debris.

Paper 4 only inserted boxes and said "the type of synthetic object can be easily changed"
(thesis line 2823). Each kind is drawn like the boxes (:func:`~lidar_weather_sim.augment.boxes.draw_box`:
the same draws in the same order, the whole footprint inside the cone ROI, drawn again on the car
ahead, durations from ``thesis_tables.yaml``) from the ranges below (uniform):

========== ============== ============= ============== ============ ==========================================
kind       length (m)     width (m)     height (m)     yaw          reflectivity (0-1)
========== ============== ============= ============== ============ ==========================================
box        --sizes (0.2-2, thesis yaml) same           same         0-90 deg     0-1 (thesis yaml)
vehicle    4.2-4.8        1.75-1.90     1.40-1.60      any          paint 0.05-0.80 (:data:`PAINT_REFLECTIVITY`)
pedestrian 0.25-0.35      0.45-0.55     1.60-1.90      any          0.10-0.60 (:data:`PEDESTRIAN_REFLECTIVITY`)
debris     0.3-1.0        0.15-0.25     0.03-0.10      any          0.5-2 x ``materials.yaml`` ``tyre``
========== ============== ============= ============== ============ ==========================================

Length is along the obstacle's x (a car's and a pedestrian's facing direction, a tread strip's long
side), width across, height above the road (m; REP-103 body frame, origin on the ground contact).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from lidar_weather_sim.augment.boxes import BoxRanges, ObstacleError, Roi, augmentation_table

KINDS = ("box", "vehicle", "pedestrian", "debris")
#: Diffuse NIR albedo of car paint at 905 nm, black to white (estimate: carbon-black paints absorb the
#: NIR, white paints reach ~0.8; the thesis' car body, ``materials.yaml`` ``car_paint`` 0.43, lies inside).
PAINT_REFLECTIVITY = (0.05, 0.80)
#: Diffuse NIR albedo of clothing and skin at 905 nm, dark to light (estimate).
PEDESTRIAN_REFLECTIVITY = (0.10, 0.60)
#: Tyre debris: this factor range times the thesis' wheel rubber (``materials.yaml`` ``tyre``).
DEBRIS_REFLECTIVITY_FACTOR = (0.5, 2.0)
_ANY_YAW = (-math.pi, math.pi)
_DIMS = {  # (length, width, height) lows and highs (m)
    "vehicle": ((4.2, 1.75, 1.40), (4.8, 1.90, 1.60)),
    "pedestrian": ((0.25, 0.45, 1.60), (0.35, 0.55, 1.90)),
    "debris": ((0.3, 0.15, 0.03), (1.0, 0.25, 0.10)),
}


@dataclass(frozen=True)
class KindRanges:
    """Ranges one non-box kind is drawn from (uniform): ``dims_m`` lowest and highest (length, width,
    height) m, yaw (rad), reflectivity (0-1; a car's paint), durations (frames, equal shares)."""

    kind: str
    dims_m: tuple[tuple[float, float, float], tuple[float, float, float]]
    yaw_rad: tuple[float, float]
    reflectivity: tuple[float, float]
    durations: tuple[int, ...]


def parse_kinds(text: str | list[str] | tuple[str, ...]) -> tuple[str, ...]:
    """``box,vehicle`` (or a sequence) -> ('box', 'vehicle'), each once in the order given;
    :class:`ObstacleError` naming an unknown kind."""
    names = text.split(",") if isinstance(text, str) else list(text)
    names = [n.strip().lower() for n in names if n.strip()]
    if not names:
        raise ObstacleError(f"--kinds: no kind given (choose from {','.join(KINDS)})")
    for name in names:
        if name not in KINDS:
            raise ObstacleError(f"unknown obstacle kind '{name}' (choose from {','.join(KINDS)})")
    return tuple(dict.fromkeys(names))


def tyre_reflectivity() -> float:
    """``materials.yaml``'s ``tyre`` albedo (the thesis' wheels, paper 3 Table II)."""
    from lidar_weather_sim.scene.materials import MaterialTable

    table = MaterialTable.default()
    return float(table.reflectivity[table.index("tyre")])


def kind_ranges(kind: str, size_m: tuple[float, float] | None = None) -> BoxRanges | KindRanges:
    """The ranges of ``kind`` (module table); ``size_m`` (``--sizes``) sets the box's sides only."""
    if kind == "box":
        return BoxRanges.paper(size_m)
    if kind not in _DIMS:
        raise ObstacleError(f"unknown obstacle kind '{kind}' (choose from {','.join(KINDS)})")
    durations = tuple(int(v) for v in augmentation_table()["box"]["duration_frames"])
    if kind == "vehicle":
        refl = PAINT_REFLECTIVITY
    elif kind == "pedestrian":
        refl = PEDESTRIAN_REFLECTIVITY
    else:
        rubber = tyre_reflectivity()
        refl = tuple(min(1.0, f * rubber) for f in DEBRIS_REFLECTIVITY_FACTOR)
    return KindRanges(kind, _DIMS[kind], _ANY_YAW, refl, durations)


def check_kind_fits(ranges: BoxRanges | KindRanges, roi: Roi) -> None:
    """:class:`ObstacleError` when the kind's largest footprint cannot fit the ROI at every yaw (its
    diagonal longer than the ROI's depth); boxes: :func:`~lidar_weather_sim.augment.boxes.check_fits`."""
    from lidar_weather_sim.augment.boxes import check_fits

    if isinstance(ranges, BoxRanges):
        check_fits(ranges, roi)
        return
    (_, _, _), (length, width, _) = ranges.dims_m
    if math.hypot(length, width) > roi.x_max_m - roi.x_min_m:
        raise ObstacleError(f"a {ranges.kind} up to {length:g} x {width:g} m does not fit the ROI "
                            f"(x {roi.x_min_m:g}-{roi.x_max_m:g} m)")  # fmt: skip
