"""Reflectivity per triangle of a twin's mesh from the recorded intensities.

The simulator's radiometry (:mod:`lidar_weather_sim.sensor.radiometry`) run backwards, in the sensor's
profile: an intensity byte I is a peak amplitude A = T D^(I / 255) (T the dark threshold, D the
profile's ``intensity_dynamic_range``), and a full-beam Lambertian hit gives A = C rho cos(theta) / R^2 x
O(R) (C the power constant, O the biaxial overlap, clear air), so

    rho = A R^2 / (C cos(theta) O(R))

with R the point's range (m) and theta the angle between its ray and the normal of its nearest triangle
(cos clipped at :data:`MIN_COS` only so that a ray along its surface cannot
blow up: the forward model uses the unclipped cos, and a clip at 0.2 made the road beyond ~10 m, hit at
cos 0.1-0.2, come back too weak and below the threshold in re-simulation). Per triangle the geometric mean of its
points' rho, clipped to the surveyed range; a triangle without points takes its nearest neighbour's with points. A
re-simulation then returns, at the recorded geometry, the recorded intensity - whatever the sensor's own
intensity scale (a real sensor's calibrated reflectivity is read as if it were this profile's intensity).
"""

from __future__ import annotations

import numpy as np

from lidar_weather_sim.scene.surveyed import REFLECTIVITY_RANGE
from lidar_weather_sim.sensor.profile import SensorProfile
from lidar_weather_sim.sensor.radiometry import dark_level, overlap_factor

MIN_COS = 0.02


def point_reflectivity(intensity: np.ndarray, range_m: np.ndarray, cos_incidence: np.ndarray,
                       profile: SensorProfile) -> np.ndarray:  # fmt: skip
    """rho (N,) of points with ``intensity`` (0-255), ``range_m`` (m) and ``cos_incidence`` (module doc)."""
    det, optics = profile.detection, profile.optics
    peak = dark_level(det) * det.intensity_dynamic_range ** (np.asarray(intensity, dtype=np.float64) / 255.0)
    overlap = np.maximum(overlap_factor(range_m, optics.overlap_start_m, optics.overlap_full_m), 1e-3)
    cos = np.clip(np.abs(cos_incidence), MIN_COS, 1.0)
    return peak * np.asarray(range_m, dtype=np.float64) ** 2 / (det.power_constant * cos * overlap)


def triangle_reflectivity(triangle_of_point: np.ndarray, rho: np.ndarray, triangles: int,
                          centroids: np.ndarray | None = None,
                          range_m: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray | None, dict]:  # fmt: skip
    """Per-triangle rho (T,) from the points' ``rho`` and their nearest triangle, the mean of the points'
    ``range_m`` (m) per triangle (None without it: the range the reflectivity was measured from, in the same
    mean: exp(2 alpha R) of the mean range undoes the loss of an air of extinction alpha in the geometric mean),
    and a summary (median, share of points clipped at the range's ends, triangles without points). A triangle
    without points takes the values of the nearest triangle with points (by ``centroids`` (T, 3) m), else the
    median of all points."""
    lo, hi = REFLECTIVITY_RANGE
    log_rho = np.log(np.clip(rho, lo, hi))
    counts = np.bincount(triangle_of_point, minlength=triangles)
    has = counts > 0
    source = np.arange(triangles)
    if centroids is not None and has.any() and not has.all():
        from scipy.spatial import cKDTree

        source[~has] = np.flatnonzero(has)[cKDTree(centroids[has]).query(centroids[~has], workers=2)[1]]

    def mean(values: np.ndarray) -> np.ndarray:
        fill = float(np.median(values)) if len(values) else 0.0
        sums = np.bincount(triangle_of_point, weights=values, minlength=triangles)
        return np.where(counts > 0, sums / np.maximum(counts, 1), fill)[source]

    fill = float(np.median(log_rho)) if len(log_rho) else np.log(0.1)
    out = np.exp(mean(log_rho)) if len(log_rho) else np.full(triangles, np.exp(fill))
    ranges = None if range_m is None else mean(np.asarray(range_m, dtype=np.float64))
    summary = {"median": float(np.exp(fill)), "clipped_high": float(np.mean(rho > hi)) if len(rho) else 0.0,
               "clipped_low": float(np.mean(rho < lo)) if len(rho) else 0.0,
               "triangles_without_points": int(np.count_nonzero(counts == 0))}  # fmt: skip
    return out, ranges, summary
