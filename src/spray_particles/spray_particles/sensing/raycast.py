"""Exact ray-sphere intersection for many small spheres against a batch of sub-rays.

Broad phase: each sphere is projected into the angular grid of the rays (azimuth,
elevation seen from the batch's mean origin); the rays are binned by a pseudo-angle of their
azimuth (:func:`_pseudo_angle`: one division instead of an arctangent, monotone in the azimuth;
a counting sort into ``AZIMUTH_BINS`` x ``Z_BINS`` cells, the second by the ray's z, the sine of
its elevation) and each sphere takes the rays of the cells its angular radius (widened by the
spread of the ray origins) touches, then those within its elevation span (compared as sines). Narrow phase: the perpendicular distance of
the sphere centre from each candidate ray, in float64 (a float32 ray-sphere test loses
centimetre spheres at 50 m). The hits come out ordered by window row, then by the ray's bin of
``AZIMUTH_BINS`` equal azimuth steps, then by ray (:func:`_in_azimuth_order`), so the order does
not depend on the binning. All frames are the caller's (world); m.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import NamedTuple

import numba
import numpy as np


@dataclass
class SphereHits:
    ray: np.ndarray  # (H,) index into the flattened rays
    sphere: np.ndarray  # (H,) index into the spheres
    range_m: np.ndarray  # (H,) distance from the ray origin to the entry point (m)
    cos_incidence: np.ndarray  # (H,) cosine between the ray and the sphere normal at entry (spheres)
    half_chord_m: np.ndarray  # (H,) half the length of the ray inside the sphere or ellipsoid (m)


class Rays(NamedTuple):
    """A batch of rays (world frame)."""

    origins: np.ndarray  # (R, 3) m
    directions: np.ndarray  # (R, 3) unit
    max_range: np.ndarray  # (R,) m, a hit must enter before it


class RayTable(NamedTuple):
    """The rays counting-sorted into cells of ``n_az`` pseudo-angle bins x ``n_z`` z bins (:func:`_bin_rays`),
    over the azimuth bins ``first_bin .. first_bin + bins - 1`` they occupy; cell ``(b - first_bin) * n_z + z``."""

    order: np.ndarray  # (R,) ray indices in cell order
    cell_start: np.ndarray  # (bins * n_z + 1,) first position of each cell in ``order``
    z_sorted: np.ndarray  # (R,) the rays' z (the sine of their elevation) in that order
    first_bin: int
    bins: int
    n_az: int
    n_z: int


class NearSpheres(NamedTuple):
    """The spheres that can lie within reach of the rays (:func:`_near_spheres`), seen from the rays' mean
    origin."""

    idx: np.ndarray  # (m,) index into all spheres
    near: np.ndarray  # (m,) m, centre distance beyond the origins' spread
    radius: np.ndarray  # (m,) m
    span: np.ndarray  # (m,) rad, angular radius seen from the origins
    azimuth: np.ndarray  # (m,) rad, of the centre
    elevation: np.ndarray  # (m,) rad, of the centre


class Windows(NamedTuple):
    """The azimuth windows of the near spheres in the rays' table (:func:`_cast`): one row per window
    (a window crossing +-pi is two rows) and each near sphere's z span."""

    sphere: np.ndarray  # (rows,) index into the near spheres
    b_first: np.ndarray  # (rows,) first azimuth bin of the table (from first_bin on)
    b_last: np.ndarray  # (rows,) last azimuth bin
    zb_first: np.ndarray  # (m,) first z bin
    zb_last: np.ndarray  # (m,) last z bin
    z_lo: np.ndarray  # (m,) lowest sine of elevation
    z_hi: np.ndarray  # (m,) highest sine of elevation


def _empty() -> SphereHits:
    z = np.zeros(0)
    return SphereHits(np.zeros(0, np.int64), np.zeros(0, np.int64), z, z, z)


def sphere_hits(origins: np.ndarray, directions: np.ndarray, max_range: np.ndarray, centres: np.ndarray,
                radius: float | np.ndarray, vertical: np.ndarray | None = None) -> SphereHits:  # fmt: skip
    """Every (ray, sphere) pair where ray i (origin (R, 3), unit direction (R, 3)) enters sphere j
    (centre (P, 3), ``radius`` m, one for all or one per sphere (P,)) at a range in (0, max_range[i]), or
    starts inside it (entry 0, the chord to the exit: a sensor inside a drop packet sees its optical depth).
    With ``vertical`` (P,) m <= radius the spheres are ellipsoids of that semi-axis along z."""
    if not len(centres) or not len(directions):
        return _empty()
    origins = np.asarray(origins, dtype=np.float64)
    directions = np.asarray(directions, dtype=np.float64)
    centres = np.asarray(centres, dtype=np.float64)
    radius = np.broadcast_to(np.asarray(radius, dtype=np.float64), (len(centres),))
    z_scale = radius / np.asarray(vertical, dtype=np.float64) if vertical is not None else np.ones(len(centres))
    ref, spread = origin_spread(origins)
    q = centres - ref
    dist = np.sqrt(np.einsum("nk,nk->n", q, q))
    idx, q, dist, near, rad, span_sine, el_sine = _near_spheres(q, dist, radius, spread, float(np.max(max_range)))
    if not len(idx):
        return _empty()
    # numpy's own arcsin / arctan2 (the kernels use only IEEE-exact operations and libm's cos)
    spheres = NearSpheres(idx, near, rad, np.arcsin(span_sine), np.arctan2(q[:, 1], q[:, 0]), np.arcsin(el_sine))
    table = _bin_rays(directions, AZIMUTH_BINS, Z_BINS)
    rays = Rays(origins, directions, max_range)
    row, ray, sphere, entry, cos_incidence, half_chord = _cast(spheres, table, centres, z_scale, rays)
    if not len(ray):
        return _empty()
    keep = _in_azimuth_order(row, ray, directions, AZIMUTH_BINS)
    return SphereHits(ray[keep], sphere[keep], entry[keep], cos_incidence[keep], half_chord[keep])


AZIMUTH_BINS = 4096  # 1.5 mrad each (as equal steps; the pseudo-angle's bins are 1-2 mrad)
Z_BINS = 64  # of the sine of the elevation over [-1, 1]: 1.8 deg at the horizon


@numba.njit(cache=True, nogil=True)
def origin_spread(origins):
    """Mean of the ray origins (3,) and the largest distance of an origin from it (m)."""
    ref = np.zeros(3)
    for i in range(origins.shape[0]):
        for k in range(3):
            ref[k] += origins[i, k]
    ref /= max(origins.shape[0], 1)
    far = 0.0
    for i in range(origins.shape[0]):
        d = (origins[i, 0] - ref[0]) ** 2 + (origins[i, 1] - ref[1]) ** 2 + (origins[i, 2] - ref[2]) ** 2
        far = max(far, d)
    return ref, math.sqrt(far)


@numba.njit(cache=True, inline="always")
def _pseudo_angle(x, y):
    """A monotone stand-in for atan2(y, x) + pi in [0, 4) (the "diamond angle" of (-x, -y)): 0 at
    azimuth -pi, 2 at 0, rising with the azimuth to 4 at +pi; one division, no arctangent."""
    u, v = -x, -y
    if v >= 0.0:
        return v / (u + v) if u >= 0.0 else 1.0 - u / (v - u)
    return 2.0 - v / (-u - v) if u < 0.0 else 3.0 + u / (u - v)


@numba.njit(cache=True, inline="always")
def _pseudo_bin(x, y, n_bins):
    """Bin (0..n_bins-1) of the direction (x, y)'s pseudo-angle."""
    if x == 0.0 and y == 0.0:
        return 0
    return min(max(int(math.floor(_pseudo_angle(x, y) * (n_bins / 4.0))), 0), n_bins - 1)


@numba.njit(cache=True, inline="always")
def _z_bin(z, n_z):
    """Bin (0..n_z-1) of a sine of elevation z in [-1, 1]."""
    return min(max(int(math.floor((z + 1.0) * (0.5 * n_z))), 0), n_z - 1)


@numba.njit(cache=True, nogil=True)
def _bin_rays(directions, n_az, n_z):
    """Counting sort of the rays by cell (pseudo-angle bin x z bin, row-major) over the azimuth bins they
    occupy, ``first``..``first + span - 1``: a :class:`RayTable` of the ray order (R,), the first position of
    each cell in it (span * n_z + 1,; cell ``(b - first) * n_z + z``), the rays' z (the sine of their
    elevation) in that order, ``first``, ``span``, ``n_az`` and ``n_z``. A batch of columns spans a slice of
    the circle (OS1-128's 10 ms: 36 deg), so its table is that slice's, not the circle's 262 144 cells."""
    n = directions.shape[0]
    ray_bin = np.empty(n, np.int64)
    first, last = n_az, -1
    for i in range(n):
        b = _pseudo_bin(directions[i, 0], directions[i, 1], n_az)
        ray_bin[i] = b
        first, last = min(first, b), max(last, b)
    span = max(last - first + 1, 0)
    first = min(first, n_az - 1)
    ray_cell = np.empty(n, np.int64)
    start = np.zeros(span * n_z + 1, np.int64)
    for i in range(n):
        c = (ray_bin[i] - first) * n_z + _z_bin(directions[i, 2], n_z)
        ray_cell[i] = c
        start[c + 1] += 1
    for c in range(span * n_z):
        start[c + 1] += start[c]
    fill = start[:-1].copy()
    order = np.empty(n, np.int64)
    z_sorted = np.empty(n)
    for i in range(n):
        k = fill[ray_cell[i]]
        order[k] = i
        z_sorted[k] = directions[i, 2]
        fill[ray_cell[i]] += 1
    return RayTable(order, start, z_sorted, first, span, n_az, n_z)


#: Longest row sorted by insertion (a sphere's hits are a few hundred; one around the sensor takes every ray, whose
#: pseudo-angle and z bins mix thousands of rays out of this order)
INSERTION_SORT_MAX = 4096


@numba.njit(cache=True, nogil=True)
def _in_azimuth_order(row, ray, directions, n_bins):
    """Indices that put the hits in (row, azimuth bin, ray) order, the order of a scan over rays sorted into
    ``n_bins`` equal azimuth bins over [-pi, pi). The narrow phase lists the hits row by row, rows ascending, and
    a ray once per row: each row's hits are sorted on their own (by bin, then ray; no ties), the order of a sort
    of all hits by that key. Arctangents once per ray hit, not for every ray or hit."""
    n_rays = directions.shape[0]
    ray_bin = np.full(n_rays, -1, np.int64)
    n = row.shape[0]
    key = np.empty(n, np.int64)
    for h in range(n):
        i = ray[h]
        if ray_bin[i] < 0:
            a = math.atan2(directions[i, 1], directions[i, 0])
            ray_bin[i] = min(max(int(math.floor((a + math.pi) * (n_bins / (2.0 * math.pi)))), 0), n_bins - 1)
        key[h] = ray_bin[i] * n_rays + i
    out = np.empty(n, np.int64)
    h0 = 0
    while h0 < n:
        h1 = h0 + 1
        while h1 < n and row[h1] == row[h0]:
            h1 += 1
        if h1 - h0 > INSERTION_SORT_MAX:
            part = np.argsort(key[h0:h1])
            for k in range(h1 - h0):
                out[h0 + k] = h0 + part[k]
        else:  # insertion sort: the narrow phase's order (pseudo-angle, z, ray) is nearly this one
            for h in range(h0, h1):
                k = h
                while k > h0 and key[out[k - 1]] > key[h]:
                    out[k] = out[k - 1]
                    k -= 1
                out[k] = h
        h0 = h1
    return out


@numba.njit(cache=True, nogil=True)
def _near_spheres(q, dist, radius, spread, max_range):
    """The spheres (centre ``q`` from the rays' mean origin, m; ``dist`` its length) that can lie within
    ``max_range`` of a ray origin: their indices, q, dist, distance beyond the origins' ``spread``
    (near), radius, the sine of their angular radius seen from the origins and of their elevation."""
    n = q.shape[0]
    keep = np.empty(n, np.int64)
    m = 0
    for i in range(n):
        if dist[i] - spread < max_range + radius[i]:
            keep[m] = i
            m += 1
    idx = keep[:m].copy()
    q_k, dist_k, near, rad = np.empty((m, 3)), np.empty(m), np.empty(m), np.empty(m)
    span_sine, el_sine = np.empty(m), np.empty(m)
    for j in range(m):
        i = idx[j]
        for k in range(3):
            q_k[j, k] = q[i, k]
        dist_k[j], near[j], rad[j] = dist[i], dist[i] - spread, radius[i]
        span_sine[j] = min(max((rad[j] + spread) / max(near[j], 1e-9), 0.0), 1.0)
        el_sine[j] = min(max(q[i, 2] / max(dist[i], 1e-12), -1.0), 1.0)
    return idx, q_k, dist_k, near, rad, span_sine, el_sine


@numba.njit(cache=True, inline="always")
def _azimuth_bin(azimuth, n_bins):
    """Pseudo-angle bin (0..n_bins-1, as :func:`_bin_rays`) of an azimuth in [-pi, pi] (rad)."""
    if azimuth >= np.pi:
        return n_bins - 1
    return _pseudo_bin(math.cos(azimuth), math.sin(azimuth), n_bins)


@numba.njit(cache=True, nogil=True)
def _cast(spheres, table, centres, z_scale, rays):
    """Azimuth windows of the near ``spheres`` (:class:`NearSpheres`; their angular radius ``span`` widened by
    1e-4 and 1e-9 rad, over cos(elevation); windows crossing +-pi split into two rows, listed after all first
    rows; a sphere around the origins gets the full circle once) in the ray ``table`` (:class:`RayTable`), then
    the narrow phase over each window's ``rays`` (:class:`Rays`; see :func:`_narrow_phase`). Returns (window row,
    ray, sphere, entry range, cos incidence, half chord)."""
    idx, near, rad, span_arcsin, az_p, el_p = (spheres.idx, spheres.near, spheres.radius, spheres.span,
                                               spheres.azimuth, spheres.elevation)  # fmt: skip
    cell_start, first_bin, bins = table.cell_start, table.first_bin, table.bins
    m = idx.shape[0]
    span = np.empty(m)
    lo_a, hi_a = np.empty(m), np.empty(m)
    full = np.empty(m, np.bool_)
    n_rows = m
    for j in range(m):
        s = span_arcsin[j] if near[j] > rad[j] + 1e-9 else np.pi  # inside the sphere: all around
        span[j] = s * 1.0001 + 1e-9
        cos_el = math.cos(min(abs(el_p[j]) + span[j], 0.5 * np.pi))
        half_w = min(span[j] / max(cos_el, 1e-6), np.pi) if cos_el > 1e-6 else np.pi
        lo_a[j], hi_a[j] = az_p[j] - half_w, az_p[j] + half_w
        full[j] = half_w >= np.pi
        n_rows += (lo_a[j] < -np.pi) + (hi_a[j] > np.pi)
    rp = np.empty(n_rows, np.int64)
    rlo, rhi = np.empty(n_rows), np.empty(n_rows)
    for j in range(m):
        rp[j], rlo[j], rhi[j] = j, max(lo_a[j], -np.pi), min(hi_a[j], np.pi)
    r = m
    for j in range(m):
        if lo_a[j] < -np.pi:
            rp[r], rlo[r], rhi[r] = j, lo_a[j] + 2 * np.pi, np.pi
            r += 1
    for j in range(m):
        if hi_a[j] > np.pi:
            rp[r], rlo[r], rhi[r] = j, -np.pi, hi_a[j] - 2 * np.pi
            r += 1
    n_az = table.n_az
    n_z = table.n_z
    b_first, b_last = np.empty(n_rows, np.int64), np.empty(n_rows, np.int64)
    z_lo, z_hi = np.empty(m), np.empty(m)
    zb_first, zb_last = np.empty(m, np.int64), np.empty(m, np.int64)
    for j in range(m):
        z_lo[j] = math.sin(max(el_p[j] - span[j], -0.5 * np.pi))
        z_hi[j] = math.sin(min(el_p[j] + span[j], 0.5 * np.pi))
        zb_first[j], zb_last[j] = _z_bin(z_lo[j], n_z), _z_bin(z_hi[j], n_z)
    room = 0
    for r in range(n_rows):
        p = rp[r]
        if full[p]:
            b_first[r], b_last[r] = (0, n_az - 1) if r < m else (0, -1)
        else:
            b_first[r], b_last[r] = _azimuth_bin(rlo[r], n_az), _azimuth_bin(rhi[r], n_az)
        # in the rays' table (:func:`_bin_rays`): the bins no ray occupies hold none
        b_first[r], b_last[r] = max(b_first[r], first_bin) - first_bin, min(b_last[r], first_bin + bins - 1) - first_bin
        for b in range(b_first[r], b_last[r] + 1):  # a ray is a candidate of a row at most once: room for every hit
            room += cell_start[b * n_z + zb_last[p] + 1] - cell_start[b * n_z + zb_first[p]]
    out = (np.empty(room, np.int64), np.empty(room, np.int64), np.empty(room), np.empty(room))
    n = _narrow_phase(Windows(rp, b_first, b_last, zb_first, zb_last, z_lo, z_hi), table, spheres, centres, z_scale,
                      rays, out)  # fmt: skip
    row, ray, entry, half_chord = out[0][:n], out[1][:n], out[2][:n], out[3][:n]
    sphere, cos_incidence = np.empty(n, np.int64), np.empty(n)
    for h in range(n):
        sphere[h] = idx[rp[row[h]]]
        cos_incidence[h] = half_chord[h] / rad[rp[row[h]]]
    return row, ray, sphere, entry, cos_incidence, half_chord


@numba.njit(cache=True, inline="always")
def _narrow_phase(windows, table, spheres, centres, z_scale, rays, out):
    """For each window row (:class:`Windows`; sphere ``idx[rp[j]]``'s azimuth bins ``b_first[j]..b_last[j]`` of
    the rays' ``table`` and its z bins, over the rays sorted into cells, ``order``, whose z are ``z_sorted``):
    the ``rays`` within its z span ``z_lo..z_hi`` that pass through it (z stretched by ``z_scale`` = radius /
    vertical semi-axis, so ellipsoids become spheres; rays are solved along their own unit length) with the
    entry in (0, max_range); a ray that starts inside enters at 0 with the chord from its origin to the exit.
    ``spheres``: :class:`NearSpheres`, ``centres`` (P, 3) m of all spheres. Fills ``out`` = (row, ray, entry
    range, half chord) and returns the count."""
    rp, b_first, b_last, zb_first, zb_last, z_lo, z_hi = windows
    n_z, cell_start, order, z_sorted = table.n_z, table.cell_start, table.order, table.z_sorted
    idx, radius = spheres.idx, spheres.radius
    origins, directions, max_range = rays
    n = 0
    for j in range(len(b_first)):
        p = rp[j]
        c = idx[p]
        cx, cy, cz, r, s = centres[c, 0], centres[c, 1], centres[c, 2], radius[p], z_scale[c]
        lo, hi = z_lo[p], z_hi[p]
        for b in range(b_first[j], b_last[j] + 1):
            for k in range(cell_start[b * n_z + zb_first[p]], cell_start[b * n_z + zb_last[p] + 1]):
                if z_sorted[k] < lo or z_sorted[k] > hi:
                    continue
                i = order[k]
                vx, vy, vz = cx - origins[i, 0], cy - origins[i, 1], (cz - origins[i, 2]) * s
                dx, dy, dz = directions[i, 0], directions[i, 1], directions[i, 2] * s
                a = dx * dx + dy * dy + dz * dz
                t = (vx * dx + vy * dy + vz * dz) / a
                wx, wy, wz = vx - t * dx, vy - t * dy, vz - t * dz
                perp2 = wx * wx + wy * wy + wz * wz
                if perp2 >= r * r:
                    continue
                half_chord = math.sqrt((r * r - perp2) / a)
                entry = t - half_chord
                if entry <= 0.0:  # starts inside (the chord from the origin to the exit) or behind the origin
                    if t + half_chord <= 0.0:
                        continue
                    entry, half_chord = 0.0, 0.5 * (t + half_chord)
                if entry >= max_range[i]:
                    continue
                out[0][n], out[1][n], out[2][n], out[3][n] = j, i, entry, half_chord
                n += 1
    return n


@numba.njit(cache=True, nogil=True)
def rays_in_cone(directions, axis, cos_half, mask):
    """Marks in ``mask`` (R,) bool the rays of ``directions`` (R, 3) unit that lie within the cone of unit ``axis``
    (3,) whose half-angle has the cosine ``cos_half``; returns whether any does. (A broad phase: the caller widens
    the cone beyond what its spheres need, so a ray on its edge decides nothing.)"""
    found = False
    a0, a1, a2 = axis[0], axis[1], axis[2]
    for i in range(directions.shape[0]):
        if directions[i, 0] * a0 + directions[i, 1] * a1 + directions[i, 2] * a2 >= cos_half:
            mask[i] = True
            found = True
    return found


@numba.njit(cache=True, nogil=True)
def group_bounds(centres, radius, group, n_groups):
    """Per group (e.g. the emitting vehicle) of spheres: the lower and upper corners (G, 3) of its
    centres' box and its largest radius (G,), -1 for a group without spheres."""
    lo = np.full((n_groups, 3), np.inf)
    hi = np.full((n_groups, 3), -np.inf)
    largest = np.full(n_groups, -1.0)
    for i in range(centres.shape[0]):
        g = group[i]
        for k in range(3):
            lo[g, k] = min(lo[g, k], centres[i, k])
            hi[g, k] = max(hi[g, k], centres[i, k])
        largest[g] = max(largest[g], radius[i])
    return lo, hi, largest


@numba.njit(cache=True, nogil=True)
def candidates(ray_mask, chosen, group, beam_origins, directions, distance, n_sub):
    """The rays of ``ray_mask`` (indices into the flattened (beam, sub-ray) directions) with their
    beam's origin, direction and scene range (inf -> 1e9 m), and the spheres whose ``group`` is
    ``chosen``: (rays, spheres, origins, directions, max_range)."""
    n = 0
    for i in range(ray_mask.shape[0]):
        n += ray_mask[i]
    rays = np.empty(n, np.int64)
    origins, dirs, max_range = np.empty((n, 3)), np.empty((n, 3)), np.empty(n)
    j = 0
    for i in range(ray_mask.shape[0]):
        if ray_mask[i]:
            rays[j] = i
            for k in range(3):
                origins[j, k] = beam_origins[i // n_sub, k]
                dirs[j, k] = directions[i, k]
            d = distance[i]
            max_range[j] = d if np.isfinite(d) else 1e9
            j += 1
    m = 0
    for i in range(group.shape[0]):
        m += chosen[group[i]]
    spheres = np.empty(m, np.int64)
    m = 0
    for i in range(group.shape[0]):
        if chosen[group[i]]:
            spheres[m] = i
            m += 1
    return rays, spheres, origins, dirs, max_range
