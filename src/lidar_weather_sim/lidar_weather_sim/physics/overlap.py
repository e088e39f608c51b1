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


def defocused_overlap(range_m: np.ndarray, separation_m: float, divergence_rad: float, fov_rad: float,
                      tx_radius_m: float = 0.0, rx_radius_m: float = 0.0, rings: int = 48,
                      spokes: int = 96) -> np.ndarray:  # fmt: skip
    """O(r) in [0, 1] at ``range_m`` (m) with the receiver's aperture imaged out of focus (the geometric form
    factor, Halldorsson & Langerholc 1978; Stelmaszczyk et al. 2005, Appl. Opt. 44, 1323).

    The receiver lens (aperture radius ``rx_radius_m``) is focused at infinity and its field stop, on its axis,
    accepts ``fov_rad`` (full angle). A ray from a point of the beam at lateral distance p from the receiver
    axis, range r, through the aperture point a lands on the focal plane at angle (p - a) / r: the point's
    light is spread over a blur disc of angular radius a_r / r, and the share of it the stop accepts is the
    share of the aperture within r tan(fov / 2) of p. O(r) is that share averaged over the beam's uniform
    disc (radius ``tx_radius_m + r tan(divergence / 2)``, centre ``separation_m`` off the receiver axis),
    by an equal-area polar quadrature of ``rings`` x ``spokes`` points. Without an aperture (``rx_radius_m``
    0) it is :func:`biaxial_overlap`'s; with one, :func:`biaxial_overlap` counts every point within
    ``rx_radius_m + r tan(fov / 2)`` as wholly seen, which overstates O where the blur disc is not on the stop.
    """
    r = np.maximum(np.atleast_1d(np.asarray(range_m, np.float64)), 0.0)
    beam = tx_radius_m + r * np.tan(0.5 * divergence_rad)  # (N,) m
    view = r * np.tan(0.5 * fov_rad)  # the stop's radius at range r, around each beam point (m)
    out = np.zeros(r.shape)
    full = separation_m + beam + rx_radius_m <= view  # every point sees the whole aperture
    out[full] = 1.0
    part = ~full & (separation_m - beam - rx_radius_m < view)  # else no point sees any of it
    if part.any():
        rho = np.sqrt((np.arange(rings) + 0.5) / rings)  # equal-area rings of the unit disc
        phi = 2.0 * np.pi * (np.arange(spokes) + 0.5) / spokes
        ux, uy = (rho[:, None] * np.cos(phi)).ravel(), (rho[:, None] * np.sin(phi)).ravel()
        b = beam[part, None]
        p = np.hypot(separation_m + b * ux, b * uy)  # (n, M) lateral distance of each beam point (m)
        out[part] = point_share("defocus", p, r[part, None], fov_rad, rx_radius_m).mean(axis=1)
    return np.clip(out, 0.0, 1.0).reshape(np.shape(range_m))


#: the overlap models of a profile's optics (``optics.overlap_model``): the receiver's field of view as a cone
#: from its whole aperture (:func:`biaxial_overlap`) or the aperture's blur on the field stop (:func:`defocused_overlap`)
OVERLAP_MODELS = {"cone": biaxial_overlap, "defocus": defocused_overlap}


def point_share(model: str, lateral_m: np.ndarray, range_m: np.ndarray, fov_rad: float,
                rx_radius_m: float) -> np.ndarray:  # fmt: skip
    """Share (0-1) of the light a point of the beam sends back that reaches the detector, the point at ``lateral_m``
    (m) from the receiver's axis and ``range_m`` (m) out: ``cone``: 1 within ``rx_radius_m + r tan(fov / 2)``,
    else 0; ``defocus``: the share of the aperture within ``r tan(fov / 2)`` of it (:func:`defocused_overlap`).
    Averaged over the beam's disc it is the model's O(r)."""
    p, r = np.broadcast_arrays(np.asarray(lateral_m, np.float64), np.asarray(range_m, np.float64))
    view = r * np.tan(0.5 * fov_rad)
    if model == "cone":
        return (p <= rx_radius_m + view).astype(np.float64)
    if rx_radius_m <= 0:
        return (p <= view).astype(np.float64)
    aperture = np.full(p.shape, rx_radius_m)
    return np.clip(circle_overlap_area(aperture, view, p) / (np.pi * rx_radius_m**2), 0.0, 1.0)
