"""Geometric overlap O(r) of a biaxial LiDAR: the share of the transmitted beam's cross-section that lies
inside the receiver's field of view at range r.

Model (the geometric overlap of two cones with parallel axes, e.g. Measures 1984, "Laser remote sensing",
sec. 7.2; Halldorsson & Langerholc 1978, Appl. Opt. 17, 240, in its uniform-beam limit): at range r the
beam is a disc of radius ``a_t + r tan(theta_t / 2)`` and the receiver sees a disc of radius
``a_r + r tan(theta_r / 2)`` whose centre is ``d`` (the lens separation) away. O(r) is the area of the
intersection over the beam's area: 0 while the discs are apart (r small), 1 once the receiver's disc
contains the beam's (r large, for theta_r > theta_t or a receiver aperture larger than ``d`` plus the beam's).
A uniform (top-hat) beam is assumed.
"""

from __future__ import annotations

import numpy as np


def circle_overlap_area(r1: np.ndarray, r2: np.ndarray, d: float | np.ndarray) -> np.ndarray:
    """Area (m^2) of the intersection of discs of radii ``r1``, ``r2`` (m) whose centres are ``d`` (m) apart."""
    r1, r2, d = np.broadcast_arrays(np.asarray(r1, np.float64), np.asarray(r2, np.float64), np.asarray(d, np.float64))
    out = np.zeros(r1.shape)
    apart = d >= r1 + r2
    inside = d <= np.abs(r1 - r2)
    out[inside] = np.pi * np.minimum(r1, r2)[inside] ** 2
    part = ~apart & ~inside
    a, b, c = r1[part], r2[part], d[part]
    u = np.clip((c * c + a * a - b * b) / (2 * c * a), -1.0, 1.0)
    v = np.clip((c * c + b * b - a * a) / (2 * c * b), -1.0, 1.0)
    k = np.sqrt(np.maximum((-c + a + b) * (c + a - b) * (c - a + b) * (c + a + b), 0.0))
    out[part] = a * a * np.arccos(u) + b * b * np.arccos(v) - 0.5 * k
    return out


def biaxial_overlap(range_m: np.ndarray, separation_m: float, divergence_rad: float, fov_rad: float,
                    tx_radius_m: float = 0.0, rx_radius_m: float = 0.0) -> np.ndarray:  # fmt: skip
    """O(r) in [0, 1] at ``range_m`` (m): beam of full divergence ``divergence_rad`` from an aperture of radius
    ``tx_radius_m``, receiver of full field of view ``fov_rad`` and aperture radius ``rx_radius_m``, optical
    axes parallel and ``separation_m`` apart (m)."""
    r = np.maximum(np.asarray(range_m, np.float64), 0.0)
    rt = tx_radius_m + r * np.tan(0.5 * divergence_rad)
    rr = rx_radius_m + r * np.tan(0.5 * fov_rad)
    area = np.pi * np.maximum(rt, 1e-12) ** 2
    return np.clip(circle_overlap_area(rt, rr, separation_m) / area, 0.0, 1.0)
