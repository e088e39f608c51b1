"""What a filter may use of a cloud: every field it reads checked, the points it cannot use set aside.

A decoded cloud can still hold values no filter can work with: array fields (several values per
point), a float or negative channel, coordinates that are not finite or beyond any sensor's reach
(a KD-tree over 1e300 overflows), and the (0, 0, 0) placeholders organised clouds write for beams
without a return (thousands of duplicates make neighbour searches quadratic). :func:`usable_points`
refuses a cloud whose *required* fields are unusable with one :class:`CloudFieldError` naming the
field and the value (an unusable *optional* field, read only when present, is left out instead), and
marks the *points* that cannot take part (non-finite or out-of-reach coordinates,
placeholders at the origin): the filters run on the others only, so garbage never changes the
decision for a good point, and the set-aside points are removed (they are not detections) and
counted.

Limits: coordinates within :data:`MAX_COORDINATE_M` of the sensor (m, sensor frame), channels
0..:data:`MAX_CHANNELS` - 1 (no automotive LiDAR has more rings; the learned filter sizes its
range image by them), echo numbers 0..:data:`MAX_ECHO`.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.lib.recfunctions import repack_fields

#: Coordinates farther than this from the sensor on any axis are not a return (m).
MAX_COORDINATE_M = 1.0e4
#: Channels (rings) a filter accepts: 0 .. MAX_CHANNELS - 1.
MAX_CHANNELS = 1024
#: Largest echo (return) number a filter accepts.
MAX_ECHO = 255
#: Fields that hold small non-negative integers, with their largest value (``label``: the ground-truth
#: code ``weather-filter eval`` scores by).
INTEGER_FIELDS = {"channel": MAX_CHANNELS - 1, "echo": MAX_ECHO, "label": 255}


class CloudFieldError(ValueError):
    """A field a filter reads cannot be used (shape, type or value); the message names it."""


@dataclass(frozen=True)
class Usable:
    """``keep``: the points the filters use (bool, one per point); counts of those set aside."""

    keep: np.ndarray
    non_finite: int  # a coordinate NaN or infinite
    out_of_reach: int  # a coordinate beyond MAX_COORDINATE_M
    at_origin: int  # (0, 0, 0): the no-return placeholder of organised clouds
    ignored: tuple[str, ...] = ()  # optional fields left out (unusable; the filter runs as without them)

    @property
    def set_aside(self) -> int:
        return self.non_finite + self.out_of_reach + self.at_origin


def field_problem(points: np.ndarray, name: str) -> str | None:
    """Why a filter cannot read field ``name`` of ``points`` (one line naming it), or None."""
    dtype = points.dtype.fields[name][0]
    if dtype.shape:
        return f"field '{name}' holds {int(np.prod(dtype.shape))} values per point; a filter reads one"
    if name in INTEGER_FIELDS:
        if dtype.kind not in "iu":
            return f"field '{name}' is {dtype.name}; a filter needs integers"
        values = points[name]
        if len(values):
            lo, hi = int(values.min()), int(values.max())
            if lo < 0 or hi > INTEGER_FIELDS[name]:
                return f"field '{name}': value {lo if lo < 0 else hi} outside 0..{INTEGER_FIELDS[name]}"
    elif dtype.kind not in "iuf":
        return f"field '{name}' is {dtype.name}; a filter needs numbers"
    return None


def usable_points(points: np.ndarray, required: frozenset[str] | set[str],
                  optional: frozenset[str] | set[str] = frozenset()) -> tuple[np.ndarray, Usable]:  # fmt: skip
    """Check the fields of ``points`` (a structured array) a filter reads: a ``required`` one it cannot
    use raises :class:`CloudFieldError`; an ``optional`` one (read when present, e.g. the channel for the
    scan geometry) is left out of the returned points instead. Returns those points and which of them
    take part. Fields the cloud lacks are not checked (:class:`MissingFieldsError` is the filter's)."""
    names = list(points.dtype.names or ())
    for name in sorted(set(required) & set(names)):
        problem = field_problem(points, name)
        if problem:
            raise CloudFieldError(problem)
    ignored = tuple(n for n in names if n in set(optional) - set(required) and field_problem(points, n))
    if ignored:
        points = repack_fields(points[[n for n in names if n not in ignored]])
    if not {"x", "y", "z"} <= set(names):
        return points, Usable(np.ones(len(points), bool), 0, 0, 0, ignored)
    with np.errstate(invalid="ignore"):
        coords = [points[k].astype(np.float64, copy=False) for k in ("x", "y", "z")]
        finite = np.isfinite(coords[0]) & np.isfinite(coords[1]) & np.isfinite(coords[2])
        inside = finite & (np.abs(coords[0]) <= MAX_COORDINATE_M) & (np.abs(coords[1]) <= MAX_COORDINATE_M) & \
            (np.abs(coords[2]) <= MAX_COORDINATE_M)  # fmt: skip
        origin = (coords[0] == 0) & (coords[1] == 0) & (coords[2] == 0)
    keep = inside & ~origin
    return points, Usable(keep, int((~finite).sum()), int((finite & ~inside).sum()), int(origin.sum()), ignored)
