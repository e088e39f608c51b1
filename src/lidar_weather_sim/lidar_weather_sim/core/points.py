"""The one point layout used by every cloud this project writes.

The first 32 bytes are Autoware/Nebula's ``PointXYZIRCAEDT``; echo, EPW and the
ground-truth fields follow. Clouds are unorganised (height 1).

| Field      | Type    | Offset | Units | Description                                              |
|------------|---------|-------:|-------|----------------------------------------------------------|
| x          | float32 |      0 | m     | sensor frame (REP-103: x forward, y left, z up)          |
| y          | float32 |      4 | m     |                                                          |
| z          | float32 |      8 | m     |                                                          |
| intensity  | uint8   |     12 | -     | 0-255, received power on the sensor's scale              |
| return_type| uint8   |     13 | -     | Nebula return type (``ReturnType``: 1 last, 2 first...)  |
| channel    | uint16  |     14 | -     | beam index, 0 = lowest beam                              |
| azimuth    | float32 |     16 | rad   | atan2(y, x) in the sensor frame                          |
| elevation  | float32 |     20 | rad   | atan2(z, hypot(x, y))                                    |
| distance   | float32 |     24 | m     | range along the beam                                     |
| time_stamp | uint32  |     28 | ns    | firing time after the header stamp                       |
| echo       | uint8   |     32 | -     | 1-based rank among the beam's detected echoes, by range  |
| label      | uint8   |     33 | -     | ground truth, see ``Label`` (only with ground truth)      |
| epw        | float32 |     36 | m     | echo pulse width                                         |
| object_id  | uint32  |     40 | -     | ground-truth object (only with ground truth)             |

With ground truth the point step is 44 bytes; without it ``label`` and
``object_id`` are absent, byte 33-35 is padding and the step is 40 bytes.
Real sensors that measure no EPW (e.g. an Ouster OS1) write the 40-byte layout
without the ``epw`` field as well (:data:`POINT_DTYPE_NO_EPW`): a missing field,
not a fill value, is how readers such as the weather filters tell that EPW is
unknown (they then fall back to intensity or geometry).
``echo`` is the rank of the echo among all the echoes its beam detected (up to ``max_echoes``), also when
the return mode reports only some of them: under ``last`` a beam whose drop in front of a wall gave two
echoes reports the wall with echo 2. ``return_type`` says which return the mode reported (Nebula's codes):
under ``all`` IDENTICAL, FIRST, SECOND or LAST by position among the beam's points; under ``strongest``,
``last``, ``first`` STRONGEST, LAST, FIRST; under ``dual`` LAST and STRONGEST, or LAST_STRONGEST and
SECOND_STRONGEST when the last echo is the strongest, or IDENTICAL for a beam with one echo.
A merged echo takes the label and object id of its strongest contributing
sub-ray; a spray point's object id is the emitting vehicle's.
"""

from __future__ import annotations

from enum import IntEnum

import numpy as np

POINT_STEP_WITH_GROUND_TRUTH = 44
POINT_STEP_WITHOUT_GROUND_TRUTH = 40


class Label(IntEnum):
    """Ground-truth label codes carried in the ``label`` field."""

    UNKNOWN = 0
    STATIC = 1  # road, guard rails, buildings
    VEHICLE = 2
    OBSTACLE = 3
    COVER = 10
    RAIN = 11
    FOG = 12
    SNOW = 13
    SPRAY = 14
    NOISE = 15


#: Labels of weather or sensor artefacts that a weather filter should remove.
WEATHER_LABELS = frozenset({Label.COVER, Label.RAIN, Label.FOG, Label.SNOW, Label.SPRAY, Label.NOISE})
class ReturnType(IntEnum):
    """Nebula's return types (nebula_common ``ReturnType``) of the ``return_type`` field."""

    UNKNOWN = 0
    LAST = 1
    FIRST = 2
    STRONGEST = 3
    IDENTICAL = 6  # the beam's only kept echo (all, dual)
    SECOND = 7
    SECOND_STRONGEST = 8  # dual: the strongest of the others when the last echo is the strongest
    LAST_STRONGEST = 10  # dual: the last echo when it is also the strongest


#: Labels of solid objects that a weather filter must keep.
SOLID_LABELS = frozenset({Label.STATIC, Label.VEHICLE, Label.OBSTACLE})

_BASE_FIELDS = [
    ("x", np.float32, 0),
    ("y", np.float32, 4),
    ("z", np.float32, 8),
    ("intensity", np.uint8, 12),
    ("return_type", np.uint8, 13),
    ("channel", np.uint16, 14),
    ("azimuth", np.float32, 16),
    ("elevation", np.float32, 20),
    ("distance", np.float32, 24),
    ("time_stamp", np.uint32, 28),
    ("echo", np.uint8, 32),
]


def _dtype(fields: list[tuple[str, type, int]], itemsize: int) -> np.dtype:
    return np.dtype(
        {
            "names": [f[0] for f in fields],
            "formats": [np.dtype(f[1]).newbyteorder("<") for f in fields],
            "offsets": [f[2] for f in fields],
            "itemsize": itemsize,
        }
    )


#: Point dtype with ground truth (``label``, ``object_id``); 44 bytes.
POINT_DTYPE = _dtype(
    _BASE_FIELDS + [("label", np.uint8, 33), ("epw", np.float32, 36), ("object_id", np.uint32, 40)],
    POINT_STEP_WITH_GROUND_TRUTH,
)
#: Point dtype without ground truth; 40 bytes.
POINT_DTYPE_NO_GROUND_TRUTH = _dtype(_BASE_FIELDS + [("epw", np.float32, 36)], POINT_STEP_WITHOUT_GROUND_TRUTH)
#: Point dtype of real sensors without EPW and without ground truth; 40 bytes, bytes 33-39 padding.
POINT_DTYPE_NO_EPW = _dtype(_BASE_FIELDS, POINT_STEP_WITHOUT_GROUND_TRUTH)


def point_dtype(ground_truth: bool = True) -> np.dtype:
    """The project's point dtype, with or without the ground-truth fields."""
    return POINT_DTYPE if ground_truth else POINT_DTYPE_NO_GROUND_TRUTH


def empty_points(n: int = 0, ground_truth: bool = True) -> np.ndarray:
    """A zero-filled point array of length ``n`` in the project's layout."""
    return np.zeros(n, dtype=point_dtype(ground_truth))


def strip_ground_truth(points: np.ndarray) -> np.ndarray:
    """Copy of ``points`` in the 40-byte layout (drops ``label`` and ``object_id``)."""
    out = np.empty(len(points), dtype=POINT_DTYPE_NO_GROUND_TRUTH)
    for name in POINT_DTYPE_NO_GROUND_TRUTH.names:
        out[name] = points[name]
    return out


def fill_polar(points: np.ndarray) -> None:
    """Set ``azimuth``, ``elevation`` and ``distance`` in place from x, y, z (sensor frame)."""
    x = points["x"].astype(np.float64)
    y = points["y"].astype(np.float64)
    z = points["z"].astype(np.float64)
    horizontal = np.hypot(x, y)
    points["azimuth"] = np.arctan2(y, x)
    points["elevation"] = np.arctan2(z, horizontal)
    points["distance"] = np.hypot(horizontal, z)


def add_range_noise(points: np.ndarray, sigma_m: float, rng: np.random.Generator) -> None:
    """Move ``points`` (an array or a view with x, y, z, distance) along their beams by N(0, sigma_m) (m), in
    place (ranges kept >= 1 mm)."""
    if sigma_m <= 0 or not len(points):
        return
    d = points["distance"].astype(np.float64)
    new = np.maximum(d + rng.normal(0.0, sigma_m, len(d)), 1e-3)
    scale = new / np.maximum(d, 1e-9)
    for axis in ("x", "y", "z"):
        points[axis] = points[axis] * scale
    points["distance"] = new
