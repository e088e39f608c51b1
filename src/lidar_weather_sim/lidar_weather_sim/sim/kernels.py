"""The numba kernels of the frame pipeline (:mod:`lidar_weather_sim.sim.simulator`) and their wrappers.

Each kernel reproduces the numpy expression it replaces operation for operation (numpy's einsum adds
three products as (p0 + p2) + p1), so the clouds are bit for bit the same
(``src/lidar_weather_sim/test/test_sim_kernels.py`` checks each against its numpy form); the
occlusion (:func:`occluded_candidates`) sums each sub-ray's log transmissions on their own, not as
differences of one running sum over the batch, and is checked against a per-sub-ray loop. A wrapper
splits its batch into chunks of :data:`CHUNK_RAYS` rays run on all cores
(:mod:`lidar_weather_sim.core.workers`) and takes its large temporaries from a reused scratch store,
so the pipeline itself reads without buffer bookkeeping.
"""

from __future__ import annotations

import functools
from typing import NamedTuple

import numba
import numpy as np

from lidar_weather_sim.core import workers
from lidar_weather_sim.core.points import ReturnType
from lidar_weather_sim.core.scratch import allocator
from lidar_weather_sim.scene.raycast import TriangleTables
from lidar_weather_sim.sensor.echo import Candidates, beam_groups
from lidar_weather_sim.sensor.radiometry import intensity_byte, overlap_at, peak_amplitude_at, surface_reflectance_at

_LAST, _FIRST, _IDENTICAL, _SECOND = (int(r) for r in (ReturnType.LAST, ReturnType.FIRST, ReturnType.IDENTICAL,
                                                       ReturnType.SECOND))  # fmt: skip
#: Rays per chunk when a batch is shared between threads (:mod:`lidar_weather_sim.core.workers`).
CHUNK_RAYS = 32768


class SubrayHits(NamedTuple):
    """The scene hit of every sub-ray (N), flat, beam-major, as candidates."""

    range_m: np.ndarray  # (N,) float64 m, inf: a miss
    amplitude: np.ndarray  # (N,) float64, 0: none
    label: np.ndarray  # (N,) uint8
    object_id: np.ndarray  # (N,) uint32


class Scatterers(NamedTuple):
    """Scatterers of the batch (K), each on one sub-ray of its beam (the beams apart)."""

    subray: np.ndarray  # (K,) int64
    range_m: np.ndarray  # (K,) float64 m
    amplitude: np.ndarray  # (K,) float64
    label: np.ndarray  # (K,) uint8
    object_id: np.ndarray  # (K,) uint32
    occlusion: np.ndarray  # (K,) float64, 0-1: the share of the sub-ray's light it takes


class CastHits(NamedTuple):
    """The caster's nearest hit per sub-ray (N, flat), map frame
    (:class:`~lidar_weather_sim.scene.raycast.scene_caster.Hits`, cast with ``gather=False``)."""

    distance: np.ndarray  # (N,) float32 m, inf: a miss
    triangle: np.ndarray  # (N,) int64 static triangle, -1: an actor's hit or a miss
    normal: np.ndarray  # (N, 3) float32, actor hits only
    material: np.ndarray  # (N,) int32, actor hits only
    actor: np.ndarray  # (N,) int32 actor id (a row of Surfaces.actor_label), actor hits only
    object_id: np.ndarray  # (N,) uint32, actor hits only


class Surfaces(NamedTuple):
    """Per material (its last row: no material) and per actor, what a hit reflects and is labelled."""

    reflectivity: np.ndarray  # (M + 1,) float64
    retro: np.ndarray  # (M + 1,) float64
    material_label: np.ndarray  # (M + 1,) uint8
    actor_label: np.ndarray  # (max actor id + 1,) uint8


class Receiver(NamedTuple):
    """The LIDAR equation's sensor terms (:func:`~lidar_weather_sim.sensor.radiometry.peak_amplitude_at`)."""

    subray_weight: np.ndarray  # (S,) float64, each sub-ray's share of the beam's power
    power: float  # power constant C (noise units m^2): a full-beam hit's peak amplitude
    overlap_start: float  # m, biaxial overlap starts
    overlap_full: float  # m, full overlap


class KeptEchoes(NamedTuple):
    """The echoes of a batch (E) as :func:`fill_points` reads them, indexed by echo."""

    range_m: np.ndarray  # (E,) float64 m, with range noise
    beam: np.ndarray  # (E,) int64 beam of the batch (column-major: column x n_beams + beam)
    echo: np.ndarray  # (E,) uint8, 1-based within the beam
    epw_m: np.ndarray  # (E,) float64
    reported: np.ndarray  # (E,) uint8 return type (see select_returns); empty: return mode all


class ScanTables(NamedTuple):
    """Where a batch's beams point and when they fire: its columns (C) and active channels (B),
    and per (pattern column, channel) / channel / pattern column the scan pattern's tables."""

    columns: np.ndarray  # (C,) int64 pattern column of each batch column
    channels: np.ndarray  # (B,) channel of each beam of a column
    n_beams: int  # B
    cos_az: np.ndarray  # (columns, channels) float64
    sin_az: np.ndarray  # (columns, channels) float64
    azimuth: np.ndarray  # (columns, channels) float64 rad, wrapped
    cos_el: np.ndarray  # (channels,) float64
    sin_el: np.ndarray  # (channels,) float64
    elevation: np.ndarray  # (channels,) float64 rad
    stamp: np.ndarray  # (columns,) uint32 ns since the frame's start


class RegionEffects(NamedTuple):
    """The weather regions' effect per (beam, sub-ray) (N, S) of the batch, if ``active``."""

    active: bool
    reflectance_scale: np.ndarray  # (N, S) float64
    range_offset: np.ndarray  # (N, S) float64 m
    two_way: np.ndarray  # (N, S) float64 transmission


def occluded_candidates(surface, scatterers, n_beams, n_sub, scratch=None):
    """Every beam's candidates, grouped by beam, with each amplitude scaled by the two-way light the
    candidates in front of it on the same sub-ray leave: prod over nearer ones of (1 - occlusion)^2.

    ``surface``: the scene hit of every sub-ray as (range m (inf: a miss), amplitude (0: none), label,
    object id), flat (beam-major, ``n_sub`` per beam); it blocks its whole sub-ray behind it.
    ``scatterers``: (beam, sub-ray, range m, amplitude, label, object id, occlusion 0-1), any order.
    Within a beam the candidates keep their order (its sub-rays' hits in sub-ray order, then its
    scatterers as given); ties in range count the earlier one as in front. Returns (beam, range,
    amplitude, label, object id) of those left with light (amplitude > 0), beam-major, each chunk's
    from its first candidate's index on, and those runs as (starts, counts)."""
    sc_beam = np.ascontiguousarray(scatterers[0], np.int64)
    order, first = beam_groups(sc_beam, n_beams)
    size = n_beams * n_sub + len(sc_beam)
    new = allocator(scratch)
    out = Candidates(new("occ_beam", size, np.int64), new("occ_range", size, np.float64),
                     new("occ_amp", size, np.float64), new("occ_label", size, np.uint8),
                     new("occ_obj", size, np.uint32))  # fmt: skip
    surface = SubrayHits(*surface)
    sc = Scatterers(np.ascontiguousarray(scatterers[1], np.int64), *(np.ascontiguousarray(x, t) for x, t in
                    zip(scatterers[2:], (np.float64, np.float64, np.uint8, np.uint32, np.float64))))  # fmt: skip
    cuts = workers.bounds(n_beams, CHUNK_RAYS // max(n_sub, 1))
    counts = workers.run_chunks(
        lambda c: _occluded_run(surface, sc, order, first, n_sub, cuts[c], cuts[c + 1], out), len(cuts) - 1)
    starts = cuts[:-1] * n_sub + first[cuts[:-1]]
    return *out, (starts, np.array(counts, np.int64))


@numba.njit(cache=True, nogil=True)
def _occluded_run(surface, scatterers, order, first, n_sub, b0, b1, out):
    """Beams b0..b1 of :func:`occluded_candidates` (``surface``: :class:`SubrayHits`, ``scatterers``:
    :class:`Scatterers` in the beam ``order`` with each beam's ``first``), into ``out``
    (:class:`~lidar_weather_sim.sensor.echo.Candidates`); returns how many candidates were written."""
    s_range, s_amp, s_label, s_obj = surface
    sc_sub, sc_range, sc_amp, sc_label, sc_obj, sc_occ = scatterers
    out_beam, out_range, out_amp, out_label, out_obj = out
    most = n_sub
    for b in range(b0, b1):
        most = max(most, n_sub + first[b + 1] - first[b])
    rng = np.empty(most)
    amp = np.empty(most)
    log_t = np.empty(most)
    sub = np.empty(most, np.int64)
    idx = np.empty(most, np.int64)
    start = b0 * n_sub + first[b0]
    count = start
    for b in range(b0, b1):
        m = n_sub + first[b + 1] - first[b]
        for s in range(n_sub):  # the sub-rays' scene hits: opaque
            k = b * n_sub + s
            rng[s], amp[s], sub[s], log_t[s] = s_range[k], s_amp[k], s, 2.0 * np.log(1e-30)
        for q in range(n_sub, m):
            i = order[first[b] + q - n_sub]
            occ = min(max(sc_occ[i], 0.0), 1.0)
            rng[q], amp[q], sub[q], log_t[q] = sc_range[i], sc_amp[i], sc_sub[i], 2.0 * np.log(max(1.0 - occ, 1e-30))
        if m > n_sub:  # scatterers: order by (sub-ray, range), stable, NaN last, and scale by what is in front
            for q in range(m):
                p = q
                while p > 0:
                    j = idx[p - 1]
                    if sub[j] < sub[q] or (sub[j] == sub[q] and not (rng[j] > rng[q] or (np.isnan(rng[j])
                                                                                          and not np.isnan(rng[q])))):
                        break
                    idx[p] = j
                    p -= 1
                idx[p] = q
            before = 0.0
            for p in range(m):
                q = idx[p]
                if p > 0 and sub[idx[p - 1]] != sub[q]:
                    before = 0.0
                if before != 0.0:
                    amp[q] = amp[q] * np.exp(before)
                before += log_t[q]
        for q in range(m):
            if amp[q] > 0:
                out_beam[count] = b
                out_range[count] = rng[q]
                out_amp[count] = amp[q]
                if q < n_sub:
                    out_label[count], out_obj[count] = s_label[b * n_sub + q], s_obj[b * n_sub + q]
                else:
                    i = order[first[b] + q - n_sub]
                    out_label[count], out_obj[count] = sc_label[i], sc_obj[i]
                count += 1
    return count - start


def world_rays(directions, rotation, translation, want64, scratch=None):
    """Sensor-frame sub-ray directions (C, B, S, 3) rotated by each column's rotation (C, 3, 3):
    float32 origins and directions (C*B*S, 3) for the caster, column-major (transposes of
    (3, C*B*S) arrays, which Mitsuba takes without a copy; in ``scratch`` if given), and the
    float64 directions (C*B*S, 3) if ``want64`` (else an empty array)."""
    n_cols, n_beams, n_sub = directions.shape[:3]
    m = n_cols * n_beams * n_sub
    new = allocator(scratch)
    o32 = new("origins32", (3, m), np.float32).T
    d32 = new("directions32", (3, m), np.float32).T
    d64 = np.empty((m if want64 else 0, 3))
    cuts = workers.bounds(n_cols, CHUNK_RAYS // max(n_beams * n_sub, 1))
    workers.run_chunks(lambda c: _world_rays_run(directions, rotation, translation, cuts[c], cuts[c + 1], want64,
                                                 o32, d32, d64), len(cuts) - 1)  # fmt: skip
    return o32, d32, d64


@numba.njit(cache=True, nogil=True)
def _world_rays_run(directions, rotation, translation, c0, c1, want64, o32, d32, d64):
    """Columns c0..c1 of :func:`world_rays`."""
    n_beams, n_sub = directions.shape[1:3]
    k = c0 * n_beams * n_sub
    for c in range(c0, c1):
        r = rotation[c]
        tx, ty, tz = np.float32(translation[c, 0]), np.float32(translation[c, 1]), np.float32(translation[c, 2])
        for b in range(n_beams):
            for s in range(n_sub):
                x, y, z = directions[c, b, s, 0], directions[c, b, s, 1], directions[c, b, s, 2]
                wx = (r[0, 0] * x + r[0, 2] * z) + r[0, 1] * y
                wy = (r[1, 0] * x + r[1, 2] * z) + r[1, 1] * y
                wz = (r[2, 0] * x + r[2, 2] * z) + r[2, 1] * y
                o32[k, 0], o32[k, 1], o32[k, 2] = tx, ty, tz
                d32[k, 0], d32[k, 1], d32[k, 2] = wx, wy, wz
                if want64:
                    d64[k, 0], d64[k, 1], d64[k, 2] = wx, wy, wz
                k += 1


def surface_returns(hits, static, directions, rotation, reflectivity, retro, material_label, actor_label, weights,
                     power, overlap_start, overlap_full, effects, scale, offset, two_way, compact,
                     scratch=None):  # fmt: skip
    """Range and peak amplitude (LIDAR equation) of every sub-ray's scene hit.

    ``hits``: the caster's distance, triangle, normal, material, actor and object id per
    sub-ray (:class:`~lidar_weather_sim.scene.raycast.scene_caster.Hits`); ``static``: the static
    mesh's normal, material and object id per triangle, which a static hit's are read from
    (the per-ray ones only for actor hits).

    ``compact``: the candidates with amplitude > 0 as (beam, range, amplitude, label,
    object id), beam-major (in ``scratch`` if given), each chunk's from its first ray's
    index on, and these runs as (starts, counts): the echo stage reads them where they
    are. Else range (inf for a miss) and amplitude (0 for a miss) of every sub-ray, flat
    (the other outputs empty; runs None). With ``effects`` the regions' reflectance
    scale, range offset and two-way transmission (N, S) apply.
    """
    n_cols, n_beams, n_sub = directions.shape[:3]
    m = n_cols * n_beams * n_sub
    size = m if compact else 0
    new = allocator(scratch if compact else None)
    out = Candidates(new("cand_beam", size, np.int64), new("cand_range", m, np.float64),
                     new("cand_amp", m, np.float64), new("cand_label", size, np.uint8),
                     new("cand_obj", size, np.uint32))  # fmt: skip
    hits, static = CastHits(*hits), TriangleTables(*static)
    surfaces = Surfaces(reflectivity, retro, material_label, actor_label)
    receiver = Receiver(weights, power, overlap_start, overlap_full)
    regions = RegionEffects(effects, scale, offset, two_way)
    cuts = workers.bounds(n_cols, CHUNK_RAYS // max(n_beams * n_sub, 1))
    counts = workers.run_chunks(
        lambda c: _surface_returns_run(hits, static, directions, rotation, surfaces, receiver, regions, compact,
                                       cuts[c], cuts[c + 1], out),
        len(cuts) - 1,
    )  # fmt: skip
    if not compact:
        return *out, None
    return *out, (cuts[:-1] * (n_beams * n_sub), np.array(counts, np.int64))


def compact_candidates(candidates, segments):
    """The candidates of ``segments`` (starts, counts) moved together (in place): flat arrays."""
    count = _compact_run(tuple(candidates), *segments)
    return tuple(x[:count] for x in candidates)


@numba.njit(cache=True, nogil=True)
def _compact_run(out, starts, counts):
    beam, rng, amp, label, obj = out
    count = 0
    for c in range(len(counts)):
        src = starts[c]
        if src != count:
            for k in range(counts[c]):
                beam[count + k], rng[count + k], amp[count + k] = beam[src + k], rng[src + k], amp[src + k]
                label[count + k], obj[count + k] = label[src + k], obj[src + k]
        count += counts[c]
    return count


@numba.njit(cache=True, nogil=True)
def _surface_returns_run(hits, static, directions, rotation, surfaces, receiver, regions, compact, c0, c1, out):
    """Columns c0..c1 of :func:`surface_returns` (``hits``: :class:`CastHits`, ``static``:
    :class:`~lidar_weather_sim.scene.raycast.scene_caster.TriangleTables`, ``surfaces``: :class:`Surfaces`,
    ``receiver``: :class:`Receiver`, ``regions``: :class:`RegionEffects`) into ``out``
    (:class:`~lidar_weather_sim.sensor.echo.Candidates`); compact candidates are written from the
    chunk's first ray index on. Returns how many."""
    distance, triangle, normal, material, actor, object_id = hits
    static_normal, static_material, static_object_id = static
    reflectivity, retro, material_label, actor_label = surfaces
    weights, power, overlap_start, overlap_full = receiver
    effects, scale, offset, two_way = regions
    out_beam, out_rng, out_amp, out_label, out_obj = out
    n_beams, n_sub = directions.shape[1:3]
    no_material = len(reflectivity) - 1
    k = c0 * n_beams * n_sub
    count = k
    for c in range(c0, c1):
        r = rotation[c]
        for b in range(n_beams):
            beam = c * n_beams + b
            for s in range(n_sub):
                dist = np.float64(distance[k])
                if not np.isfinite(dist):
                    if not compact:
                        out_rng[k] = np.inf
                        out_amp[k] = 0.0
                    k += 1
                    continue
                t = triangle[k]
                if t >= 0:  # the static triangle's normal, unflipped: |cos| is the same
                    a = -1
                    n0, n1, n2 = static_normal[t, 0], static_normal[t, 1], static_normal[t, 2]
                    mat, obj = static_material[t], static_object_id[t]
                else:  # an actor's hit
                    a = actor[k]
                    n0, n1, n2, mat, obj = normal[k, 0], normal[k, 1], normal[k, 2], material[k], object_id[k]
                x, y, z = directions[c, b, s, 0], directions[c, b, s, 1], directions[c, b, s, 2]
                wx = (r[0, 0] * x + r[0, 2] * z) + r[0, 1] * y
                wy = (r[1, 0] * x + r[1, 2] * z) + r[1, 1] * y
                wz = (r[2, 0] * x + r[2, 2] * z) + r[2, 1] * y
                cos_inc = abs((np.float64(n0) * wx + np.float64(n2) * wz) + np.float64(n1) * wy)
                mat = mat if mat >= 0 else no_material
                refl = surface_reflectance_at(reflectivity[mat], retro[mat], cos_inc)
                rng = dist
                if effects:
                    refl = refl * scale[beam, s]
                    rng = dist + offset[beam, s]
                amp = peak_amplitude_at(power, weights[s], refl, rng, two_way[beam, s] if effects else 1.0,
                                        overlap_at(rng, overlap_start, overlap_full))  # fmt: skip
                if not compact:
                    out_rng[k] = rng
                    out_amp[k] = amp
                elif amp > 0:
                    out_beam[count] = beam
                    out_rng[count] = rng
                    out_amp[count] = amp
                    out_label[count] = actor_label[a] if a >= 0 else material_label[mat]
                    out_obj[count] = obj
                    count += 1
                k += 1
    return count - c0 * n_beams * n_sub


#: Below this many draws numpy's ``normal`` is faster (numba's unboxing of a new generator costs ~15 us).
NUMBA_NORMAL_MIN = 2048


def range_noise(rng: np.random.Generator, sigma: float, n: int, scratch) -> np.ndarray:
    """``rng.normal(0, sigma, n)`` (m): the same values, drawn by numba's port of numpy's
    generator (3x faster) into ``scratch`` when there are many."""
    if n < NUMBA_NORMAL_MIN:
        return rng.normal(0.0, sigma, n)
    out = scratch.get("range_noise", n, np.float64)
    _normal(rng, sigma, out)
    return out


@numba.njit(cache=True, nogil=True)
def _normal(rng, sigma, out):
    for k in range(len(out)):
        out[k] = rng.normal(0.0, sigma)


@numba.njit(cache=True, nogil=True)
def kept_echoes(noise, range_m, amplitude, starts, counts, min_range, dark, ranges, kept, ratio, reported):
    """The echoes in the runs (starts, counts) in order: ``ranges`` (where the echoes are) gets
    each one's range plus its ``noise`` (every echo's, reported or not: a return mode changes which
    points there are, never their noise); those the return mode reports (``reported`` non-zero, see
    :func:`~lidar_weather_sim.sensor.echo.select_returns`; empty: all) and at or beyond ``min_range``
    get their index into ``kept`` and their peak amplitude (at least 1e-12) over ``dark`` into
    ``ratio``, as numpy's sum, flatnonzero, maximum and division. Returns how many were kept."""
    every = len(reported) == 0
    j = count = 0
    for c in range(len(counts)):
        for i in range(starts[c], starts[c] + counts[c]):
            ranges[i] = noise[j] + range_m[i]
            j += 1
            if ranges[i] >= min_range and (every or reported[i] != 0):
                a = amplitude[i]
                kept[count] = i
                ratio[count] = (a if not a < 1e-12 else 1e-12) / dark
                count += 1
    return count


@functools.cache
def padding_bytes(dtype: np.dtype) -> np.ndarray:
    """Offsets of the bytes of a point that belong to no field (written as zeros)."""
    used = np.zeros(dtype.itemsize, bool)
    for base, offset in (dtype.fields[name][:2] for name in dtype.names):
        used[offset : offset + base.itemsize] = True
    return np.flatnonzero(~used)


def fill_points(points, kept, echoes: KeptEchoes, log_ratio, span: float, scan: ScanTables, truth=None):
    """Points of the ``echoes`` ``kept`` (ascending) in the sensor frame at their firing time; every
    byte of ``points`` is written (padding as zeros), so it may come from ``np.empty``. The return
    type is the echo's ``reported`` code (:func:`~lidar_weather_sim.sensor.echo.select_returns`), or
    with an empty ``reported`` (return mode all) its position among the beam's kept echoes. Intensity:
    each kept echo's ``log_ratio`` (log of its amplitude over the dark threshold) over ``span``
    (:func:`~lidar_weather_sim.sensor.radiometry.intensity_byte`). ``truth``: the echoes' (label,
    object id) for a point layout with ground-truth fields (None: a layout without)."""
    raw = points.view(np.uint8).reshape(len(points), points.dtype.itemsize)
    padding = padding_bytes(points.dtype)
    cuts = workers.bounds(len(kept), CHUNK_RAYS // 4)

    def run(c):
        _fill_points_run(points, raw, padding, kept, cuts[c], cuts[c + 1], echoes, log_ratio, span, scan)
        if truth is not None:  # a kernel of its own: numba types every branch, the other layout has no such fields
            _fill_ground_truth_run(points, kept, cuts[c], cuts[c + 1], *truth)

    workers.run_chunks(run, len(cuts) - 1)


@numba.njit(cache=True, nogil=True)
def _fill_ground_truth_run(points, kept, j0, j1, label, object_id):
    for j in range(j0, j1):
        p = points[j]
        p["label"] = label[kept[j]]
        p["object_id"] = object_id[kept[j]]


@numba.njit(cache=True, nogil=True)
def _fill_points_run(points, raw, padding, kept, j0, j1, echoes, log_ratio, span, scan):
    """Points j0..j1 of :func:`fill_points` (``raw``: the same memory as bytes, (N, itemsize);
    ``padding``: its byte offsets written as zeros) from the ``kept`` :class:`KeptEchoes` with
    their log amplitude ratios over ``span`` and the :class:`ScanTables` ``scan``."""
    ranges, beam, echo, epw, reported = echoes
    columns, channels, n_beams, cos_az, sin_az, azimuth, cos_el, sin_el, elevation, stamp = scan
    first = -n_beams  # first beam of the current column (none yet): divisions only where it changes
    col = 0
    for j in range(j0, j1):
        for b in padding:
            raw[j, b] = 0
        i = kept[j]
        bm = beam[i]
        if not first <= bm < first + n_beams:
            col = columns[bm // n_beams]
            first = bm // n_beams * n_beams
        ch = channels[bm - first]
        r = ranges[i]
        p = points[j]
        p["x"] = r * cos_el[ch] * cos_az[col, ch]
        p["y"] = r * cos_el[ch] * sin_az[col, ch]
        p["z"] = r * sin_el[ch]
        p["azimuth"] = azimuth[col, ch]
        p["elevation"] = elevation[ch]
        p["distance"] = r
        p["channel"] = ch
        p["time_stamp"] = stamp[col]
        p["echo"] = echo[i]
        p["epw"] = epw[i]
        p["intensity"] = intensity_byte(log_ratio[j], span)
        if len(reported):
            p["return_type"] = reported[i]
            continue
        # Nebula return type: IDENTICAL when alone, else FIRST / SECOND / LAST (among the kept echoes)
        last = j + 1 == len(kept) or beam[kept[j + 1]] != bm
        if echo[i] == 1:
            p["return_type"] = _IDENTICAL if last else _FIRST
        else:
            p["return_type"] = _LAST if last else _SECOND
