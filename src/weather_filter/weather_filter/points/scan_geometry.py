"""Angular sampling of a scan, estimated from the cloud itself.

Radius-based outlier filters (DROR, the LIOR isolation stage) need the angle
between neighbouring beams: a surface at range r is sampled every ``alpha * r``.
Hard-coding one sensor's value (the scala4's 0.25 deg) makes the filters remove
surface points of every coarser sensor (the OS1-128 at 1024 columns steps
0.35 deg) and, with 4 layers 0.8 deg apart, every point whose only neighbours
are in the layers above and below. So the steps are read off the points:

* azimuth step: within each channel, the points sorted by azimuth are one firing
  apart (or a multiple of it where returns are missing); the median of the
  consecutive differences is the step. Differences below ``MIN_STEP_RAD`` (the
  same firing seen as several echoes, range noise) are ignored.
* elevation step: the median difference between the channels' mean elevations.

The result is trusted only when the azimuth differences form a sharp mode (a
scanning pattern): at least ``MIN_DIFFS`` differences and their lower quartile
within a factor ``MODE_SPREAD`` of the median. Otherwise (a cloud without
``channel``, an unorganised test cloud) :func:`estimate_angular_steps` returns
``None`` and the caller uses its configured value.

The *resolution* used for a neighbour radius is the coarser of the two steps:
a point on a surface facing the sensor then has neighbours along both axes
within ``beta * alpha * r`` for any beta >= 1.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

MIN_STEP_RAD = 1e-4  # 0.006 deg: far below any scanning LiDAR's step (HDL-64E at 5 Hz: 0.08 deg)
MIN_DIFFS = 50
MODE_SPREAD = 1.5
#: alpha when the cloud has no scan structure to estimate it from (no ``channel``, or not a scanning
#: pattern, e.g. a hand-made test cloud): the project's reference sensor's step (scala4, 0.25 deg).
DEFAULT_ANGULAR_RESOLUTION_DEG = 0.25


@dataclass(frozen=True)
class AngularSteps:
    """Estimated steps in radians; ``elevation_rad`` is None for a single-channel cloud."""

    azimuth_rad: float
    elevation_rad: float | None

    @property
    def resolution_rad(self) -> float:
        """The coarser step: the spacing a neighbour search must span on both axes."""
        return max(self.azimuth_rad, self.elevation_rad or 0.0)


def estimate_angular_steps(points: np.ndarray) -> AngularSteps | None:
    """Azimuth and elevation steps of the scan that produced ``points``, or None if they cannot be told."""
    names = set(points.dtype.names or ())
    if "channel" not in names or len(points) < MIN_DIFFS:
        return None
    if "echo" in names:  # later echoes repeat their beam's direction
        points = points[points["echo"] <= 1]
    channel = points["channel"].astype(np.int64)
    if "azimuth" in names:
        azimuth = points["azimuth"].astype(np.float64)
    else:
        azimuth = np.arctan2(points["y"].astype(np.float64), points["x"].astype(np.float64))
    order = np.lexsort((azimuth, channel))
    diffs = np.diff(azimuth[order])
    diffs = diffs[(np.diff(channel[order]) == 0) & (diffs > MIN_STEP_RAD)]
    if len(diffs) < MIN_DIFFS:
        return None
    az_step = float(np.median(diffs))
    if np.percentile(diffs, 25) * MODE_SPREAD < az_step:
        return None  # no sharp mode: not a scanning pattern
    el_step = None
    if "elevation" in names:
        ids, inverse = np.unique(channel, return_inverse=True)
        if len(ids) > 1:
            mean_el = np.bincount(inverse, points["elevation"].astype(np.float64)) / np.bincount(inverse)
            gaps = np.diff(np.sort(mean_el))
            gaps = gaps[gaps > MIN_STEP_RAD]
            if len(gaps):
                el_step = float(np.median(gaps))
    return AngularSteps(az_step, el_step)


def angular_resolution_rad(points: np.ndarray, configured_deg: float | None, default_deg: float,
                           axis: str = "coarsest") -> float:  # fmt: skip
    """The neighbour-search angle: ``configured_deg`` if set, else estimated from ``points`` (``axis``
    "coarsest": :attr:`AngularSteps.resolution_rad`; "azimuth": the horizontal step), else ``default_deg``."""
    if configured_deg is not None:
        return float(np.radians(configured_deg))
    steps = estimate_angular_steps(points)
    if steps is None:
        return float(np.radians(default_deg))
    return steps.azimuth_rad if axis == "azimuth" else steps.resolution_rad
