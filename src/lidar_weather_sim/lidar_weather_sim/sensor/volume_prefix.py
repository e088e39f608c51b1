"""The echoes a volume gives on its own in front of the beams' hard targets, found once for all the beams that
read the same tables at the same scales, and kept for the next batches of those tables.

A medium's tables are per channel (:mod:`lidar_weather_sim.sensor.volume_tables`; fog on OS1-128 x 2048: one
table per channel, read by the channel's 2048 beams of a scan). In front of where a beam's layers are cut by
its hard target (:func:`~lidar_weather_sim.sensor.volume_tables.uncut_end`) and of where its pulses add
anything to a sample (below ``NEGLIGIBLE`` of the threshold, far under a double's rounding of the samples the
echoes read), the beam's waveform is its tables' alone: the same samples, bit for bit, for every beam of the
group. Fog's near-field echo (above the threshold over ~12 m of an OS1 beam in fog 50 m, ~450 samples) is thus
sampled once per group instead of once per beam; a region builds its tables once per weather state, so a group's
echoes are found once per weather state (and receiver) instead of once per batch.

A beam takes the echoes of its group that end in front of the last two samples ``W - 2, W - 1`` in that common
part which are both below the threshold; the echo stage samples the beam's waveform from ``W`` on (its window
then begins at ``W - 2`` or ``W - 1``, below the threshold); a beam without pulses whose layers are not cut takes
all of its group's echoes and is done. The echoes are therefore those the echo stage finds
on the whole waveform, bit for bit (``test_volume_prefix.py`` compares both on fog, rain and snow batches).
"""

from __future__ import annotations

import threading
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


def build_prefix(volume: Volume, detector: NamedTuple, detect: Callable[[Volume], tuple]) -> VolumePrefix:
    """The :class:`VolumePrefix` of ``volume``'s beams for a receiver ``detector`` (its ``threshold``, noise units,
    and ``max_echoes`` per beam; all its fields key the kept groups, below).

    Only beams whose layers together may exceed the threshold (the sum of their scales times their tables'
    peaks) are grouped. ``detect(group_volume)``: the echoes of the volume alone of each row of ``group_volume``
    (its hard targets at inf), as (beam, range_m, amplitude, epw_m, label), beams ascending, each beam's echoes
    in range order. A group whose echoes are not one per interval above the threshold (up to ``max_echoes``) is
    not used (its beams are sampled on their own). A group's intervals and echoes are kept with the volume's
    tables for the next batches (:class:`_StackGroups`); a group of one beam is used only if it was kept before
    (sampling its beam alone costs less than the group's whole volume)."""
    n, layers = volume.table.shape
    if layers == 0 or len(volume.peak) == 0:
        return no_prefix(n)
    threshold = float(detector.threshold)
    loudest = sum(np.nanmax(volume.scale[:, k], initial=0.0) for k in range(layers)) * volume.peak.max()
    if loudest <= threshold:  # (a column's max: numpy reduces an (N, L) array along N ~50x slower)
        return no_prefix(n)  # no beam's layers reach the threshold (rain's, snow's volumes): nothing to share
    scale_bits = np.ascontiguousarray(volume.scale, np.float64).view(np.int64)
    group, rows, size = _groups(volume.table, volume.scale, scale_bits, volume.peak, threshold)
    if len(rows) == 0:
        return no_prefix(n)
    valid = (volume.table[rows] >= 0) & (volume.scale[rows] > 0)
    table, scale = np.where(valid, volume.table[rows], -1), np.where(valid, volume.scale[rows], 0.0)
    keys = [k.tobytes() for k in np.concatenate([table, np.where(valid, scale_bits[rows], 0)], axis=1)]
    kept = _StackGroups.of(volume, tuple(detector))
    index, usable, arrays = kept.find(keys)
    todo = np.flatnonzero((index < 0) & (size > 1))
    if len(todo):
        made = _group_prefixes(volume, table[todo], scale[todo], detector, detect)
        index[todo], usable, arrays = kept.add([keys[g] for g in todo], made)
    used = np.append(usable, False)[index]  # index -1: not kept
    number = np.append(np.where(used, index, -1), -1)  # the last for the beams without a group (-1)
    return VolumePrefix(number[group], *arrays)


def _group_prefixes(volume: Volume, table: np.ndarray, scale: np.ndarray, detector, detect) -> tuple:
    """A :class:`VolumePrefix` without its ``group`` field (interval_origin .. label) of the groups with
    layers ``table``, ``scale`` (G, L) on ``volume``'s tables, one group per row, and which are usable (G,)."""
    group_volume = volume._replace(table=np.ascontiguousarray(table), scale=np.ascontiguousarray(scale),
                                   hit_m=np.full(table.shape, np.inf))  # fmt: skip
    interval_origin, over_first, over_end = _over_intervals(group_volume, float(detector.threshold))
    beam, range_m, amplitude, epw_m, label = detect(group_volume)
    echo_origin = np.searchsorted(beam, np.arange(len(table) + 1)).astype(np.int64)
    usable = np.diff(echo_origin) == np.minimum(np.diff(interval_origin), detector.max_echoes)
    arrays = (interval_origin, over_first, over_end, echo_origin, np.ascontiguousarray(range_m, np.float64),
              np.ascontiguousarray(amplitude, np.float64), np.ascontiguousarray(epw_m, np.float64),
              np.ascontiguousarray(label, np.uint8))  # fmt: skip
    return arrays, usable


class _StackGroups:
    """The groups met so far on one stack of tables (a region builds its tables once per weather state,
    :func:`~lidar_weather_sim.sensor.volume_tables.stack_volume` stacks them once) for one receiver: their
    intervals and echoes as a :class:`VolumePrefix`'s arrays (``arrays``: interval_origin .. label, group k at
    row k), whether each is usable, and each one's row by its layers' bytes (``index``). Kept for the last
    ``STACKS`` stacks, each with at most ``GROUPS`` groups (drops or a dirty cover in front of the volume give
    beams scales of their own; beyond, a batch's new groups serve that batch alone). An entry holds its stack's
    ``wave`` array, so that array's id is not reused while it lives. Batches are detected on worker threads: the
    groups only grow, under a lock, each time in new arrays, so a row found stays valid in every later snapshot."""

    STACKS = 8
    GROUPS = 8192
    _kept: dict[tuple, _StackGroups] = {}
    _lock = threading.Lock()

    def __init__(self, wave: np.ndarray) -> None:
        self.wave = wave
        self.index: dict[bytes, int] = {}
        self.usable = np.zeros(0, np.bool_)
        self.arrays = tuple(no_prefix())[1:]

    @classmethod
    def of(cls, volume: Volume, receiver: tuple) -> _StackGroups:
        """The groups kept for ``volume``'s tables and ``receiver`` (the detector's fields)."""
        key = (id(volume.wave), receiver)
        with cls._lock:
            kept = cls._kept.get(key)
            if kept is None or kept.wave is not volume.wave:
                while len(cls._kept) >= cls.STACKS:
                    cls._kept.pop(next(iter(cls._kept)))
                kept = cls._kept[key] = _StackGroups(volume.wave)
        return kept

    def find(self, keys: list[bytes]) -> tuple[np.ndarray, np.ndarray, tuple]:
        """The rows of the groups ``keys`` (-1: not kept), and a snapshot of ``usable`` and ``arrays``."""
        with self._lock:
            return np.array([self.index.get(key, -1) for key in keys], np.int64), self.usable, self.arrays

    def add(self, keys: list[bytes], made: tuple) -> tuple[np.ndarray, np.ndarray, tuple]:
        """The groups ``made`` (from :func:`_group_prefixes`) added under ``keys`` (kept if there is room): their
        rows (G,), and a snapshot of ``usable`` and ``arrays`` with them."""
        (interval_origin, over_first, over_end, echo_origin, *echoes), usable = made
        with self._lock:
            old = self.arrays
            rows = len(self.usable) + np.arange(len(keys))
            arrays = (np.concatenate([old[0], old[0][-1] + interval_origin[1:]]),
                      np.concatenate([old[1], over_first]), np.concatenate([old[2], over_end]),
                      np.concatenate([old[3], old[3][-1] + echo_origin[1:]]),
                      *(np.concatenate([a, b]) for a, b in zip(old[4:], echoes)))  # fmt: skip
            usable = np.concatenate([self.usable, usable])
            if len(usable) <= self.GROUPS:
                self.arrays, self.usable = arrays, usable
                self.index.update(zip(keys, rows.tolist()))
        return rows, usable, arrays


@numba.njit(cache=True, nogil=True)
def _groups(table, scale, bits, peak, thr):
    """(group (N,), rows (G,), size (G,)): the beams whose layers (``table``, ``scale`` and its ``bits`` as int64,
    each (N, L); a layer without a table or with scale <= 0 is none) may together exceed ``thr`` (the sum of scale
    times the table's ``peak``), grouped by equal layers, numbered in the order of their first beam (rows: it;
    size: the group's beams); the other beams are -1."""
    n, layers = table.shape
    key = np.empty((n, 2 * layers), np.int64)  # the layers as compared: table, scale's bits (none: -1, 0)
    loud = np.zeros(n, np.bool_)
    code = np.zeros(n, np.uint64)
    for b in range(n):
        total = 0.0
        h = np.uint64(1469598103934665603)
        for layer in range(layers):
            valid = table[b, layer] >= 0 and scale[b, layer] > 0.0
            key[b, 2 * layer] = table[b, layer] if valid else -1
            key[b, 2 * layer + 1] = bits[b, layer] if valid else 0
            if valid:
                total += scale[b, layer] * peak[table[b, layer]]
            h = (h ^ np.uint64(key[b, 2 * layer])) * np.uint64(1099511628211)
            h = (h ^ np.uint64(key[b, 2 * layer + 1])) * np.uint64(1099511628211)
        h = (h ^ (h >> np.uint64(33))) * np.uint64(0xFF51AFD7ED558CCD)  # the high bits into the low ones
        loud[b] = total > thr
        code[b] = h ^ (h >> np.uint64(33))
    mask = np.uint64(1)
    while mask < np.uint64(2 * n):
        mask = mask * np.uint64(2)
    mask -= np.uint64(1)
    slots = np.full(int(mask) + 1, -1, np.int64)  # open addressing: the first beam of each layers met
    owner = np.full(n, -1, np.int64)  # each loud beam's first beam of equal layers
    size = np.zeros(n, np.int64)
    for b in range(n):
        if not loud[b]:
            continue
        slot = code[b] & mask
        while True:
            f = slots[slot]
            if f < 0:
                slots[slot] = b
                owner[b] = b
                break
            same = True
            for j in range(2 * layers):
                if key[f, j] != key[b, j]:
                    same = False
                    break
            if same:
                owner[b] = f
                break
            slot = (slot + np.uint64(1)) & mask
        size[owner[b]] += 1
    number = np.full(n, -1, np.int64)
    g = 0
    for b in range(n):
        if owner[b] == b:
            number[b] = g
            g += 1
    group = np.full(n, -1, np.int64)
    rows = np.empty(g, np.int64)
    sizes = np.empty(g, np.int64)
    for b in range(n):
        if owner[b] >= 0:
            group[b] = number[owner[b]]
        if owner[b] == b:
            rows[number[b]] = b
            sizes[number[b]] = size[b]
    return group, rows, sizes


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
