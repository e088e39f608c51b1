"""Exact ray-sphere intersection for many small spheres against a batch of sub-rays.

Broad phase: each sphere is projected into the angular grid of the rays (azimuth,
elevation seen from the batch's mean origin); the rays are sorted by azimuth and
each sphere takes the rays inside its angular radius (widened by the spread of the
ray origins) with two binary searches. Narrow phase: the perpendicular distance of
the sphere centre from each candidate ray, in float64 (a float32 ray-sphere test
loses centimetre spheres at 50 m). All frames are the caller's (world); m.
"""

from __future__ import annotations

from dataclasses import dataclass

import math

import numba
import numpy as np


@dataclass
class SphereHits:
    ray: np.ndarray  # (H,) index into the flattened rays
    sphere: np.ndarray  # (H,) index into the spheres
    range_m: np.ndarray  # (H,) distance from the ray origin to the entry point (m)
    cos_incidence: np.ndarray  # (H,) cosine between the ray and the sphere normal at entry


def _empty() -> SphereHits:
    z = np.zeros(0)
    return SphereHits(np.zeros(0, np.int64), np.zeros(0, np.int64), z, z)


def sphere_hits(origins: np.ndarray, directions: np.ndarray, max_range: np.ndarray, centres: np.ndarray,
                radius: float | np.ndarray) -> SphereHits:  # fmt: skip
    """Every (ray, sphere) pair where ray i (origin (R, 3), unit direction (R, 3)) enters sphere j
    (centre (P, 3), ``radius`` m, one for all or one per sphere (P,)) at a range in (0, max_range[i])."""
    if not len(centres) or not len(directions):
        return _empty()
    origins = np.asarray(origins, dtype=np.float64)
    directions = np.asarray(directions, dtype=np.float64)
    centres = np.asarray(centres, dtype=np.float64)
    radius = np.broadcast_to(np.asarray(radius, dtype=np.float64), (len(centres),))
    ref = origins.mean(axis=0)
    spread = float(np.sqrt(np.max(np.sum((origins - ref) ** 2, axis=1))))
    q = centres - ref
    dist = np.sqrt(np.einsum("nk,nk->n", q, q))
    near = dist - spread
    keep = near < np.max(max_range) + radius
    if not keep.any():
        return _empty()
    idx = np.flatnonzero(keep)
    q, dist, near, rad = q[keep], dist[keep], near[keep], radius[keep]
    span = np.where(near > rad + 1e-9, np.arcsin(np.clip((rad + spread) / np.maximum(near, 1e-9), 0, 1)), np.pi)
    span = span * 1.0001 + 1e-9
    az_p = np.arctan2(q[:, 1], q[:, 0])
    el_p = np.arcsin(np.clip(q[:, 2] / np.maximum(dist, 1e-12), -1, 1))
    cos_el = np.cos(np.minimum(np.abs(el_p) + span, 0.5 * np.pi))
    half_w = np.where(cos_el > 1e-6, np.minimum(span / np.maximum(cos_el, 1e-6), np.pi), np.pi)

    az_r = np.arctan2(directions[:, 1], directions[:, 0])
    el_r = np.arcsin(np.clip(directions[:, 2], -1, 1))
    order = np.argsort(az_r, kind="stable")
    az_sorted = az_r[order]
    # azimuth windows, split where they wrap around +-pi
    lo_a, hi_a = az_p - half_w, az_p + half_w
    rows_p = [np.arange(len(az_p))]
    rows_lo, rows_hi = [np.maximum(lo_a, -np.pi)], [np.minimum(hi_a, np.pi)]
    wrap_lo = lo_a < -np.pi
    rows_p.append(np.flatnonzero(wrap_lo)); rows_lo.append(lo_a[wrap_lo] + 2 * np.pi); rows_hi.append(np.full(wrap_lo.sum(), np.pi))  # noqa: E702
    wrap_hi = hi_a > np.pi
    rows_p.append(np.flatnonzero(wrap_hi)); rows_lo.append(np.full(wrap_hi.sum(), -np.pi)); rows_hi.append(hi_a[wrap_hi] - 2 * np.pi)  # noqa: E702
    full = half_w >= np.pi
    rp, rlo, rhi = np.concatenate(rows_p), np.concatenate(rows_lo), np.concatenate(rows_hi)
    rlo = np.where(full[rp], -np.inf, rlo)
    rhi = np.where(full[rp], np.inf, rhi)
    first = np.searchsorted(az_sorted, rlo, side="left")
    last = np.searchsorted(az_sorted, rhi, side="right")
    if np.any(full):  # a full window must not be counted twice by the wrap rows
        dup = full[rp] & (np.arange(len(rp)) >= len(az_p))
        last = np.where(dup, first, last)
    sphere = idx[rp]
    args = (first, last, rp, order, el_r, el_p, span, centres[sphere], rad[rp], origins, directions, max_range)
    n_hits = _narrow_phase(*args, None)
    if not n_hits:
        return _empty()
    out = (np.empty(n_hits, np.int64), np.empty(n_hits, np.int64), np.empty(n_hits), np.empty(n_hits))
    _narrow_phase(*args, out)
    row, ray, entry, cos_incidence = out
    return SphereHits(ray, sphere[row], entry, cos_incidence)


@numba.njit(cache=True)
def _narrow_phase(first, last, rp, order, el_r, el_p, span, centre, radius, origins, directions, max_range, out):
    """For each window row (a sphere's azimuth window over the sorted rays ``order[first:last]``): the
    rays within its elevation span whose perpendicular distance from the centre is below the radius and
    whose entry lies in (0, max_range). Counts the hits when ``out`` is None, else fills ``out`` = (row,
    ray, entry range, cos incidence) and returns the count."""
    n = 0
    for j in range(len(first)):
        p = rp[j]
        cx, cy, cz, r = centre[j, 0], centre[j, 1], centre[j, 2], radius[j]
        for k in range(first[j], last[j]):
            i = order[k]
            if abs(el_r[i] - el_p[p]) > span[p]:
                continue
            vx, vy, vz = cx - origins[i, 0], cy - origins[i, 1], cz - origins[i, 2]
            dx, dy, dz = directions[i, 0], directions[i, 1], directions[i, 2]
            t = vx * dx + vy * dy + vz * dz
            wx, wy, wz = vx - t * dx, vy - t * dy, vz - t * dz
            perp2 = wx * wx + wy * wy + wz * wz
            if perp2 >= r * r:
                continue
            half_chord = math.sqrt(r * r - perp2)
            entry = t - half_chord
            if entry <= 0.0 or entry >= max_range[i]:
                continue
            if out is not None:
                out[0][n], out[1][n], out[2][n], out[3][n] = j, i, entry, half_chord / r
            n += 1
    return n
