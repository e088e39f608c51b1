"""The echoes a volume gives on its own in front of the beams' hard targets, found once per batch for all the
beams that read the same tables at the same scales.

A medium's tables are per channel (:mod:`lidar_weather_sim.sensor.volume_tables`; fog on OS1-128 x 2048: one
table per channel, read by the channel's 2048 beams of a scan). In front of where a beam's layers are cut by
its hard target (:func:`~lidar_weather_sim.sensor.volume_tables.uncut_end`) and of where its pulses add
anything to a sample (below ``NEGLIGIBLE`` of the threshold, far under a double's rounding of the samples the
echoes read), the beam's waveform is its tables' alone: the same samples, bit for bit, for every beam of the
group. Fog's near-field echo (above the threshold over ~12 m of an OS1 beam in fog 50 m, ~450 samples) is thus
sampled once per group and batch instead of once per beam.

A beam takes the echoes of its group that end in front of the last two samples ``W - 2, W - 1`` in that common
part which are both below the threshold; the echo stage samples the beam's waveform from ``W`` on (its window
then begins at ``W - 2`` or ``W - 1``, below the threshold); a beam without pulses whose layers are not cut takes
all of its group's echoes and is done. The echoes are therefore those the echo stage finds
on the whole waveform, bit for bit (``test_volume_prefix.py`` compares both on fog, rain and snow batches).
"""

from __future__ import annotations

from collections.abc import Callable
from typing import NamedTuple

import numba
import numpy as np

from lidar_weather_sim.sensor.volume_tables import Volume, fill_volume, uncut_end, volume_window

#: A pulse farther than where it falls below this fraction of the threshold adds nothing to a sample the
#: echoes read (their values are near the threshold or above it; a double rounds at 1.1e-16 of them).
NEGLIGIBLE = 1e-20


class VolumePrefix(NamedTuple):
    """Per beam of a batch (N, a row of the :class:`Volume`'s ``table``) its group (G: beams with the same layers
    at the same scales), and per group the intervals of samples where its volume alone exceeds the threshold
    and the echoes it gives there (the first ``max_echoes``), in range order."""

    group: np.ndarray  # (N,) int64, -1: none
    interval_origin: np.ndarray  # (G + 1,) int64: group g's intervals at interval_origin[g] .. interval_origin[g + 1]
    over_first: np.ndarray  # (I,) int64, an interval's first sample above the threshold
    over_end: np.ndarray  # (I,) int64, the first sample after it that is not
    echo_origin: np.ndarray  # (G + 1,) int64: group g's echoes at echo_origin[g] .. echo_origin[g + 1]
    range_m: np.ndarray  # (E,) m
    amplitude: np.ndarray  # (E,) noise units
    epw_m: np.ndarray  # (E,) m
    label: np.ndarray  # (E,) uint8


def no_prefix(n_beams: int = 0) -> VolumePrefix:
    """A :class:`VolumePrefix` without groups (every beam's volume is sampled on its own)."""
    origin = np.zeros(1, np.int64)
    none = np.zeros(0, np.int64)
    return VolumePrefix(np.full(n_beams, -1, np.int64), origin, none, none, origin, np.zeros(0), np.zeros(0),
                        np.zeros(0), np.zeros(0, np.uint8))  # fmt: skip


def build_prefix(volume: Volume, threshold: float, max_echoes: int, detect: Callable[[Volume], tuple]) -> VolumePrefix:
    """The :class:`VolumePrefix` of ``volume``'s beams for a receiver of ``threshold`` (noise units) keeping
    ``max_echoes`` per beam.

    Only beams whose layers together may exceed the threshold (the sum of their scales times their tables'
    peaks) are grouped, and only groups of two beams or more. ``detect(group_volume)``: the echoes of the
    volume alone of each row of ``group_volume`` (its hard targets at inf), as (beam, range_m, amplitude,
    epw_m, label), beams ascending, each beam's echoes in range order. A group whose echoes are not one per
    interval above the threshold (up to ``max_echoes``) is not used (its beams are sampled on their own)."""
    n, layers = volume.table.shape
    if layers == 0 or n < 2 or len(volume.peak) == 0:
        return no_prefix(n)
    if (np.nan_to_num(volume.scale).max(axis=0) * volume.peak.max()).sum() <= threshold:
        return no_prefix(n)  # no beam's layers reach the threshold (rain's, snow's volumes): nothing to share
    scale_bits = np.ascontiguousarray(volume.scale, np.float64).view(np.int64)
    group, rows = _groups(volume.table, volume.scale, scale_bits, volume.peak, float(threshold))
    if len(rows) == 0:
        return no_prefix(n)
    table, scale = volume.table[rows], volume.scale[rows]
    valid = (table >= 0) & (scale > 0)
    table, scale = np.where(valid, table, -1), np.where(valid, scale, 0.0)
    group_volume = volume._replace(table=np.ascontiguousarray(table), scale=np.ascontiguousarray(scale),
                                   hit_m=np.full((len(rows), layers), np.inf))  # fmt: skip
    interval_origin, over_first, over_end = _over_intervals(group_volume, float(threshold))
    beam, range_m, amplitude, epw_m, label = detect(group_volume)
    found = np.bincount(beam, minlength=len(rows))
    unused = np.flatnonzero(found != np.minimum(np.diff(interval_origin), max_echoes))
    if len(unused):
        group[np.isin(group, unused)] = -1
    echo_origin = np.concatenate([[0], np.cumsum(found)]).astype(np.int64)
    return VolumePrefix(group, interval_origin, over_first, over_end, echo_origin,
                        np.ascontiguousarray(range_m, np.float64), np.ascontiguousarray(amplitude, np.float64),
                        np.ascontiguousarray(epw_m, np.float64), np.ascontiguousarray(label, np.uint8))  # fmt: skip


@numba.njit(cache=True, nogil=True)
def _groups(table, scale, bits, peak, thr):
    """(group (N,), rows (G,)): the beams whose layers (``table``, ``scale`` and its ``bits`` as int64, each (N, L);
    a layer without a table or with scale <= 0 is none) may together exceed ``thr`` (the sum of scale times the table's ``peak``),
    grouped by equal layers; groups of two beams or more are numbered in the order of their first beam (rows:
    it), the other beams are -1."""
    n, layers = table.shape
    key = np.empty((n, 2 * layers), np.int64)  # the layers as compared: table, scale's bits (none: -1, 0)
    loud = np.zeros(n, np.bool_)
    code = np.zeros(n, np.int64)
    for b in range(n):
        total = 0.0
        h = np.int64(1469598103934665603)
        for layer in range(layers):
            valid = table[b, layer] >= 0 and scale[b, layer] > 0.0
            key[b, 2 * layer] = table[b, layer] if valid else -1
            key[b, 2 * layer + 1] = bits[b, layer] if valid else 0
            if valid:
                total += scale[b, layer] * peak[table[b, layer]]
            h = (h ^ key[b, 2 * layer]) * np.int64(1099511628211)
            h = (h ^ key[b, 2 * layer + 1]) * np.int64(1099511628211)
        loud[b] = total > thr
        code[b] = h
    first = numba.typed.Dict.empty(numba.types.int64, numba.types.int64)  # hash -> the first beam with it
    owner = np.full(n, -1, np.int64)  # each loud beam's first beam of equal layers
    size = np.zeros(n, np.int64)
    for b in range(n):
        if not loud[b]:
            continue
        h = code[b]
        while True:  # open addressing on the hash: equal layers, or the next free hash
            if h not in first:
                first[h] = b
                owner[b] = b
                break
            f = first[h]
            same = True
            for j in range(2 * layers):
                if key[f, j] != key[b, j]:
                    same = False
                    break
            if same:
                owner[b] = f
                break
            h += 1
        size[owner[b]] += 1
    number = np.full(n, -1, np.int64)
    rows = []
    for b in range(n):
        if owner[b] == b and size[b] >= 2:
            number[b] = len(rows)
            rows.append(b)
    group = np.full(n, -1, np.int64)
    for b in range(n):
        if owner[b] >= 0:
            group[b] = number[owner[b]]
    out = np.empty(len(rows), np.int64)
    for g in range(len(rows)):
        out[g] = rows[g]
    return group, out


@numba.njit(cache=True, nogil=True)
def _over_intervals(volume, thr):
    """Per beam (row) of ``volume``: the intervals [first, end) of samples where its volume exceeds ``thr``, in
    range order, as (origin (B + 1,), first (I,), end (I,)) (:class:`VolumePrefix`)."""
    n = volume.table.shape[0]
    origin = np.zeros(n + 1, np.int64)
    first, end = [0], [0]
    first.pop()
    end.pop()
    for b in range(n):
        v0, v1, _ = volume_window(volume, b)
        if v1 > v0:
            values, labels = np.empty(v1 - v0), np.empty(v1 - v0, np.uint8)
            fill_volume(volume, b, v0, v1 - v0, values, labels)
            inside = False
            for i in range(v1 - v0):
                over = values[i] > thr
                if over and not inside:
                    first.append(v0 + i)
                elif inside and not over:
                    end.append(v0 + i)
                inside = over
            if inside:
                end.append(v1)
        origin[b + 1] = len(first)
    return origin, np.array(first, np.int64), np.array(end, np.int64)


@numba.njit(cache=True, inline="always")
def prefix_echoes(prefix, volume, b, pulses, m, detector, v0, v1, out, out0):
    """Beam b's echoes from its group's (module doc), written into ``out`` (the echo stage's buffers) from out0
    on: returns (how many, the sample from which the echo stage samples the beam's volume instead of ``v0``; v1
    when nothing is left to find: no room, or a beam without pulses whose whole volume is its group's).
    ``pulses``: its m merged pulses (range_m, amplitude); [v0, v1): where its volume may be non-zero."""
    g = prefix.group[b] if b < len(prefix.group) else -1
    if g < 0:
        return 0, v0
    thr, s, max_echoes = detector.threshold, detector.sigma, detector.max_echoes
    dx = s / 8.0
    end = min(uncut_end(volume, b), v1 - 1)  # the samples in front of end are the group's
    whole = end == v1 - 1 and m == 0  # ... and every sample, the beam having no pulses
    r, a = pulses.range_m, pulses.amplitude
    floor, total, r_min = thr * NEGLIGIBLE, 0.0, 1e300
    for q in range(m):
        if a[q] > floor:
            end = min(end, int(np.floor((r[q] - s * np.sqrt(2.0 * np.log(a[q] / floor))) / dx)) - 1)
        if a[q] > 0.0:
            total += a[q]
            r_min = min(r_min, r[q])
    if total > thr:  # how far in front of them the echo stage's window reaches (see _volume_echoes)
        end = min(end, int(np.floor((r_min - s * (np.sqrt(2.0 * np.log(total / thr)) + 1e-6)) / dx)) - 2)
    c = end - 1  # the last two samples in front of end below the threshold: c - 1, c
    taken = 0
    i0 = prefix.interval_origin[g]
    for i in range(prefix.interval_origin[g + 1] - 1, i0 - 1, -1):
        if prefix.over_first[i] > c:
            continue
        if prefix.over_end[i] <= c - 1:
            taken = i - i0 + 1
            break
        c = prefix.over_first[i] - 1
    if c + 1 <= v0:
        return 0, v0
    every = taken == prefix.interval_origin[g + 1] - i0
    e0 = prefix.echo_origin[g]
    taken = min(taken, prefix.echo_origin[g + 1] - e0, max_echoes)
    for k in range(taken):
        out.range_m[out0 + k] = prefix.range_m[e0 + k]
        out.amplitude[out0 + k] = prefix.amplitude[e0 + k]
        out.epw_m[out0 + k] = prefix.epw_m[e0 + k]
        out.label[out0 + k] = prefix.label[e0 + k]
        out.object_id[out0 + k] = 0
    if taken == max_echoes or (whole and every):
        return taken, v1
    return taken, c + 1
