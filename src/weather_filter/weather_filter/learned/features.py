"""Per-point features of paper 4 (thesis lines 2770-2795) for the learned filter.

Per detection: x, y, echo, layer (channel), EPW; counts of the bird's-eye
histogram cell holding it for five cell shapes (radial 1 deg, 10x10 cm,
20 cm x 2 m, 4 m x 10 cm, 50x50 cm); |radial count now - radial count of the
previous frame|; and the small-feature (10 cm) histogram convolved with the
paper's horizontal (A2), corner (A3), corner rotated 90 deg and impulse (A1)
matrices (Appendix B), read at the detection's cell. We add z, intensity and
range (the paper's sensor had no usable intensity in its feature list; ours does).

Beyond the paper (model v4): features of the scan's range image and of the height in the 50 cm cell, which
do not depend on the scan's resolution the way the histogram counts do. The range image has a row per
channel and a column per azimuth step (the step is read off the frame: the median azimuth difference
between consecutive first echoes of the fullest channel), each cell holding up to 4 echoes. Per point,
with r its 3-D range and relative differences |r' - r| / r:

* ``ri_ring``: log10 of the smallest relative difference to a return of the same channel within
  ``RI_COLUMNS`` columns (1e-3 .. 1: log10 in [-3, 0]; 0 without such a return);
* ``ri_cross``: the same for the neighbouring channels (+-1) within ``RI_COLUMNS`` columns;
* ``ri_close``: returns in that window (channels +-``RI_CHANNELS``, columns +-``RI_COLUMNS``, own cell
  excluded) within 3 % of r; ``ri_occ``: occupied cells of the window;
* ``ri_behind`` / ``ri_front``: returns of the point's own cell farther / nearer than it, and
  ``ri_gap_behind``: log10 of the relative gap to the nearest one behind (0 without);
* ``dz_min`` / ``dz_max``: height above the lowest and below the highest point of its 50x50 cm cell.

A snowflake or spray droplet has no neighbour at its range along or across the scan lines, a surface has;
the counts-per-cell features alone told a fog-dimmed road with missing returns from snow at the same
range poorly on the 128-channel scans.

Histograms cover |x|, |y| <= ``extent_m`` (sensor frame); points outside get
the counts of the border cell clipped to, and zero convolution responses.
Computed by numba-compiled passes, each point's features bit-identical to the direct definitions above (CPU
time min on a 120k-point os1_128_2048 frame, 2 shared cores; ``python -m weather_filter.stage_timing``): the
point fields copied to the feature columns (0.7 ms); the azimuth, a vectorised polynomial
(:mod:`weather_filter.learned.azimuth`, 0.14 ms; ``np.arctan2`` per point took 2.4 ms); histograms, cell heights and
convolutions (once per occupied cell, in integers: 4.4 ms); the azimuth step (0.7 ms); the range image (~7 ms:
a dense first-echo plane read without branches by a window of constant size, later echoes only where the
window holds a crowded cell, the logarithms vectorised by :mod:`weather_filter.learned.log10f`).

Why one module of ~410 lines: the per-point feature vector is one definition (column order, units,
the trained model depends on it bit for bit); its stages share the cell tables.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
from numba import njit

from weather_filter.learned.azimuth import AZIMUTH_ERROR_RAD, approx_azimuth
from weather_filter.learned.log10f import log10_clamped

IMPULSE = np.array([[-1, -1, -1], [-1, 4, -1], [-1, -1, -1]], dtype=np.float32)  # A1
HORIZONTAL = np.array([[-1] * 10, [2] * 10, [-1] * 10], dtype=np.float32)  # A2
CORNER = np.array(
    [[-1, -1, -1, -1, -1], [-1, 2, 2, 2, -1], [-1, -1, 2, 2, -1], [-1, -1, -1, 2, -1], [-1, -1, -1, 2, -1]],
    dtype=np.float32,
)  # A3

#: (name, cell size x m, cell size y m) of the Cartesian bird's-eye histograms.
CELL_SHAPES = (("small", 0.1, 0.1), ("rear", 0.2, 2.0), ("side", 4.0, 0.1), ("middle", 0.5, 0.5))
N_SHAPES = len(CELL_SHAPES)
FEATURE_NAMES = (
    "x", "y", "z", "echo", "channel", "epw", "intensity", "range",
    "n_radial", "n_small", "n_rear", "n_side", "n_middle", "d_radial",
    "conv_horizontal", "conv_corner", "conv_corner_rot90", "conv_impulse",
    "ri_ring", "ri_cross", "ri_close", "ri_occ", "ri_behind", "ri_gap_behind", "ri_front", "dz_min", "dz_max",
)  # fmt: skip
#: Columns (+-) and channels (+-) of the range-image window around a point.
RI_COLUMNS = 2
RI_CHANNELS = 2
#: Echoes kept per range-image cell; relative range difference counted as "close" in ``ri_close``.
RI_ECHOES = 4
RI_CLOSE = 0.03
#: Azimuth step used when a frame gives none (fewer than 10 first echoes in its fullest channel).
DEFAULT_STEP_DEG = 0.2
#: Largest range image (cells): a coarser step is used beyond it (a corrupt channel or azimuth field).
MAX_RI_CELLS = 1 << 22
REQUIRED_FIELDS = frozenset({"x", "y", "z", "echo", "channel", "epw", "intensity"})
#: Column values of fields a single-return cloud lacks (:mod:`weather_filter.learned.single_return`).
ABSENT_FIELD_VALUES = {"echo": 1, "epw": 0.0}


class CellGrids(NamedTuple):
    """The Cartesian bird's-eye histograms of :data:`CELL_SHAPES` over |x|, |y| <= ``extent`` (m, sensor frame):
    inverse cell sizes (1/m) and cells along x and y, one entry per shape; input of :func:`_point_features`."""

    extent: float
    inv_cxs: np.ndarray  # float64
    inv_cys: np.ndarray  # float64
    nxs: np.ndarray  # int64
    nys: np.ndarray  # int64


def _grid_shape(cx: float, cy: float, extent_m: float) -> tuple[int, int]:
    return int(np.ceil(2 * extent_m / cx)), int(np.ceil(2 * extent_m / cy))


def radial_histogram(points: np.ndarray, bin_deg: float = 1.0) -> tuple[np.ndarray, np.ndarray]:
    """Counts per azimuth bin over [-180, 180) deg and each point's bin (float64 azimuth, as the extractor)."""
    az = np.degrees(np.arctan2(points["y"].astype(np.float64), points["x"].astype(np.float64)))
    n_bins = int(round(360 / bin_deg))
    idx = np.clip(((az + 180.0) / bin_deg).astype(np.int64), 0, n_bins - 1)
    return np.bincount(idx, minlength=n_bins), idx


def _kernel_taps() -> tuple[np.ndarray, np.ndarray]:
    """The non-zero entries of the four kernels as taps (row offset, col offset, weight) from the centre cell
    (rows//2, cols//2), as ``ndimage.correlate``; kernel k's taps are rows ``start[k]:start[k + 1]``."""
    taps, start = [], [0]
    for kernel in (HORIZONTAL, CORNER, np.rot90(CORNER), IMPULSE):
        rows, cols = kernel.shape
        for a, b in zip(*np.nonzero(kernel)):
            taps.append((a - rows // 2, b - cols // 2, kernel[a, b]))
        start.append(len(taps))
    return np.array(taps, np.float64), np.array(start, np.int64)


@njit(cache=True, nogil=True, fastmath=True)
def _point_features(out, grids, n_radial, inv_bin_deg, previous, has_previous, taps, start, azimuth):
    """Feature columns 7-17 and 25-26 (see :class:`PointFeatures`), from the point fields (m, sensor frame) in
    columns 0-6 of ``out`` and the histograms of ``grids`` (:class:`CellGrids`); returns the radial histogram.
    ``azimuth`` holds :func:`approx_azimuth` on entry, and where that leaves a point's radial bin in doubt, the
    exact ``np.arctan2`` (rad) on return. Convolutions follow
    ``ndimage.correlate`` (zero outside the grid, kernel centre at (rows//2, cols//2)), from the taps of
    :func:`_kernel_taps`, computed once per occupied cell. Writes ``dz_min`` / ``dz_max`` (m) in the 4th (50 cm)
    grid."""
    extent, inv_cxs, inv_cys, nxs, nys = grids
    x, y, z = out[:, 0], out[:, 1], out[:, 2]
    n = len(x)
    n_shapes = N_SHAPES  # a constant: the loops over the shapes unroll
    radial = np.zeros(n_radial, np.int64)
    ridx = np.empty(n, np.int32)
    cells = np.empty((n_shapes, n), np.int32)
    offsets = np.zeros(n_shapes + 1, np.int64)
    for s in range(n_shapes):
        offsets[s + 1] = offsets[s] + nxs[s] * nys[s]
    grids = np.zeros(offsets[n_shapes], np.int32)
    rad2deg = 180.0 / np.pi
    doubt = np.empty(n, np.bool_)
    for i in range(n):  # bins and cells (no calls, no scatter: vectorised)
        xi, yi = np.float64(x[i]), np.float64(y[i])
        out[i, 7] = np.sqrt(xi * xi + yi * yi)
        a = azimuth[i]
        b = min(max(int(((a - AZIMUTH_ERROR_RAD) * rad2deg + 180.0) * inv_bin_deg), 0), n_radial - 1)
        b_hi = min(max(int(((a + AZIMUTH_ERROR_RAD) * rad2deg + 180.0) * inv_bin_deg), 0), n_radial - 1)
        doubt[i] = (yi == 0) | (b != b_hi)
        ridx[i] = b
        for s in range(n_shapes):
            ny = nys[s]
            ix = min(max(int((xi + extent) * inv_cxs[s]), 0), nxs[s] - 1)
            iy = min(max(int((yi + extent) * inv_cys[s]), 0), ny - 1)
            cells[s, i] = ix * ny + iy
    for i in range(n):  # the exact azimuth where the bin is in doubt, and the histograms
        if doubt[i]:
            a = np.arctan2(np.float64(y[i]), np.float64(x[i]))
            azimuth[i] = a
            b = int((a * rad2deg + 180.0) * inv_bin_deg)
            ridx[i] = min(max(b, 0), n_radial - 1)
        radial[ridx[i]] += 1
        for s in range(n_shapes):
            grids[offsets[s] + cells[s, i]] += 1
    for i in range(n):
        out[i, 8] = radial[ridx[i]]
    for i in range(n):
        out[i, 13] = abs(radial[ridx[i]] - previous[ridx[i]]) if has_previous else 0.0
    for s in range(n_shapes):
        for i in range(n):
            out[i, 9 + s] = grids[offsets[s] + cells[s, i]]
    # height above the lowest / below the highest point of the 50 cm (4th) cell
    n_mid = nxs[3] * nys[3]
    zlo = np.full(n_mid, np.float32(np.inf))
    zhi = np.full(n_mid, np.float32(-np.inf))
    for i in range(n):
        c = cells[3, i]
        zlo[c] = min(zlo[c], z[i])
        zhi[c] = max(zhi[c], z[i])
    for i in range(n):
        c = cells[3, i]
        out[i, 25] = z[i] - zlo[c]
        out[i, 26] = zhi[c] - z[i]
    # convolutions on the small (first) grid, once per occupied cell (far fewer cells than points), in integers
    # (the kernels' weights and the counts are; exact), without bounds checks away from the grid's border
    nx0, ny0 = nxs[0], nys[0]
    n_kernels = len(start) - 1
    tap_i = np.empty(len(taps), np.int64)
    tap_j = np.empty(len(taps), np.int64)
    tap_w = np.empty(len(taps), np.int64)
    for t in range(len(taps)):
        tap_i[t], tap_j[t], tap_w[t] = int(taps[t, 0]), int(taps[t, 1]), int(taps[t, 2])
    margin = max(np.abs(tap_i).max(), np.abs(tap_j).max()) if len(taps) else 0
    tap_offset = tap_i * ny0 + tap_j
    slot = np.full(nx0 * ny0, -1, np.int32)
    responses = np.empty((n, n_kernels), np.float32)
    used = 0
    for i in range(n):
        if not (abs(np.float64(x[i])) < extent and abs(np.float64(y[i])) < extent):
            for k in range(n_kernels):
                out[i, 14 + k] = 0.0
            continue
        c = cells[0, i]
        if slot[c] < 0:
            slot[c] = used
            ci, cj = c // ny0, c % ny0
            interior = margin <= ci < nx0 - margin and margin <= cj < ny0 - margin
            for k in range(n_kernels):
                acc = 0
                if interior:
                    for t in range(start[k], start[k + 1]):
                        acc += tap_w[t] * grids[c + tap_offset[t]]
                else:
                    for t in range(start[k], start[k + 1]):
                        gi = ci + tap_i[t]
                        gj = cj + tap_j[t]
                        if 0 <= gi < nx0 and 0 <= gj < ny0:
                            acc += tap_w[t] * grids[gi * ny0 + gj]
                responses[used, k] = acc
            used += 1
        r = slot[c]
        for k in range(n_kernels):
            out[i, 14 + k] = responses[r, k]
    return radial


@njit(cache=True, nogil=True)
def _first_echo_azimuths(x, y, channel, echo, n_channels):
    """``np.arctan2(y, x)`` (rad) of the first echoes (echo <= 1) of the channel with the most of them."""
    counts = np.zeros(n_channels, np.int64)
    for i in range(len(x)):
        if echo[i] <= 1:
            counts[channel[i]] += 1
    best = np.argmax(counts)
    sel = np.empty(counts[best], np.float64)
    j = 0
    for i in range(len(x)):
        if echo[i] <= 1 and channel[i] == best:
            sel[j] = np.arctan2(np.float64(y[i]), np.float64(x[i]))
            j += 1
    return sel


@njit(cache=True, nogil=True)
def _median_gap(azimuths):
    """Median difference (rad) between consecutive sorted ``azimuths`` above 1e-4 rad; 0 if fewer than 5."""
    diffs = np.diff(azimuths)
    diffs = diffs[diffs > 1e-4]
    if len(diffs) < 5:
        return 0.0
    return np.median(diffs)


def azimuth_step(x, y, channel, echo, n_channels: int) -> float:
    """Median azimuth difference (rad) between consecutive first echoes of the channel with the most
    first echoes (differences below 1e-4 rad ignored; azimuths ``np.arctan2(y, x)``); 0 if fewer than 10.
    (numpy sorts: numba's quicksort is ~8x slower on a channel's nearly sorted azimuths.)"""
    azimuths = np.sort(_first_echo_azimuths(x, y, channel, echo, n_channels))
    return 0.0 if len(azimuths) < 10 else float(_median_gap(azimuths))


#: Range stored in the empty cells of a range image's first-echo plane (m): finite (fastmath assumes no inf), and
#: its relative difference to any return is far above 1, so it changes no minimum and counts as no close return.
_EMPTY_RANGE = np.float32(1e30)


@njit(inline="always", fastmath=True)
def _first_echoes(first, c, stride, ri, inv, close, columns, channels):
    """(ring, cross, n_close, occupied) of :func:`_range_image_features` over the first echoes of the window of
    cell ``c``, the own cell counted in ``n_close`` and ``occupied`` and left out of ``ring``."""
    ring = np.float32(1.0)
    cross = np.float32(1.0)
    n_close = 0
    occupied = 0
    for db in range(-columns, columns + 1):
        q0 = c + db * stride
        if db != 0:
            ring = min(ring, abs(first[q0] - ri) * inv)
        if channels >= 1:
            cross = min(cross, min(abs(first[q0 - 1] - ri) * inv, abs(first[q0 + 1] - ri) * inv))
        for q in range(q0 - channels, q0 + channels + 1):
            occupied += first[q] < _EMPTY_RANGE
            n_close += abs(first[q] - ri) * inv < close
    return ring, cross, n_close, occupied


@njit(cache=True, nogil=True, fastmath=True)
def _range_image_features(out, azimuth, step, n_channels, n_echoes, columns, channels, close):
    """``ri_*`` columns (18-24) of ``out`` (whose columns 0-2 and 4 hold x, y, z in m and the channel; ``ri_ring``
    and ``ri_cross`` as relative differences, the caller takes their :func:`log10_clamped`) from a
    range image of ``n_channels`` rows and 2 pi / ``step`` columns (``step`` and ``azimuth`` in rad, wrapping
    round; ``azimuth`` from :func:`approx_azimuth`, the exact one taken where the column is in doubt), ``n_echoes``
    ranges per cell (further ones of a crowded cell are dropped).

    Stored column-major (a column's channels adjacent: the order points arrive in) with ``channels`` empty rows
    and ``columns`` wrapped columns of padding on each side, so the window needs no bounds checks. A cell's first
    range is in ``first`` (:data:`_EMPTY_RANGE` if empty), so the window's first echoes are read without
    branches; its later ones (``extra``) are visited only for windows holding a crowded cell."""
    n = out.shape[0]
    n_cols = max(int(2.0 * np.pi / step + 0.5), 1)
    stride = n_channels + 2 * channels
    n_cells = (n_cols + 2 * columns) * stride
    n_extra = max(n_echoes - 1, 1)
    counts = np.zeros(n_cells, np.int8)
    first = np.full(n_cells, _EMPTY_RANGE)
    extra = np.empty((n_cells, n_extra), np.float32)
    cell = np.empty(n, np.int64)
    r = np.empty(n, np.float32)
    inv_step = 1.0 / step
    for i in range(n):
        xi, yi, zi = np.float64(out[i, 0]), np.float64(out[i, 1]), np.float64(out[i, 2])
        r[i] = np.sqrt(xi * xi + yi * yi + zi * zi)
        a = azimuth[i]
        b = int((a - AZIMUTH_ERROR_RAD + np.pi) * inv_step)
        if yi == 0 or b != int((a + AZIMUTH_ERROR_RAD + np.pi) * inv_step):
            b = int((np.arctan2(yi, xi) + np.pi) * inv_step)
        if b >= n_cols:
            b -= n_cols
        b = min(max(b, 0), n_cols - 1)
        c = (b + columns) * stride + channels + np.int64(out[i, 4])
        cell[i] = c
        k = counts[c]
        if k == 0:
            first[c] = r[i]
        elif k < n_echoes:
            extra[c, k - 1] = r[i]
        counts[c] = min(k + 1, n_echoes)
    for j in range(columns):  # wrap: the last columns before the first, the first after the last
        for src, dst in ((n_cols + j, j), (columns + j, n_cols + columns + j)):
            for t in range(stride):
                counts[dst * stride + t] = counts[src * stride + t]
                first[dst * stride + t] = first[src * stride + t]
                for k in range(n_extra):
                    extra[dst * stride + t, k] = extra[src * stride + t, k]
    near_crowded = np.zeros(n_cells, np.bool_)  # cells whose window holds a crowded cell (few)
    for q in range(n_cells):
        if counts[q] > 1:
            for db in range(-columns, columns + 1):
                for dc in range(-channels, channels + 1):
                    if 0 <= q + db * stride + dc < n_cells:
                        near_crowded[q + db * stride + dc] = True
    for i in range(n):
        ri = r[i]
        inv = np.float32(1.0) / max(ri, np.float32(0.05))
        c = cell[i]
        # the point's own cell: returns behind / in front of it
        behind = 0
        front = 0
        gap = np.float32(1.0)
        for k in range(counts[c]):
            d = ((first[c] if k == 0 else extra[c, k - 1]) - ri) * inv
            if d > 1e-3:
                behind += 1
                gap = min(gap, d)
            elif d < -1e-3:
                front += 1
        # the window's first echoes (the own cell's counted, then taken off, and left out of ring); the shipped
        # window size as constants, so the compiler unrolls the window
        if columns == RI_COLUMNS and channels == RI_CHANNELS:
            ring, cross, n_close, occupied = _first_echoes(first, c, stride, ri, inv, close, RI_COLUMNS, RI_CHANNELS)
        else:
            ring, cross, n_close, occupied = _first_echoes(first, c, stride, ri, inv, close, columns, channels)
        n_close -= abs(first[c] - ri) * inv < close
        occupied -= 1
        if near_crowded[c]:  # later echoes of the window's cells but the own one
            for db in range(-columns, columns + 1):
                for dc in range(-channels, channels + 1):
                    q = c + db * stride + dc
                    if q == c:
                        continue
                    for k in range(counts[q] - 1):
                        d = abs(extra[q, k] - ri) * inv
                        n_close += d < close
                        if dc == 0:
                            ring = min(ring, d)
                        elif dc == 1 or dc == -1:
                            cross = min(cross, d)
        out[i, 18] = ring  # their log10 in one vectorised pass after (log10_clamped)
        out[i, 19] = cross
        out[i, 20] = n_close
        out[i, 21] = occupied
        out[i, 22] = behind
        out[i, 23] = np.log10(max(gap, np.float32(1e-3))) if gap < 1 else np.float32(0.0)
        out[i, 24] = front


class PointFeatures:
    """Feature extractor; keeps the previous frame's radial histogram for the frame-difference feature
    (``d_radial`` is 0 on the first frame after construction or :meth:`reset`). The histogram, convolution and
    height features come from :func:`_point_features`, the range-image ones from :func:`_range_image_features`."""

    def __init__(self, extent_m: float = 30.0, radial_bin_deg: float = 1.0, ri_columns: int = RI_COLUMNS,
                 ri_channels: int = RI_CHANNELS) -> None:  # fmt: skip
        self.extent_m = float(extent_m)
        self.ri_columns, self.ri_channels = int(ri_columns), int(ri_channels)
        self.last_step_rad: float | None = None
        self.last_azimuth: np.ndarray | None = None
        self.radial_bin_deg = float(radial_bin_deg)
        self._n_radial = int(round(360 / self.radial_bin_deg))
        shapes = [_grid_shape(cx, cy, self.extent_m) for _, cx, cy in CELL_SHAPES]
        self._cxs = np.array([cx for _, cx, _ in CELL_SHAPES], np.float64)
        self._cys = np.array([cy for _, _, cy in CELL_SHAPES], np.float64)
        self._nxs = np.array([s[0] for s in shapes], np.int64)
        self._nys = np.array([s[1] for s in shapes], np.int64)
        self._grids = CellGrids(self.extent_m, 1.0 / self._cxs, 1.0 / self._cys, self._nxs, self._nys)
        self._taps, self._tap_start = _kernel_taps()
        self._previous_radial: np.ndarray | None = None

    def reset(self) -> None:
        self._previous_radial = None

    def __call__(self, points: np.ndarray) -> np.ndarray:
        """(N, len(FEATURE_NAMES)) float32 (column-major: each feature contiguous)."""
        out = np.empty((len(FEATURE_NAMES), len(points)), np.float32).T
        previous = self._previous_radial
        has_previous = previous is not None
        if previous is None:
            previous = np.zeros(self._n_radial, np.int64)
        names = points.dtype.names or ()
        for k, name in enumerate(("x", "y", "z", "echo", "channel", "epw", "intensity")):
            # a single-return cloud without echo / EPW (the single-return model's input): echo 1, EPW 0
            out[:, k] = points[name] if name in names else ABSENT_FIELD_VALUES[name]
        azimuth = np.empty(len(points), np.float64)
        approx_azimuth(out[:, 0], out[:, 1], azimuth)
        self._previous_radial = _point_features(out, self._grids, self._n_radial, 1.0 / self.radial_bin_deg, previous,
                                                has_previous, self._taps, self._tap_start, azimuth)  # fmt: skip
        if len(points):
            channel = points["channel"]
            n_channels = int(channel.max()) + 1
            echo = points["echo"] if "echo" in names else np.ones(len(points), np.uint8)
            step = azimuth_step(out[:, 0], out[:, 1], channel, echo, n_channels)
            step = max(step if step > 0 else np.radians(DEFAULT_STEP_DEG), 2 * np.pi * n_channels / MAX_RI_CELLS)
            self.last_step_rad = float(step)
            self.last_azimuth = azimuth  # rad, for the single-return features' range image
            _range_image_features(out, azimuth, step, n_channels, RI_ECHOES, self.ri_columns, self.ri_channels,
                                  np.float32(RI_CLOSE))  # fmt: skip
            for k in (FEATURE_NAMES.index("ri_ring"), FEATURE_NAMES.index("ri_cross")):
                log10_clamped(out[:, k], out[:, k].view(np.uint32))
        return out
