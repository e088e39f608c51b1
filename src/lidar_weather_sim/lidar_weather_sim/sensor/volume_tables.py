"""Volume returns as tables on the echo stage's sampling grid: what a beam inside a medium (fog, the drops too
small to be seen one by one) receives from it, built once per medium and read per beam.

The grid is the one :mod:`lidar_weather_sim.sensor.echo` samples a waveform on: ``dx = s / 8`` (``s`` the pulse's
Gaussian sigma in range, m), sample k at range ``k dx`` (m along the beam, from the sensor), from k = -REACH (the
pulses of the nearest cells reach in front of the sensor, as the echo stage's pulses do): index i of the arrays is
sample i - REACH. Cell k is [(k - 1/2) dx, (k + 1/2) dx]. A table holds, for one medium seen by one beam's optics:

- ``density[k]``: the medium's return per cell (noise units): the integral over the cell of a density of range
  (noise units per m, e.g. ``C pi beta O(r) exp(-2 alpha r) / r^2`` of
  :class:`lidar_weather_sim.regions.volume_return.VolumeReturn`) by 8-point Gauss-Legendre (exact to < 1e-6
  where 1/r^2 rises near the sensor), then the receiver's AC coupling
  (:func:`lidar_weather_sim.sensor.ac_coupling.highpass_slabs` over the cells, clipped at 0 as there);
- ``wave[k]``: the waveform, the density convolved with the unit-peak Gaussian pulse on the grid
  (``sum_k' density[k'] exp(-((k - k') / 8)^2 / 2)`` over ``|k - k'| <= REACH``, 6 s: what it leaves out is
  below 1e-8 of the sum); 0 outside the support;
- ``cut[i, o]``: the waveform of the density in front of the cell boundary ``(K - 1/2) dx``, K = ``cut_first`` + i,
  at samples ``K - REACH + o`` (o < 2 REACH). Farther in front the truncated waveform is ``wave``, farther behind it
  is 0. A beam whose hard target is at R reads its volume truncated at R as the quadratic interpolation in R of
  the rows of the boundary in front of R and the two behind it (the truncated waveform is smooth in R: its
  derivative is the density at R times the pulse; linear interpolation was off by 6e-3 a sigma behind R);
- ``label[k]`` (uint8) and ``support`` = [k0, k1) (samples): where ``wave`` exceeds ``floor`` (noise units);
  the volume is 0 elsewhere.

The high-pass is causal, so truncating the filtered density at a hit is the filtered truncated density: the
rows hold both. :class:`Volume` stacks the tables of a batch with each beam's hit and scale for the echo kernel,
which reads them with :func:`volume_window` and :func:`fill_volume`, and bounds them block by block
(:func:`fill_block_bounds`: per ``BLOCK`` samples, the largest magnitude of ``wave`` and of every cut row there)
so that the kernel samples only where a beam's waveform may reach its threshold.
"""

from __future__ import annotations

import threading
from collections.abc import Callable
from dataclasses import dataclass
from typing import NamedTuple

import numba
import numpy as np

from lidar_weather_sim.core.borrow import borrow
from lidar_weather_sim.sensor.ac_coupling import highpass_slabs

#: Samples per pulse sigma on the grid (the echo stage's, :func:`lidar_weather_sim.sensor.echo._cluster_echoes`).
SAMPLES_PER_SIGMA = 8
#: Samples (6 sigma) the pulse reaches on each side of a cell.
REACH = 6 * SAMPLES_PER_SIGMA
#: Samples per block of :func:`fill_block_bounds` (sample k in block k // BLOCK).
BLOCK = 16
#: A truncated layer is the quadratic interpolation of three cut rows (weights summing to 1, the last in
#: [-1/8, 0]): its magnitude is at most 1 - 2 (-1/8) = 1.25 times the rows' largest.
INTERPOLATION_GAIN = 1.25
_NODES, _WEIGHTS = np.polynomial.legendre.leggauss(8)
_KERNEL = np.exp(-0.5 * (np.arange(-REACH, REACH + 1) / SAMPLES_PER_SIGMA) ** 2)  # the pulse at k dx, k = -REACH..REACH


def grid_step(sigma_m: float) -> float:
    """The grid's step dx (m) for a pulse of Gaussian sigma ``sigma_m`` (m), as the echo stage computes it."""
    return float(sigma_m) / 8.0


@dataclass(frozen=True)
class VolumeTable:
    """One medium's volume return seen by one beam's optics on the grid of step ``dx_m`` (module doc)."""

    dx_m: float
    density: np.ndarray  # (n,) noise units per cell, after the high-pass (index i: cell i - REACH)
    wave: np.ndarray  # (n,) noise units, 0 outside the support (index i: sample i - REACH)
    cut: np.ndarray  # (m, 2 REACH) noise units
    cut_first: int  # the boundary row of cut[0] (sample)
    label: np.ndarray  # (n,) uint8
    support: tuple[int, int]  # [k0, k1) samples

    @property
    def range_m(self) -> np.ndarray:
        """The range (m) of each sample of ``wave``."""
        return (np.arange(len(self.wave)) - REACH) * self.dx_m

    def truncated(self, hit_m: float) -> np.ndarray:
        """The waveform (n,) at :attr:`range_m` of the medium in front of a hard target at ``hit_m`` (m; inf:
        none), as the echo stage reads it (a reference for tests and plots: the kernel reads the same arrays)."""
        volume = stack_volume([self], np.zeros((1, 1), np.int64), np.ones((1, 1)), np.array([[hit_m]]))
        values, labels = np.zeros(len(self.wave)), np.zeros(len(self.wave), np.uint8)
        fill_volume(volume, 0, -REACH, len(self.wave), values, labels)
        return values


def build_table(density_fn: Callable[[np.ndarray], np.ndarray], *, sigma_m: float, r_max_m: float,
                label: int | np.ndarray, start_m: float = 0.0, tau_m: float = 0.0, floor: float = 0.0) -> VolumeTable:  # fmt: skip
    """The table of a medium whose return density along the beam is ``density_fn(r)`` (noise units per m at ranges
    r, m), from ``start_m`` (m; the overlap's start or the nearest range the LIDAR equation knows) to ``r_max_m``;
    pulse sigma ``sigma_m`` (m), AC coupling time constant ``tau_m`` (m; 0: DC), support where the waveform
    exceeds ``floor`` (noise units), ``label`` of every cell (one, or (n,) per cell)."""
    density = cell_density(density_fn, sigma_m=sigma_m, r_max_m=r_max_m, start_m=start_m, tau_m=tau_m)
    return table_of_cells(density, grid_step(sigma_m), label, floor)


def cell_density(density_fn: Callable[[np.ndarray], np.ndarray], *, sigma_m: float, r_max_m: float,
                 start_m: float = 0.0, tau_m: float = 0.0) -> np.ndarray:  # fmt: skip
    """The cells' return (noise units; index i: cell i - REACH) of the density ``density_fn(r)`` (noise units per m)
    on [``start_m``, ``r_max_m``] (m), after the AC coupling of time constant ``tau_m`` (m; 0: DC), on the grid of
    pulse sigma ``sigma_m`` (m) (:func:`build_table`)."""
    nodes, lower, upper = cell_nodes(sigma_m=sigma_m, r_max_m=r_max_m, start_m=start_m)
    values = density_fn(nodes.ravel()).reshape(nodes.shape)
    return realised_density(values, np.zeros((1, 0)), np.zeros(nodes.shape, np.int64), lower, upper, tau_m)[0]


def cell_nodes(*, sigma_m: float, r_max_m: float, start_m: float = 0.0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(nodes (n, 8), lower (n,), upper (n,)), m: the Gauss-Legendre nodes of each cell (index i: cell i - REACH) on
    the grid of pulse sigma ``sigma_m`` (m) and the cell's bounds clipped to [``start_m``, ``r_max_m``] (m)."""
    dx = grid_step(sigma_m)
    n = int(np.ceil(r_max_m / dx)) + 1 + 2 * REACH
    k = np.arange(n) - REACH
    lower = np.clip((k - 0.5) * dx, start_m, r_max_m)
    upper = np.clip((k + 0.5) * dx, start_m, r_max_m)
    half = 0.5 * (upper - lower)
    return (lower + half)[:, None] + half[:, None] * _NODES[None, :], lower, upper


def realised_density(values: np.ndarray, factors: np.ndarray, slab: np.ndarray, lower: np.ndarray,
                     upper: np.ndarray, tau_m: float = 0.0) -> np.ndarray:  # fmt: skip
    """The cells' return (noise units; (m, n)) of m realisations of a density whose ``values`` (noise units per m;
    (n, 8)) at the nodes of :func:`cell_nodes` of the cells [``lower``, ``upper``] (m; (n,)) realisation t scales
    node-wise by ``factors[t, slab]`` (``factors`` (m, S); ``slab`` (n, 8), S: factor 1), after the AC coupling of
    time constant ``tau_m`` (m; 0: DC), each realisation filtered on its own."""
    half = 0.5 * (upper - lower)
    density = _realised(np.ascontiguousarray(values, np.float64), np.ascontiguousarray(factors, np.float64),
                        np.ascontiguousarray(slab, np.int64), half)  # fmt: skip
    if tau_m > 0:
        inside = half > 0
        m, k = len(density), int(inside.sum())
        filtered = highpass_slabs(density[:, inside].ravel(), np.tile(lower[inside], m), np.tile(upper[inside], m),
                                  np.repeat(np.arange(m), k), tau_m)  # fmt: skip
        density[:, inside] = filtered.reshape(m, k)
    return density


@numba.njit(cache=True, nogil=True)
def _realised(values, factors, slab, half):
    """(m, n): ``sum_j values[c, j] factors[t, slab[c, j]] weight_j half[c]`` for each realisation t and cell c
    with ``half[c]`` > 0 (0 elsewhere); a slab index past the factors' is factor 1 (:func:`realised_density`)."""
    m, n, s = len(factors), len(values), factors.shape[1]
    out = np.zeros((m, n))
    for t in range(m):
        for c in range(n):
            if half[c] > 0:
                total = 0.0
                for j in range(values.shape[1]):
                    total += values[c, j] * (factors[t, slab[c, j]] if slab[c, j] < s else 1.0) * _WEIGHTS[j]
                out[t, c] = total * half[c]
    return out


def table_of_cells(density: np.ndarray, dx_m: float, label: int | np.ndarray, floor: float = 0.0) -> VolumeTable:
    """The table of the cells' return ``density`` (noise units, after the AC coupling; index i: cell i - REACH) on
    the grid of step ``dx_m`` (m): waveform, cut rows and the support where the waveform exceeds ``floor``."""
    return tables_of_cells(np.asarray(density)[None, :], dx_m, label, floor)[0]


def tables_of_cells(density: np.ndarray, dx_m: float, label: int | np.ndarray, floor: float = 0.0) -> list[VolumeTable]:
    """:func:`table_of_cells` of each row of ``density`` (m, n) at once (noise units), all with ``label`` (one, or
    (n,) per cell) and ``floor`` (noise units)."""
    density = np.ascontiguousarray(density, np.float64)
    wave, span = _waves(density, float(floor))
    k0, k1 = span[:, 0] - REACH, span[:, 1] - REACH
    first = np.maximum(k0 - REACH + 1, 0)
    count = np.where(k1 > k0, k1 + REACH + 2 - first, 0)
    end = np.cumsum(count)
    cut = _cut_rows(density, first, count, end - count, np.empty((int(count.sum()), 2 * REACH)))  # numpy's: huge pages
    label = np.broadcast_to(np.asarray(label, np.uint8), (density.shape[1],))
    return [VolumeTable(float(dx_m), density[t], wave[t], cut[end[t] - count[t] : end[t]], int(first[t]),
                        label.copy(), (int(k0[t]), int(k1[t]))) for t in range(len(density))]  # fmt: skip


@numba.njit(cache=True, nogil=True, inline="always")
def _first_row(density, first, row):
    """Row ``first`` of the cut rows of ``density`` (one table's; see :func:`_cut_rows`) into ``row``, summed."""
    for o in range(2 * REACH):
        s = 0.0
        for q in range(1, 2 * REACH + 1 - o):  # cell first - q reaches samples o <= 2 REACH - q of the row
            i = first - q + REACH
            if 0 <= i < len(density):
                s += density[i] * _KERNEL[q + o]
        row[o] = s


@numba.njit(cache=True, nogil=True, inline="always")
def _next_row(density, k, row, out):
    """The cut row of boundary k + 1 into ``out`` from that of k (``row``; see :func:`_cut_rows`)."""
    i = k + REACH
    d = density[i] if 0 <= i < len(density) else 0.0
    for o in range(2 * REACH - 1):
        out[o] = row[o + 1] + d * _KERNEL[o + 1]
    out[2 * REACH - 1] = d * _KERNEL[2 * REACH]


@numba.njit(cache=True, nogil=True)
def _cut_rows(density, first, count, origin, cut):
    """Each table t's (a row of ``density``) cut rows K = first[t] .. first[t] + count[t] - 1 into rows origin[t] ..
    of ``cut``: ``cut[i, o] = sum_{k < K} density(k) kernel(K - REACH + o - k)`` (module doc; density(k) is
    ``density[t, k + REACH]``, 0 outside), the first row summed, each next one from the last as
    ``cut_{K+1}[o] = cut_K[o + 1] + density(K) kernel(o + 1 - REACH)`` (cut_K[2 REACH] = 0: the kernel ends at
    REACH)."""
    row, nxt = np.empty(2 * REACH), np.empty(2 * REACH)
    for t in range(len(count)):
        for r in range(count[t]):
            if r == 0:
                _first_row(density[t], first[t], row)
            else:
                _next_row(density[t], first[t] + r - 1, row, nxt)
                row, nxt = nxt, row
            cut[origin[t] + r, :] = row
    return cut


@numba.njit(cache=True, nogil=True)
def _waves(density, floor):
    """Each row of ``density`` convolved with the pulse (module doc: ``wave``, index i: sample i - REACH), 0 outside
    its support, and the support [i0, i1) (indices; (0, 0): none) where it exceeds ``floor``. Sample k is the cut
    row of boundary k + REACH at o = 0 plus the cell k + REACH, which reaches it at the kernel's end."""
    m, n = density.shape
    wave = np.zeros((m, n))
    span = np.zeros((m, 2), np.int64)
    row, nxt = np.empty(2 * REACH), np.empty(2 * REACH)
    for t in range(m):
        d = density[t]
        _first_row(d, 0, row)
        i0, i1 = -1, 0
        for i in range(n):
            w = row[0] + (d[i + REACH] * _KERNEL[0] if i + REACH < n else 0.0)
            wave[t, i] = w
            if w > floor:
                i0 = i if i0 < 0 else i0
                i1 = i + 1
            _next_row(d, i, row, nxt)
            row, nxt = nxt, row
        if i0 < 0:
            wave[t] = 0.0
        else:
            wave[t, :i0] = 0.0
            wave[t, i1:] = 0.0
            span[t, 0], span[t, 1] = i0, i1
    return wave, span


class Volume(NamedTuple):
    """The volume layers of a batch's beams as the echo kernel reads them: T tables, each its support's samples
    and its cut rows, one after the other; and per beam (N) and layer (L) the table (-1: none), the scale
    (two-way transmission the table leaves out, e.g. a dirty cover's) and the range of the hard target that cuts
    it (m; inf: none)."""

    wave: np.ndarray  # (W,) the tables' support samples: sample j of table t at origin[t] + j
    label: np.ndarray  # (W,) uint8, as wave
    origin: np.ndarray  # (T,) int64
    cut: np.ndarray  # (M, 2 REACH) the tables' cut rows: boundary row k of table t at cut_origin[t] + k
    cut_first: np.ndarray  # (T,) int64, the first boundary row
    cut_end: np.ndarray  # (T,) int64, past the last boundary row
    cut_origin: np.ndarray  # (T,) int64
    support: np.ndarray  # (T, 2) int64
    peak: np.ndarray  # (T,) the highest sample of wave
    block_max: np.ndarray  # (B,) per BLOCK samples of a table's support, the largest |wave| or |cut row| there
    block_origin: np.ndarray  # (T,) int64: block k // BLOCK of table t at block_origin[t] + k // BLOCK
    dx: float  # m, the grid's step
    table: np.ndarray  # (N, L) int64
    scale: np.ndarray  # (N, L)
    hit_m: np.ndarray  # (N, L)


def stack_volume(tables: list[VolumeTable], table: np.ndarray, scale: np.ndarray, hit_m: np.ndarray) -> Volume:
    """:class:`Volume` of ``tables`` (one grid step) with per beam and layer ``table`` (index into ``tables``, -1:
    none), ``scale`` and ``hit_m`` (m), each (N, L). The tables' stacked arrays are kept for the next batches of
    the same tables (a region builds its tables once per weather state)."""
    return Volume(*_stacked(tuple(tables)), np.ascontiguousarray(table, np.int64),
                  np.ascontiguousarray(scale, np.float64), np.ascontiguousarray(hit_m, np.float64))  # fmt: skip


_STACKS: dict[tuple[int, ...], tuple] = {}  # ids of the tables -> (the tables, their stacked arrays)
_STACKS_KEPT = 8
_STACKS_LOCK = threading.Lock()


def _stacked(tables: tuple[VolumeTable, ...]) -> tuple:
    """The fields of :class:`Volume` from ``wave`` to ``dx`` for ``tables``, stacked once: the last
    ``_STACKS_KEPT`` stacks are kept, each holding its tables (so their ids stay theirs)."""
    key = tuple(id(t) for t in tables)
    kept = _STACKS.get(key)
    if kept is not None:
        return kept[1]
    steps = {t.dx_m for t in tables}
    if len(steps) > 1:
        raise ValueError(f"volume tables on different grids: steps {sorted(steps)} m")
    support = np.array([t.support for t in tables], np.int64).reshape(-1, 2)
    width = np.maximum(support[:, 1] - support[:, 0], 0)
    base = 1 + np.concatenate([[0], np.cumsum(width)[:-1]]).astype(np.int64)  # after a padding sample
    rows = np.array([len(t.cut) for t in tables], np.int64)
    cut_base = 1 + np.concatenate([[0], np.cumsum(rows)[:-1]]).astype(np.int64)
    cut_first = np.array([t.cut_first for t in tables], np.int64)
    part = [slice(k0 + REACH, k0 + REACH + w) for (k0, _), w in zip(support, width)]
    blocks = [_block_envelope(t.wave, t.cut, t.cut_first, k0, k1) for t, (k0, k1) in zip(tables, support)]
    block_base = 1 + np.concatenate([[0], np.cumsum([len(b) for b in blocks])[:-1]]).astype(np.int64)
    stacked = (np.concatenate([[0.0]] + [t.wave[p] for t, p in zip(tables, part)]),
               np.concatenate([np.zeros(1, np.uint8)] + [t.label[p] for t, p in zip(tables, part)]),
               base - support[:, 0], np.concatenate([np.zeros((1, 2 * REACH))] + [t.cut for t in tables]),
               cut_first, cut_first + rows, cut_base - cut_first, support,
               np.array([t.wave.max(initial=0.0) for t in tables]), np.concatenate([[0.0]] + blocks),
               block_base - support[:, 0] // BLOCK, float(steps.pop()))  # fmt: skip
    with _STACKS_LOCK:  # batches are detected on worker threads
        while len(_STACKS) >= _STACKS_KEPT:
            _STACKS.pop(next(iter(_STACKS)))
        _STACKS[key] = (tables, stacked)
    return stacked


@numba.njit(cache=True, nogil=True)
def _block_envelope(wave, cut, cut_first, k0, k1):
    """Per block (k // BLOCK, from k0 // BLOCK to (k1 - 1) // BLOCK) of a table's support [k0, k1) (samples): the
    largest magnitude there of its ``wave`` (index k + REACH) and of each of its ``cut`` rows (row i: boundary
    cut_first + i, sample k at column k - boundary + REACH)."""
    if k1 <= k0:
        return np.zeros(0)
    b0 = k0 // BLOCK
    out = np.zeros((k1 - 1) // BLOCK - b0 + 1)
    for k in range(k0, k1):
        out[k // BLOCK - b0] = max(out[k // BLOCK - b0], abs(wave[k + REACH]))
    for i in range(cut.shape[0]):
        boundary = cut_first + i
        for o in range(2 * REACH):
            k = boundary - REACH + o
            if k0 <= k < k1:
                out[k // BLOCK - b0] = max(out[k // BLOCK - b0], abs(cut[i, o]))
    return out


def empty_volume(n_beams: int = 0) -> Volume:
    """A :class:`Volume` without layers (what the echo kernel reads for a batch without volume returns)."""
    none = np.zeros(0, np.int64)
    return Volume(np.zeros(1), np.zeros(1, np.uint8), none, np.zeros((1, 2 * REACH)), none, none, none,
                  np.zeros((0, 2), np.int64), np.zeros(0), np.zeros(1), none, 0.0, np.full((n_beams, 0), -1, np.int64),
                  np.zeros((n_beams, 0)), np.zeros((n_beams, 0)))  # fmt: skip


@numba.njit(cache=True, inline="always")
def _cut_index(volume, t, hit_m):
    """(K, f): the hit at ``hit_m`` (m) lies at fraction f between the cell boundaries of rows K and K + 1 of table t;
    K = -1 when the hit is beyond the support's last row (no truncation)."""
    u = hit_m / volume.dx + 0.5
    if not u < volume.support[t, 1] + REACH:  # also inf, nan
        return -1, 0.0
    u = max(u, 0.0)
    k = int(np.floor(u))
    return k, u - k


@numba.njit(cache=True, inline="always")
def _layer(volume, b, layer):
    """(table, scale, support start, support end, cut row K, fraction f) of beam b's layer (see :func:`_cut_index`);
    table -1: the beam has no such layer (no table, or scale 0)."""
    t = volume.table[b, layer]
    scale = volume.scale[b, layer]
    if t < 0 or not scale > 0.0:
        return -1, 0.0, 0, 0, -1, 0.0
    k, f = _cut_index(volume, t, volume.hit_m[b, layer])
    return t, scale, volume.support[t, 0], volume.support[t, 1], k, f


@numba.njit(cache=True, inline="always")
def _reached(volume, b, layer):
    """(table, scale, first sample, past the last sample) where beam b's layer may be non-zero: its support, up to
    where its cut rows end (k + 2 + REACH); table -1: no such layer."""
    t, scale, lo, hi, k, _ = _layer(volume, b, layer)
    if k >= 0:
        hi = min(hi, k + 2 + REACH)
    return t, scale, lo, hi


@numba.njit(cache=True, nogil=True)
def volume_window(volume, b):
    """[j0, j1): the samples where beam b's volume may be non-zero (j1 <= j0: none) and a bound on its value."""
    j0, j1, bound = 1 << 62, -(1 << 62), 0.0
    if b >= volume.table.shape[0]:
        return j0, j1, bound
    for layer in range(volume.table.shape[1]):
        t, scale, lo, hi = _reached(volume, b, layer)
        if t >= 0 and hi > lo:
            j0, j1 = min(j0, lo), max(j1, hi)
            bound += scale * volume.peak[t]
    return j0, j1, bound


@numba.njit(cache=True, nogil=True)
def uncut_end(volume, b):
    """The first sample of beam b where a layer's cut rows begin (k - REACH of :func:`_cut_index`): in front of
    it :func:`fill_volume` reads every layer as ``scale * wave``, as for a beam without a hard target."""
    end = 1 << 62
    for layer in range(volume.table.shape[1]):
        t, _, _, _, k, _ = _layer(volume, b, layer)
        if t >= 0 and k >= 0:
            end = min(end, k - REACH)
    return end


@numba.njit(cache=True, nogil=True)
def fill_block_bounds(volume, b, first_block, n, bounds):
    """Into bounds[:n], for beam b's blocks first_block..first_block + n (block q: samples q BLOCK .. q BLOCK +
    BLOCK - 1): a bound on the magnitude of its volume (:func:`fill_volume`) there, the sum over its layers of the
    scale times INTERPOLATION_GAIN times the table's block envelope, for the blocks each layer may reach."""
    bounds[:n] = 0.0
    for layer in range(volume.table.shape[1]):
        t, scale, lo, hi = _reached(volume, b, layer)
        if t < 0 or hi <= lo:
            continue
        gain = INTERPOLATION_GAIN * scale
        for q in range(max(lo // BLOCK - first_block, 0), min((hi - 1) // BLOCK - first_block + 1, n)):
            bounds[q] += gain * volume.block_max[volume.block_origin[t] + first_block + q]
    return bounds


@numba.njit(cache=True, nogil=True)
def fill_volume(volume, b, first, n, values, labels):
    """Beam b's volume (the sum of its layers, each scaled and cut at its hit) at samples first..first + n into
    values[:n], and the label of the layer contributing most at each into labels[:n]."""
    values[:n] = 0.0
    labels[:n] = 0
    wave, cut, label = borrow(volume.wave), borrow(volume.cut), borrow(volume.label)  # the caller's (core.borrow)
    for layer in range(volume.table.shape[1]):
        t, scale, lo, hi, k, f = _layer(volume, b, layer)
        if t < 0:
            continue
        w0, c0, c_first, c_end = volume.origin[t], volume.cut_origin[t], volume.cut_first[t], volume.cut_end[t]
        g0, g1, g2 = 0.5 * (f - 1.0) * (f - 2.0), -f * (f - 2.0), 0.5 * f * (f - 1.0)
        i0 = max(lo - first, 0)
        if k < 0:
            for i in range(i0, min(hi - first, n)):
                v = scale * wave[w0 + first + i]
                if v > values[i]:
                    labels[i] = label[w0 + first + i]
                values[i] += v
            continue
        # in front of k - REACH the three rows are the waveform; behind k + 2 + REACH all are 0 (adds nothing)
        i1 = min(max(k - REACH - first, i0), min(hi - first, n))
        for i in range(i0, i1):  # the three rows' weights sum to 1: the waveform, as in front of no cut
            v = scale * wave[w0 + first + i]
            if v > values[i]:
                labels[i] = label[w0 + first + i]
            values[i] += v
        # from k - REACH on, in five spans where each row K = k + d is the waveform (in front of K - REACH), its
        # cut row (to K + REACH; 0 for a row outside c_first..c_end) or 0 (behind): span s starts at k - REACH + s
        # (s <= 2) or k + REACH + s - 3, and row d is the waveform in spans s < d, its cut row in d..d + 2
        i_end = min(min(hi, k + 2 + REACH) - first, n)
        m0, m1, m2 = _row_mode(k, c_first, c_end), _row_mode(k + 1, c_first, c_end), _row_mode(k + 2, c_first, c_end)
        for span in range(5):
            i_a = max(i1, _span_start(k, span) - first)
            i_b = min(i_end, _span_start(k, span + 1) - first)
            d0 = m0 if span <= 2 else 0
            d1 = 1 if span < 1 else (m1 if span <= 3 else 0)
            d2 = 1 if span < 2 else m2
            if d0 == 2 and d1 == 2 and d2 == 2:  # most of the samples: the three cut rows, without a branch
                for i in range(i_a, i_b):
                    j = first + i
                    v = scale * (g0 * cut[c0 + k, j - k + REACH] + g1 * cut[c0 + k + 1, j - k - 1 + REACH]
                                 + g2 * cut[c0 + k + 2, j - k - 2 + REACH])
                    if v > values[i]:
                        labels[i] = label[w0 + j]
                    values[i] += v
                continue
            for i in range(i_a, i_b):  # (the arrays read here, not in a helper: a helper's arrays are counted)
                j = first + i
                x0 = cut[c0 + k, j - k + REACH] if d0 == 2 else (wave[w0 + j] if d0 == 1 else 0.0)
                x1 = cut[c0 + k + 1, j - k - 1 + REACH] if d1 == 2 else (wave[w0 + j] if d1 == 1 else 0.0)
                x2 = cut[c0 + k + 2, j - k - 2 + REACH] if d2 == 2 else (wave[w0 + j] if d2 == 1 else 0.0)
                v = scale * (g0 * x0 + g1 * x1 + g2 * x2)
                if v > values[i]:
                    labels[i] = label[w0 + j]
                values[i] += v
    return values


@numba.njit(cache=True, inline="always")
def _span_start(k, span):
    """The first sample of :func:`fill_volume`'s span 0-5 behind cut row k: k - REACH + span, then k + REACH + span
    - 3 (span 5 starts where the three rows have ended)."""
    return k - REACH + span if span <= 2 else k + REACH + span - 3


@numba.njit(cache=True, inline="always")
def _row_mode(k, c_first, c_end):
    """How :func:`fill_volume` reads boundary row k where it is cut: 2 its cut row, 0 none (a row outside
    c_first..c_end: its samples all lie outside the support)."""
    return 2 if c_first <= k < c_end else 0
