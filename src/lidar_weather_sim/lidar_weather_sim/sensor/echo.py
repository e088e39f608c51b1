"""Echo decision: from candidate returns of each beam to detected echoes with EPW.

Pulse model
-----------
Every candidate return i of a beam (a sub-ray hitting the scene, or a
scatterer supplied by a region) contributes a Gaussian pulse to the beam's
received waveform, in range units (m)::

    w(r) = sum_i A_i * exp(-(r - r_i)^2 / (2 s^2)),    s = fwhm / (2 sqrt(2 ln 2))

``A_i`` is the peak amplitude from the LIDAR equation and ``T = mu + x sigma``
the threshold (thesis paper 2, eq. 3-5), both in :mod:`lidar_weather_sim.sensor.radiometry`.
The receiver compares the waveform with the threshold: each interval where w > T is one
echo. Its range is the position of the waveform's maximum inside the interval,
its EPW (echo pulse width, m) the interval's length, and its label / object id
those of the candidate contributing most at the maximum. For one isolated
pulse the EPW has the closed form ``2 s sqrt(2 ln(A / T))``: it grows with
reflectivity and shrinks when background light raises ``T``. Candidates closer
than the range resolution are merged first (power-summed at their
power-weighted range). Up to ``max_echoes`` echoes per beam are kept, in range
order, numbered from 1.

Return modes
------------
What a beam reports of its detected echoes is the return mode (:data:`~lidar_weather_sim.core.names.RETURN_MODES`),
applied by :func:`select_returns` as the sensor's firmware does before the driver's minimum-range cut:
``strongest`` the echo with the highest peak amplitude (on a tie the nearer), ``last`` the farthest,
``first`` the nearest, ``dual`` the last and the strongest; when the last is also the strongest, the
strongest of the others instead (Velodyne VLP-16 / VLP-32C manuals, "Dual Return Mode": "If the strongest
return is also the last return, then the second-strongest return is provided"), a beam with one echo gives
one point. ``all`` reports every echo. Ouster's dual return differs: the two strongest echoes, strongest
first (Ouster firmware "Return Order", default STRONGEST_TO_WEAKEST); it is not one of these modes.

Why one module of ~940 lines: the waveform, the threshold crossing and the echo selection are one
algorithm (thesis eq. 3-5) with its numba kernels beside it.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import NamedTuple

import numba
import numpy as np

from lidar_weather_sim.core import workers
from lidar_weather_sim.core.borrow import borrow
from lidar_weather_sim.core.names import RETURN_MODES
from lidar_weather_sim.core.points import ReturnType
from lidar_weather_sim.core.scratch import allocator
from lidar_weather_sim.sensor.radiometry import FWHM_TO_SIGMA, Threshold
from lidar_weather_sim.sensor.volume_prefix import VolumePrefix, build_prefix, no_prefix, prefix_echoes
from lidar_weather_sim.sensor.volume_tables import (BLOCK, INTERPOLATION_GAIN, Volume, empty_volume, fill_block_bounds,
                                                    fill_volume, volume_window)


@dataclass(frozen=True)
class Echoes:
    """Detected echoes: the runs (starts, counts) of the arrays (one per candidate), in order,
    each chunk's echoes where the kernel wrote them; ``beam`` indexes the beams of the batch."""

    beam: np.ndarray  # (E,) int64
    echo: np.ndarray  # (E,) uint8, 1-based, in range order within the beam
    range_m: np.ndarray  # (E,) float64
    amplitude: np.ndarray  # (E,) float64, waveform peak (noise units)
    epw_m: np.ndarray  # (E,) float64
    label: np.ndarray  # (E,) uint8
    object_id: np.ndarray  # (E,) uint32
    runs: tuple[np.ndarray, np.ndarray]  # (starts, counts) int64


class Candidates(NamedTuple):
    """Candidate returns, one row per candidate (C): what :func:`detect_echoes` reads."""

    beam: np.ndarray  # (C,) int64
    range_m: np.ndarray  # (C,) float64
    amplitude: np.ndarray  # (C,) float64, peak (noise units)
    label: np.ndarray  # (C,) uint8
    object_id: np.ndarray  # (C,) uint32


class Detector(NamedTuple):
    """The receiver's settings, as the detection kernels read them."""

    threshold: float  # noise units
    sigma: float  # m, the pulse's Gaussian width
    resolution: float  # m, candidates closer than this are merged
    max_echoes: int  # per beam


class EchoBuffers(NamedTuple):
    """Where the detection kernels write the echoes (the arrays of :class:`Echoes`)."""

    beam: np.ndarray
    echo: np.ndarray
    range_m: np.ndarray
    amplitude: np.ndarray
    epw_m: np.ndarray
    label: np.ndarray
    object_id: np.ndarray


class Pulses(NamedTuple):
    """One beam's merged pulses (M), in range order, with each one's :func:`_reach` (m)."""

    range_m: np.ndarray  # (M,) float64
    amplitude: np.ndarray  # (M,) float64
    reach: np.ndarray  # (M,) float64
    label: np.ndarray  # (M,) uint8
    object_id: np.ndarray  # (M,) uint32


class Work(NamedTuple):
    """A chunk's working arrays for C candidates, allocated by the caller so that the kernel borrows them
    (:mod:`lidar_weather_sim.core.borrow`)."""

    pulses: Pulses  # a beam's merged pulses
    order: np.ndarray  # (C,) int64, its candidates in range order
    isolated: np.ndarray  # (C,) int64, the echoes of isolated pulses (their EPW in closed form at the end)
    samples: np.ndarray  # (ESTIMATE_SAMPLES,) a cluster's waveform samples

    @staticmethod
    def of(size: int) -> "Work":
        """Empty arrays for ``size`` candidates."""
        return Work(Pulses(np.empty(size), np.empty(size), np.empty(size), np.empty(size, np.uint8),
                           np.empty(size, np.uint32)), np.empty(size, np.int64), np.empty(size, np.int64),
                    np.empty(ESTIMATE_SAMPLES))  # fmt: skip


def detect_echoes(
    beam: np.ndarray,
    range_m: np.ndarray,
    amplitude: np.ndarray,
    label: np.ndarray,
    object_id: np.ndarray,
    *,
    threshold: Threshold,
    fwhm_m: float,
    resolution_m: float,
    max_echoes: int,
    segments: tuple[np.ndarray, np.ndarray] | None = None,
    scratch=None,
    volume: Volume | None = None,
    shared_prefix: bool = True,
) -> Echoes:
    """Echoes of candidate returns of the beams of a batch (fastest when grouped by beam).

    Candidates with zero amplitude or non-finite range are ignored. ``segments``
    (starts, counts): the candidates are only these runs of the arrays, grouped by beam
    in beam order, as the simulator's kernels leave them (None: all of the arrays).
    With ``scratch`` (:class:`lidar_weather_sim.core.scratch.Scratch`) the echoes are views
    of its arrays, valid until its next use. ``volume``
    (:class:`~lidar_weather_sim.sensor.volume_tables.Volume`, its grid step s / 8 of this pulse): volume
    returns added to the waveforms of the beams that carry them (a beam index of the candidates is its row),
    those beams detected even without candidates. ``shared_prefix``: the volume's echoes in front of the hard
    targets found once per group of beams with the same layers (:mod:`lidar_weather_sim.sensor.volume_prefix`;
    False: every beam's sampled on its own, the same echoes bit for bit, slower).
    """
    sigma = float(fwhm_m) * FWHM_TO_SIGMA
    if volume is not None:
        beam, range_m, amplitude, label, object_id = _with_volume_beams(
            (beam, range_m, amplitude, label, object_id), segments, volume, sigma, int(max_echoes),
            float(threshold.level))  # fmt: skip
        segments = None
    beam = np.ascontiguousarray(beam, np.int64)
    if segments is None and not _ascending(beam):
        order = _beam_order(beam)
        beam, range_m, amplitude, label, object_id = (x[order] for x in (beam, range_m, amplitude, label, object_id))
    candidates = Candidates(
        beam,
        np.ascontiguousarray(range_m, np.float64),
        np.ascontiguousarray(amplitude, np.float64),
        np.ascontiguousarray(label, np.uint8),
        np.ascontiguousarray(object_id, np.uint32),
    )
    detector = Detector(float(threshold.level), sigma, float(resolution_m), int(max_echoes))
    prefix = None
    if volume is not None and shared_prefix:
        prefix = build_prefix(volume, detector, lambda group_volume: _group_echoes(group_volume, detector))
    out = _detect(candidates, detector, scratch, segments, volume, prefix)
    return Echoes(*out)


def _group_echoes(group_volume: Volume, detector: Detector) -> tuple:
    """(beam, range_m, amplitude, epw_m, label) of the echoes of each row of ``group_volume`` alone, beams
    ascending (:func:`~lidar_weather_sim.sensor.volume_prefix.build_prefix`'s ``detect``)."""
    rows, k = group_volume.table.shape[0], detector.max_echoes
    n = rows * k
    candidates = Candidates(np.repeat(np.arange(rows, dtype=np.int64), k), np.full(n, np.nan), np.zeros(n),
                            np.zeros(n, np.uint8), np.zeros(n, np.uint32))  # fmt: skip
    *arrays, (starts, counts) = _detect(candidates, detector, volume=group_volume)
    written = np.concatenate([np.arange(a, a + c) for a, c in zip(starts, counts)]).astype(np.int64)
    beam, _, range_m, amplitude, epw_m, label, _ = (x[written] for x in arrays)
    return beam, range_m, amplitude, epw_m, label


def _with_volume_beams(candidates: tuple, segments, volume: Volume, sigma: float, max_echoes: int,
                       threshold: float) -> tuple:  # fmt: skip
    """The candidates (of the runs ``segments``, if given) and ``max_echoes`` empty ones (zero amplitude) on every
    beam carrying a volume layer that may give an echo, grouped by beam (ascending, each beam's own candidates
    first): each such beam is detected, with room for its echoes. A beam without candidates whose layers stay
    below ``threshold`` (noise units) together (the kernel's bound: 1.25 times the sum of their scales times their
    tables' peaks) gives none, and is left out (rain's and snow's sky beams)."""
    if volume.dx != sigma / 8.0:
        raise ValueError(f"volume tables on a grid of {volume.dx} m, the echo stage samples every {sigma / 8.0} m")
    if segments is not None:
        runs = [slice(int(a), int(a + c)) for a, c in zip(*segments)]
        candidates = tuple(np.concatenate([x[run] for run in runs]) for x in candidates)
    n, layers = volume.table.shape
    carrying, bound = np.zeros(n, bool), np.zeros(n)
    for k in range(layers):  # layer by layer: numpy reduces an (N, L) array along L ~6x slower
        valid = (volume.table[:, k] >= 0) & (volume.scale[:, k] > 0)
        carrying |= valid
        bound += np.where(valid, volume.scale[:, k] * volume.peak[np.maximum(volume.table[:, k], 0)], 0.0)
    quiet = INTERPOLATION_GAIN * bound < threshold * (1.0 - 1e-9)
    if quiet.any():
        quiet[np.asarray(candidates[0])[np.asarray(candidates[0]) < n]] = False  # beams with candidates stay
    beam, range_m, amplitude, label, object_id = (np.ascontiguousarray(x, t) for x, t in zip(candidates, (
        np.int64, np.float64, np.float64, np.uint8, np.uint32)))  # fmt: skip
    if not _ascending(beam):
        order = _beam_order(beam)
        beam, range_m, amplitude, label, object_id = (x[order] for x in (beam, range_m, amplitude, label, object_id))
    return _merged(beam, range_m, amplitude, label, object_id, np.flatnonzero(carrying & ~quiet), max_echoes)


@numba.njit(cache=True, nogil=True)
def _merged(beam, range_m, amplitude, label, object_id, carriers, k):
    """The candidates (``beam`` ascending) with ``k`` empty ones (range nan, amplitude 0) after each beam of
    ``carriers`` (ascending): grouped by beam, each beam's own candidates first (as a stable sort of both)."""
    n, m = len(beam), len(carriers) * k
    out = (np.empty(n + m, np.int64), np.empty(n + m), np.empty(n + m), np.empty(n + m, np.uint8),
           np.empty(n + m, np.uint32))  # fmt: skip
    ob, orr, oa, ol, oo = out
    i = j = 0
    for c in carriers:
        while i < n and beam[i] <= c:
            ob[j], orr[j], oa[j], ol[j], oo[j] = beam[i], range_m[i], amplitude[i], label[i], object_id[i]
            i += 1
            j += 1
        for _ in range(k):
            ob[j], orr[j], oa[j], ol[j], oo[j] = c, np.nan, 0.0, 0, 0
            j += 1
    while i < n:
        ob[j], orr[j], oa[j], ol[j], oo[j] = beam[i], range_m[i], amplitude[i], label[i], object_id[i]
        i += 1
        j += 1
    return out


@numba.njit(cache=True, nogil=True)
def _ascending(beam):
    """The beams are in ascending order (grouped)."""
    for i in range(1, len(beam)):
        if beam[i] < beam[i - 1]:
            return False
    return True


@numba.njit(cache=True, nogil=True)
def beam_groups(beam, n_beams):
    """A stable counting sort of ``beam`` (0..n_beams - 1): the order, and each beam's first
    position in it (n_beams + 1,)."""
    first = np.zeros(n_beams + 1, np.int64)
    for b in beam:
        first[b + 1] += 1
    for b in range(n_beams):
        first[b + 1] += first[b]
    fill = first[:-1].copy()
    order = np.empty(len(beam), np.int64)
    for i in range(len(beam)):
        order[fill[beam[i]]] = i
        fill[beam[i]] += 1
    return order, first


@numba.njit(cache=True, nogil=True)
def _beam_order(beam):
    """``np.argsort(beam, kind="stable")`` of beam indices >= 0: a counting sort."""
    return beam_groups(beam, beam.max() + 1)[0]


@numba.njit(cache=True, inline="always")
def _sort_and_merge(r, a, lab, obj, i0, i1, resolution, idx, mr, ma, ml, mo):
    """Sort candidates i0..i1 (one beam) by range (insertion sort: beams hold few) and merge
    runs closer than ``resolution`` (chained) into mr/ma/ml/mo[0:m]; returns m."""
    n = i1 - i0
    for q in range(n):
        k = q
        rq = r[i0 + q]
        while k > 0 and r[idx[k - 1]] > rq:
            idx[k] = idx[k - 1]
            k -= 1
        idx[k] = i0 + q
    m = -1
    strongest = 0.0
    start_r = -1e300
    for q in range(n):
        i = idx[q]
        if a[i] <= 0.0 or not np.isfinite(r[i]):
            continue
        if m < 0 or r[i] - start_r > resolution:
            m += 1
            mr[m] = r[i] * a[i]
            ma[m] = a[i]
            ml[m] = lab[i]
            mo[m] = obj[i]
            strongest = a[i]
            start_r = r[i]
        else:
            mr[m] += r[i] * a[i]
            ma[m] += a[i]
            if a[i] > strongest:
                strongest = a[i]
                ml[m] = lab[i]
                mo[m] = obj[i]
    m += 1
    for q in range(m):
        mr[q] /= ma[q]
    return m


@numba.njit(cache=True, inline="always")
def _reach(a, thr, s):
    """Distance (m) from a pulse's centre beyond which it is below threshold, plus a margin."""
    return s * np.sqrt(2.0 * np.log(max(a / thr, 1.0))) + 2.0 * s


@numba.njit(cache=True, inline="always")
def _sample(r, a, c0, c1, s, x):
    """The waveform of pulses c0..c1 at range ``x`` (m), summed in order: the detector's value."""
    w = 0.0
    for i in range(c0, c1):
        d = (x - r[i]) / s
        w += a[i] * np.exp(-0.5 * d * d)
    return w


#: Bound on the relative error of :func:`_fill_estimates` (its error stays below 1e-9: ~k^2
#: roundings of 1.1e-16 after k steps, k < 480 as each pulse is estimated only within 30 widths
#: of its centre, and ~1e-11 from rounding the exact samples' arguments).
ESTIMATE_TOLERANCE = 1e-7
#: Longest window (samples) estimated by recurrence, and how far from its centre (pulse widths) a
#: pulse is estimated: beyond, it adds less than exp(-30^2 / 2) ~ 1e-196 of its amplitude, which
#: :func:`_fill_estimates` leaves out (its absolute bound).
ESTIMATE_SAMPLES = 4096
ESTIMATE_REACH = 30.0


@numba.njit(cache=True, inline="always")
def _fill_estimates(r, a, c0, c1, s, lo, dx, first, n, buf):
    """Waveform samples first..first+n (at ``lo + k dx``) into buf[:n]; returns (relative, absolute)
    error bounds: the exact sample lies in [est (1 - rel), est (1 + rel) + abs]. A Gaussian on a
    uniform grid is a recurrence, two products a sample (e_k+1 = e_k q_k, q_k+1 = q_k exp(-h^2),
    h = dx / s; run as two chains, even and odd k), run for each pulse over the samples within
    ESTIMATE_REACH widths of its centre: after k steps its error is a few k^2 ulps, and what it
    leaves out is below the pulses' total amplitude times exp(-ESTIMATE_REACH^2 / 2). A long cluster
    (fog's volume, many pulses over metres) thus costs each pulse its own ~480 samples, not the
    window's. Exact samples (:func:`_sample`, bounds 0) when the window is longer than
    ESTIMATE_SAMPLES."""
    if n > ESTIMATE_SAMPLES:
        for j in range(n):
            buf[j] = _sample(r, a, c0, c1, s, lo + (first + j) * dx)
        return 0.0, 0.0
    h = dx / s
    x0 = lo + first * dx
    buf[:n] = 0.0
    c = np.exp(-h * h)
    c4 = c * c * c * c
    total = 0.0
    for i in range(c0, c1):
        total += a[i]
        ja = max(int(np.ceil((r[i] - ESTIMATE_REACH * s - x0) / dx)), 0)
        jb = min(int(np.floor((r[i] + ESTIMATE_REACH * s - x0) / dx)) + 1, n)
        if jb <= ja:
            continue
        d0 = (x0 + ja * dx - r[i]) / s
        e0 = a[i] * np.exp(-0.5 * d0 * d0)
        q0 = np.exp(-d0 * h - 0.5 * h * h)
        # two interleaved chains (even and odd samples, e_k+2 = e_k q_k q_k+1) that the CPU runs side by side
        e1, q1 = e0 * q0, q0 * c
        p0, p1 = q0 * q1, q1 * (q1 * c)
        for j in range(ja, jb - 1, 2):
            buf[j] += e0
            buf[j + 1] += e1
            e0 *= p0
            e1 *= p1
            p0 *= c4
            p1 *= c4
        if (jb - ja) % 2:
            buf[jb - 1] += e0
    return ESTIMATE_TOLERANCE, total * np.exp(-0.5 * ESTIMATE_REACH * ESTIMATE_REACH)


@numba.njit(cache=True, inline="always")
def _cluster_echoes(pulses, c0, c1, thr, s, out, out0, room, buf):
    """Echoes of the overlapping ``pulses`` c0..c1 (two or more; threshold ``thr``, pulse width
    ``s`` m), their range, amplitude, EPW, label and object id written into ``out``
    (:class:`EchoBuffers`) from out0 on; returns how many (<= room). ``buf``: scratch for the
    samples (grown if too short). The waveform is sampled by :func:`_run_echoes` on a grid from the
    cluster's own start, over the window where it may exceed the threshold."""
    r, a, reach = pulses.range_m, pulses.amplitude, pulses.reach
    dx = s / 8.0
    lo = 1e300
    hi = -1e300
    total = 0.0
    r_min = 1e300
    r_max = -1e300
    for i in range(c0, c1):
        h = reach[i]
        lo = min(lo, r[i] - h)
        hi = max(hi, r[i] + h)
        total += a[i]
        r_min = min(r_min, r[i])
        r_max = max(r_max, r[i])
    if total <= thr:  # w <= total everywhere
        return 0
    steps = int((hi - lo) / dx) + 2
    # The waveform is below the threshold farther than s sqrt(2 ln(total / thr)) from every pulse
    # (w <= total exp(-d^2 / 2s^2)): only the samples of that window are computed, from one below
    # it to one above it, which finds the same crossings and maxima as the whole grid.
    bound = s * (np.sqrt(2.0 * np.log(total / thr)) + 1e-6)
    first = max(int((r_min - bound - lo) / dx) - 2, 0)
    n = min(int((r_max + bound - lo) / dx) + 3, steps) - first
    if n <= 0:
        return 0
    return _run_echoes(pulses, c0, c1, thr, s, (lo, first, n), _NO_VOLUME, out, out0, room, buf)


class VolumeSamples(NamedTuple):
    """A beam's volume (:mod:`lidar_weather_sim.sensor.volume_tables`) at the samples of a window and one on
    each side (index j + 1 for the window's sample j), with the label of its largest layer there; empty: none."""

    value: np.ndarray  # (n + 2,) noise units
    label: np.ndarray  # (n + 2,) uint8


_NO_VOLUME = VolumeSamples(np.zeros(0), np.zeros(0, np.uint8))


@numba.njit(cache=True, inline="always")
def _exact(r, a, c0, c1, s, x, volume, j):
    """The waveform at the window's sample j, at range ``x`` (m): pulses c0..c1 summed in order, then the volume's
    sample (``volume``: :class:`VolumeSamples`' value array, empty: none)."""
    w = _sample(r, a, c0, c1, s, x)
    if len(volume):
        w += volume[j + 1]
    return w


@numba.njit(cache=True, inline="always")
def _run_echoes(pulses, c0, c1, thr, s, window, volume, out, out0, room, buf):
    """Echoes of the waveform of ``pulses`` c0..c1 plus ``volume`` (:class:`VolumeSamples`) sampled every s / 8 m
    at ``lo + (first + j) dx``, j < n (``window`` = (lo, first, n)), written into ``out`` (:class:`EchoBuffers`)
    from out0 on; returns how many (<= room). ``buf``: scratch for the samples (grown if too short).

    An echo runs from the first sample above the
    threshold to the last (crossings interpolated linearly between samples); its peak amplitude is
    its first highest sample, its range the vertex of the parabola through that sample and its two
    neighbours (the waveform's maximum to < 5 % of a sample step; the highest sample alone is up to
    half a step off, on a grid whose offset depends on the cluster); its label and object id those of
    the largest contributor at that sample (the volume: its layer's label, object 0). Samples are estimated
    (:func:`_fill_estimates`, plus the volume, exact by definition); the exact value
    (:func:`_exact`) is computed only where the estimate's error bound leaves the comparison
    with the threshold open, at the crossings and for the samples that may be the highest:
    the echoes are those of the exact samples, bit for bit."""
    r, a, reach, lab, obj = pulses
    out_r, out_a, out_w, out_l, out_o = out.range_m, out.amplitude, out.epw_m, out.label, out.object_id
    volume, volume_label = volume.value, volume.label  # the arrays, not the tuple, in the loops (no refcounts)
    lo, first, n = window
    dx = s / 8.0
    if n > len(buf):
        buf = np.empty(n)
    tol, eps = _fill_estimates(r, a, c0, c1, s, lo, dx, first, n, buf)
    if len(volume):
        for j in range(n):
            buf[j] += volume[j + 1]
    up, down = 1.0 + tol, 1.0 - tol  # the exact sample lies in [est * down, est * up + eps]
    written = 0
    inside = False
    ks = 0
    for j in range(n):
        est = buf[j]
        if est * down > thr:
            over = True
        elif est * up + eps < thr:
            over = False
        else:
            over = _exact(r, a, c0, c1, s, lo + (first + j) * dx, volume, j) > thr
        if over and not inside:
            inside = True
            ks = j
        elif not over and inside:
            inside = False
            w_in = _exact(r, a, c0, c1, s, lo + (first + ks) * dx, volume, ks)
            prev = _exact(r, a, c0, c1, s, lo + (first + ks - 1) * dx, volume, ks - 1) if ks > 0 else 0.0
            x = lo + (first + ks) * dx
            start = x - dx * (w_in - thr) / (w_in - prev)  # linear interpolation of the crossing
            peak = 0.0
            for m in range(ks, j):
                peak = max(peak, buf[m])
            best_w = -1.0
            best_x = 0.0
            best_m = ks
            for m in range(ks, j):  # the first highest exact sample among those that may be highest
                if buf[m] * up + eps >= peak * down:
                    x = lo + (first + m) * dx
                    w = _exact(r, a, c0, c1, s, x, volume, m)
                    if w > best_w:
                        best_w = w
                        best_x = x
                        best_m = m
            # the maximum between the samples: the parabola through the highest one and its neighbours
            w_lo = _exact(r, a, c0, c1, s, best_x - dx, volume, best_m - 1)
            w_hi = _exact(r, a, c0, c1, s, best_x + dx, volume, best_m + 1)
            curvature = w_lo - 2.0 * best_w + w_hi
            peak_x = best_x
            if curvature < 0.0:
                peak_x = best_x + dx * min(max(0.5 * (w_lo - w_hi) / curvature, -0.5), 0.5)
            x = lo + (first + j) * dx
            w = _exact(r, a, c0, c1, s, x, volume, j)
            prev = _exact(r, a, c0, c1, s, lo + (first + j - 1) * dx, volume, j - 1)
            end = x - dx * (thr - w) / (prev - w)
            best_i = c0  # label of the strongest contributor at the peak
            best_c = -1.0
            for i in range(c0, c1):
                d = (best_x - r[i]) / s
                c = a[i] * np.exp(-0.5 * d * d)
                if c > best_c:
                    best_c = c
                    best_i = i
            out_r[out0 + written] = peak_x
            out_a[out0 + written] = best_w
            out_w[out0 + written] = end - start
            if len(volume) and volume[best_m + 1] > best_c:
                out_l[out0 + written] = volume_label[best_m + 1]
                out_o[out0 + written] = 0
            else:
                out_l[out0 + written] = lab[best_i]
                out_o[out0 + written] = obj[best_i]
            written += 1
            if written == room:
                return written
    return written


_EMPTY_VOLUME = empty_volume()
_NO_PREFIX = no_prefix()

#: Candidates per chunk when a batch is shared between threads (:mod:`lidar_weather_sim.core.workers`):
#: chunks are cut where the beam changes, every beam is computed the same way.
CHUNK_CANDIDATES = 8192


def _detect(candidates: Candidates, detector: Detector, scratch=None, segments=None, volume: Volume | None = None,
            prefix: VolumePrefix | None = None):  # fmt: skip
    """The arrays of :class:`Echoes` of ``candidates`` (grouped by beam; only the runs ``segments``
    (starts, counts) if given) with the beams' ``volume`` layers (None: none) and their groups' echoes
    ``prefix`` (None: none), each chunk's written from its first candidate's index on."""
    volume = _EMPTY_VOLUME if volume is None else volume
    prefix = _NO_PREFIX if prefix is None else prefix
    beam = candidates.beam
    n = len(beam)
    cap = n  # a sum of k Gaussians has at most k maxima: never more echoes than candidates (volume beams: see
    # _with_volume_beams)
    new = allocator(scratch)
    dtypes = (np.int64, np.uint8, np.float64, np.float64, np.float64, np.uint8, np.uint32)
    out = EchoBuffers(*(new(f"echo_{k}", cap, dtype) for k, dtype in enumerate(dtypes)))
    if segments is None:
        cuts = workers.bounds(n, CHUNK_CANDIDATES)
        if len(cuts) > 2:
            cuts = _beam_starts(beam, cuts)
        starts, ends = cuts[:-1], cuts[1:]
    else:
        starts, ends = segments[0], segments[0] + segments[1]
    counts = np.array(workers.run_chunks(
        lambda c: _detect_run(candidates, detector, starts[c], ends[c], out, volume, prefix,
                              Work.of(ends[c] - starts[c])),
        len(starts),
    ), np.int64)  # fmt: skip
    return (*out, (starts, counts))


@numba.njit(cache=True, nogil=True)
def _beam_starts(beam, cuts):
    """``cuts`` moved forward to where the beam changes (dropping empty chunks)."""
    out = np.empty(len(cuts), np.int64)
    out[0] = 0
    k = 1
    n = len(beam)
    for c in range(1, len(cuts) - 1):
        p = max(cuts[c], out[k - 1])
        while 0 < p < n and beam[p] == beam[p - 1]:
            p += 1
        if out[k - 1] < p < n:
            out[k] = p
            k += 1
    out[k] = n
    return out[: k + 1]


@numba.njit(cache=True, nogil=True)
def _detect_run(candidates, detector, lo, hi, out, volume, prefix, work):
    """Echoes of the beams of ``candidates`` lo..hi (whole beams), written into ``out``
    (:class:`EchoBuffers`) from index lo on; returns how many. A beam with layers in ``volume``
    (:class:`~lidar_weather_sim.sensor.volume_tables.Volume`) takes its group's echoes in front of its hard
    target from ``prefix`` (:class:`~lidar_weather_sim.sensor.volume_prefix.VolumePrefix`) and goes through
    :func:`_volume_echoes` from there on. ``work``: its :class:`Work` arrays, for hi - lo candidates."""
    thr, s, resolution, max_echoes = detector
    beam, r, a, lab, obj = borrow(candidates)  # the caller's arrays, uncounted (core.borrow)
    volume, prefix, out = borrow(volume), borrow(prefix), borrow(out)
    eb, ee, er, ea, ew, el, eo = out
    pulses = borrow(work.pulses)
    mr, ma, reach, ml, mo = pulses
    idx = borrow(work.order)
    buf = borrow(work.samples)
    samples = VolumeScratch(np.empty(0), np.empty(0, np.uint8), np.empty(0))  # a volume beam's, grown when needed
    isolated = borrow(work.isolated)
    n_isolated = 0
    count = lo
    i = lo
    while i < hi:
        j = i
        while j < hi and beam[j] == beam[i]:
            j += 1
        m = _sort_and_merge(r, a, lab, obj, i, j, resolution, idx, mr, ma, ml, mo)
        v0, v1, v_bound = volume_window(volume, beam[i])
        if v1 > v0 and m == 0 and INTERPOLATION_GAIN * v_bound < thr * (1.0 - 1e-9):
            i = j  # no pulses, and a volume whose magnitude stays below the threshold: no echo
            continue
        if v1 > v0:
            for q in range(m):
                reach[q] = _reach(ma[q], thr, s)
            found = 0
            if beam[i] < len(prefix.group) and prefix.group[beam[i]] >= 0:  # (only then: its call costs)
                found, v0 = prefix_echoes(prefix, volume, beam[i], pulses, m, detector, v0, v1, out, count)
            if v0 < v1:
                found, samples = _volume_echoes(pulses, m, detector, volume, (beam[i], v0, v1, v_bound, found), out,
                                                count, buf, samples)  # fmt: skip
            for k in range(found):
                eb[count + k] = beam[i]
                ee[count + k] = k + 1
            count += found
            i = j
            continue
        if m > 1:
            for q in range(m):
                reach[q] = _reach(ma[q], thr, s)
        found = 0
        c0 = 0
        while c0 < m and found < max_echoes:
            c1 = c0 + 1
            while c1 < m and mr[c1] - mr[c1 - 1] < reach[c1 - 1] + reach[c1]:
                c1 += 1  # pulses that may overlap above the threshold form one cluster
            if c1 - c0 > 1:
                got = _cluster_echoes(pulses, c0, c1, thr, s, out, count, max_echoes - found, buf)
            else:
                got = 0
                if ma[c0] > thr:
                    er[count], ea[count], ew[count], el[count], eo[count] = mr[c0], ma[c0], ma[c0] / thr, ml[c0], mo[c0]
                    isolated[n_isolated] = count
                    n_isolated += 1
                    got = 1
            for k in range(got):
                eb[count + k] = beam[i]
                ee[count + k] = found + k + 1
            count += got
            found += got
            c0 = c1
        i = j
    for q in range(n_isolated):  # independent of each other: the CPU overlaps the logarithms
        k = isolated[q]
        ew[k] = 2.0 * s * np.sqrt(2.0 * np.log(ew[k]))
    return count - lo


@numba.njit(cache=True, inline="always")
def _volume_echoes(pulses, m, detector, volume, beam_volume, out, out0, buf, samples):
    """Echoes of one beam's merged ``pulses`` (m, their reach set) plus its volume, written into ``out`` from out0
    on; returns (how many, ``samples`` grown if they had to be). ``beam_volume``: (the beam of ``volume``
    (:class:`~lidar_weather_sim.sensor.volume_tables.Volume`), the samples [v0, v1) where its volume may be
    non-zero, a bound on its value, the echoes already written in front of v0 (counted in the result)).
    Where the volume's magnitude stays below the threshold, only the samples where the pulses add what it lacks
    are sampled.

    Clusters of pulses (as in :func:`_detect_run`) that end before the volume's window or start after it are
    found as on a beam without a volume; the volume's window and the clusters reaching into it are one waveform,
    sampled on the grid of the volume's tables (``k dx`` from the sensor) by :func:`_run_echoes`."""
    r, a, reach, lab, obj = pulses
    thr, s, resolution, max_echoes = detector
    b, v0, v1, v_bound, found = beam_volume
    dx = s / 8.0
    v_lo, v_hi = v0 * dx, (v1 - 1) * dx
    c0 = 0
    done = False
    while (c0 < m or not done) and found < max_echoes:
        c1 = c0
        c_lo, c_hi = 1e300, 1e300
        if c0 < m:
            c1 = c0 + 1
            while c1 < m and r[c1] - r[c1 - 1] < reach[c1 - 1] + reach[c1]:
                c1 += 1
            c_lo, c_hi = 1e300, -1e300
            for q in range(c0, c1):
                c_lo, c_hi = min(c_lo, r[q] - reach[q]), max(c_hi, r[q] + reach[q])
        if done or c_hi < v_lo:  # a cluster on its own
            if c1 - c0 > 1:
                got = _cluster_echoes(pulses, c0, c1, thr, s, out, out0 + found, max_echoes - found, buf)
            else:
                got = 0
                if a[c0] > thr:
                    k = out0 + found
                    out.range_m[k], out.amplitude[k], out.label[k], out.object_id[k] = r[c0], a[c0], lab[c0], obj[c0]
                    out.epw_m[k] = 2.0 * s * np.sqrt(2.0 * np.log(a[c0] / thr))
                    got = 1
        else:  # the volume, with the pulses reaching into its window
            w_lo, w_hi = v_lo, v_hi
            if c_lo <= v_hi:
                while c1 < m and r[c1] - reach[c1] <= max(w_hi, c_hi):
                    c_hi = max(c_hi, r[c1] + reach[c1])
                    c1 += 1
            else:
                c1 = c0
            total, r_min, r_max = 0.0, 1e300, -1e300
            for q in range(c0, c1):
                total += a[q]
                r_min, r_max = min(r_min, r[q]), max(r_max, r[q])
            if total > thr:  # where the pulses alone may exceed the threshold (see _cluster_echoes)
                bound = s * (np.sqrt(2.0 * np.log(total / thr)) + 1e-6)
                w_lo, w_hi = min(w_lo, r_min - bound), max(w_hi, r_max + bound)
            got = 0
            need = thr * (1.0 - 1e-9) - INTERPOLATION_GAIN * v_bound  # what the pulses must add to the volume
            if need > 0.0:  # the volume alone stays below the threshold: an echo lies where the pulses add > need
                if total > need:
                    bound = s * (np.sqrt(2.0 * np.log(total / need)) + 1e-6)
                    w_lo, w_hi = max(w_lo, r_min - bound), min(w_hi, r_max + bound)
                else:
                    w_hi = w_lo - 1.0  # nowhere
            if total + v_bound > thr and w_hi >= w_lo:
                got = -1
                if need > 0.0:  # pulses close together in a volume below the threshold: their deciding samples
                    got, samples = _isolated_echo(pulses, (c0, c1), detector, volume, b, thr - need, out,
                                                  out0 + found, samples)  # fmt: skip
                if got < 0:
                    first = int(np.floor(w_lo / dx)) - 1
                    n = int(np.ceil(w_hi / dx)) + 2 - first
                    got, samples = _open_echoes(pulses, (c0, c1), detector, volume, (b, first, n), out, out0 + found,
                                                max_echoes - found, buf, samples)  # fmt: skip
            done = True
        found += got
        c0 = c1
    return found, samples


#: Most samples from the first band's start to the second band's end of :func:`_isolated_echo`; wider: the whole
#: window is sampled.
ISOLATED_SAMPLES = 256


@numba.njit(cache=True, inline="always")
def _isolated_echo(pulses, span, detector, volume, b, v_max, out, k_out, scratch):
    """The echo of pulses c0..c1 (``span``: one merged group, their range order) in beam b's volume whose magnitude
    stays below ``v_max`` (noise units, less than the threshold), written into ``out`` at k_out: (1, or -1 when it
    is left to the whole window; ``scratch`` (:class:`VolumeScratch`) grown if it had to be). The echo
    :func:`_open_echoes` finds, bit for bit, from the samples that decide it. With A their summed amplitude and
    r_lo, r_hi the nearest and farthest, the pulses are below A g(x - r_lo) in front of r_lo and above A g(x -
    r_hi) there (g the pulse shape), alike behind: in front of where A g = thr - v_max (and behind) no sample is
    over the threshold, between where A g = thr + v_max every one is (the pulses at most that far apart). So the
    crossings lie in the two bands between, and the highest sample where the pulses may be within 2 v_max of their
    value at a sample near their centre. Those samples are computed as :func:`_run_echoes` computes them (the
    pulses summed in order, plus the volume as :func:`fill_volume` gives it); a band that does not cross the
    threshold exactly once, or bands and zone that meet (pulses within a few v_max of the threshold, or far apart)
    leave the echo to the whole window."""
    r, a = pulses.range_m, pulses.amplitude
    c0, c1 = span
    thr, s = detector.threshold, detector.sigma
    dx = s / 8.0
    total, centre = 0.0, 0.0
    for i in range(c0, c1):
        total += a[i]
        centre += a[i] * r[i]
    r_lo, r_hi = r[c0], r[c1 - 1]
    lo_y, hi_y = thr - v_max, thr + v_max
    near = int(np.round(centre / total / dx))
    top = _sample(r, a, c0, c1, s, near * dx) - 2.0 * v_max  # below it, a sample is not the highest
    if lo_y <= 0.0 or top <= hi_y:
        return -1, scratch
    w_out, w_in, w_top = (s * np.sqrt(2.0 * np.log(total / lo_y)), s * np.sqrt(2.0 * np.log(total / hi_y)),
                          s * np.sqrt(2.0 * np.log(total / top)))  # fmt: skip
    k_a, k_b = int(np.floor((r_lo - w_out) / dx)) - 1, int(np.ceil((r_hi - w_in) / dx)) + 1  # the rising band
    k_c, k_d = int(np.floor((r_lo + w_in) / dx)) - 1, int(np.ceil((r_hi + w_out) / dx)) + 1  # the falling band
    k_p, k_q = int(np.floor((r_lo - w_top) / dx)) - 1, int(np.ceil((r_hi + w_top) / dx)) + 1  # the highest's zone
    if not (k_b < k_p and k_q < k_c) or k_d - k_a + 1 > ISOLATED_SAMPLES:
        return -1, scratch
    if len(scratch.value) < ISOLATED_SAMPLES:
        scratch = VolumeScratch(np.empty(ISOLATED_SAMPLES), np.empty(ISOLATED_SAMPLES, np.uint8), scratch.bound)
    value, label = borrow(scratch.value), borrow(scratch.label)  # held by the scratch returned (core.borrow)
    fill_volume(volume, b, k_a, k_d - k_a + 1, value, label)  # (one call: each costs ~0.1 us)
    ks, w_ks, w_before = _band_crossing(r, a, span, s, (k_a, k_b), k_a, thr, True, value)
    je, w_je, w_last = _band_crossing(r, a, span, s, (k_c, k_d), k_a, thr, False, value)
    if ks < 0 or je < 0:
        return -1, scratch
    best_w, best_m = -1.0, k_p
    for k in range(k_p, k_q + 1):  # the first highest exact sample
        w = _sample(r, a, c0, c1, s, k * dx) + value[k - k_a]
        if w > best_w:
            best_w, best_m = w, k
    best_x = best_m * dx
    w_lo = _sample(r, a, c0, c1, s, best_x - dx) + value[best_m - 1 - k_a]
    w_hi = _sample(r, a, c0, c1, s, best_x + dx) + value[best_m + 1 - k_a]
    curvature = w_lo - 2.0 * best_w + w_hi
    peak_x = best_x
    if curvature < 0.0:
        peak_x = best_x + dx * min(max(0.5 * (w_lo - w_hi) / curvature, -0.5), 0.5)
    start = ks * dx - dx * (w_ks - thr) / (w_ks - w_before)
    end = je * dx - dx * (thr - w_je) / (w_last - w_je)
    best_i, best_c = c0, -1.0  # the strongest contributor at the peak
    for i in range(c0, c1):
        d = (best_x - r[i]) / s
        contribution = a[i] * np.exp(-0.5 * d * d)
        if contribution > best_c:
            best_c, best_i = contribution, i
    out.range_m[k_out], out.amplitude[k_out], out.epw_m[k_out] = peak_x, best_w, end - start
    if value[best_m - k_a] > best_c:
        out.label[k_out], out.object_id[k_out] = label[best_m - k_a], 0
    else:
        out.label[k_out], out.object_id[k_out] = pulses.label[best_i], pulses.object_id[best_i]
    return 1, scratch


@numba.njit(cache=True, inline="always")
def _band_crossing(r, a, span, s, band, origin, thr, rising, value):
    """In the samples k0..k1 (``band``) of pulses c0..c1 (``span``) plus the volume (``value``, sample k at k -
    ``origin``), exact as :func:`_run_echoes` computes them: (the first sample over the threshold if ``rising``, else
    the first not over it; its value; the value of the sample before it), or (-1, 0, 0) unless k0 is on the other
    side and the samples change side once."""
    c0, c1 = span
    k0, k1 = band
    dx = s / 8.0
    cross, w_cross, w_before = -1, 0.0, 0.0
    was, prev = False, 0.0
    for k in range(k0, k1 + 1):
        w = _sample(r, a, c0, c1, s, k * dx) + value[k - origin]
        over = w > thr
        if k == k0:
            if over == rising:
                return -1, 0.0, 0.0
        elif over != was:
            if cross >= 0:
                return -1, 0.0, 0.0
            cross, w_cross, w_before = k, w, prev
        was, prev = over, w
    return cross, w_cross, w_before


class VolumeScratch(NamedTuple):
    """A volume beam's scratch (grown when needed): its volume's samples (:class:`VolumeSamples`) and block bounds."""

    value: np.ndarray
    label: np.ndarray
    bound: np.ndarray


@numba.njit(cache=True, inline="always")
def _pulse_bound(r, a, c0, c1, s, x0, x1):
    """A bound on the waveform of pulses c0..c1 (pulse width ``s``, m) over [x0, x1] (m): each pulse's value at
    the nearest point of the interval, plus what the pulses farther than 38 widths (below 1e-313 of their
    amplitude) may add."""
    w = 0.0
    far = 0.0
    for i in range(c0, c1):
        d = max(x0 - r[i], r[i] - x1, 0.0) / s
        if d < 38.0:
            w += a[i] * np.exp(-0.5 * d * d)
        else:
            far += a[i]
    return w + far * 1e-300


@numba.njit(cache=True, inline="always")
def _open_echoes(pulses, span, detector, volume, window, out, out0, room, buf, scratch):
    """Echoes of the waveform of ``pulses`` c0..c1 (``span``) plus beam b's ``volume`` over the samples first..first
    + n (``window`` = (b, first, n)), written into ``out`` from out0 on; returns (how many, ``scratch``
    (:class:`VolumeScratch`) grown if it had to be). Sampled by :func:`_run_echoes` only in the runs of blocks
    (:data:`~lidar_weather_sim.sensor.volume_tables.BLOCK` samples) where the bound of the pulses and the volume
    reaches the threshold, each run with one sample on each side: elsewhere the waveform is below it, so every
    echo lies inside a run, and its crossings, maximum and label are those of the whole window, bit for bit."""
    r, a = pulses.range_m, pulses.amplitude
    c0, c1 = span
    thr, s = detector.threshold, detector.sigma
    b, first, n = window
    dx = s / 8.0
    q0 = first // BLOCK
    nq = (first + n - 1) // BLOCK - q0 + 1
    if nq > len(scratch.bound) or n + 2 > len(scratch.value):
        scratch = VolumeScratch(np.empty(max(n + 2, len(scratch.value))), np.empty(max(n + 2, len(scratch.value)),
                                np.uint8), np.empty(max(nq, len(scratch.bound))))  # fmt: skip
    value, label, bound = borrow(scratch)  # held by the scratch returned (core.borrow)
    bound = fill_block_bounds(volume, b, q0, nq, bound)
    limit = thr * (1.0 - 1e-9)  # the bounds' own rounding
    got = 0
    q = 0
    while q < nq and got < room:
        if bound[q] + _pulse_bound(r, a, c0, c1, s, (q0 + q) * BLOCK * dx, ((q0 + q + 1) * BLOCK - 1) * dx) <= limit:
            q += 1
            continue
        q_end = q + 1
        while q_end < nq and bound[q_end] + _pulse_bound(r, a, c0, c1, s, (q0 + q_end) * BLOCK * dx,
                                                         ((q0 + q_end + 1) * BLOCK - 1) * dx) > limit:  # fmt: skip
            q_end += 1
        k0 = max((q0 + q) * BLOCK - 1, first)
        k1 = min((q0 + q_end) * BLOCK + 1, first + n)
        fill_volume(volume, b, k0 - 1, k1 - k0 + 2, value, label)
        got += _run_echoes(pulses, c0, c1, thr, s, (0.0, k0, k1 - k0),
                           VolumeSamples(value[: k1 - k0 + 2], label[: k1 - k0 + 2]),
                           out, out0 + got, room - got, buf)  # fmt: skip
        q = q_end
    return got, scratch


_STRONGEST, _LAST, _FIRST, _DUAL = (RETURN_MODES.index(m) for m in ("strongest", "last", "first", "dual"))
_RT_LAST, _RT_FIRST, _RT_STRONGEST, _RT_IDENTICAL, _RT_SECOND_STRONGEST, _RT_LAST_STRONGEST = (int(r) for r in (
    ReturnType.LAST, ReturnType.FIRST, ReturnType.STRONGEST, ReturnType.IDENTICAL, ReturnType.SECOND_STRONGEST,
    ReturnType.LAST_STRONGEST))  # fmt: skip


def select_returns(beam: np.ndarray, amplitude: np.ndarray, runs: tuple[np.ndarray, np.ndarray], mode: str,
                   out: np.ndarray | None = None) -> np.ndarray:  # fmt: skip
    """The return each echo is reported as under the return ``mode`` (strongest, last, first or dual; see
    the module's "Return modes"): Nebula's :class:`~lidar_weather_sim.core.points.ReturnType` code, 0 for an
    echo the mode does not report.

    ``beam``, ``amplitude`` (peak, noise units): the echoes of :class:`Echoes` in the runs (starts, counts),
    each beam's echoes together and in range order as :func:`detect_echoes` writes them. Returns ``out``
    (or a new uint8 array as long as ``beam``) with the codes written in the runs. ``all`` has nothing to
    select: every echo is reported and the caller keeps them (a ValueError here)."""
    if mode not in RETURN_MODES or mode == "all":
        raise ValueError(f"return_mode {mode!r} selects nothing here: one of strongest, last, first, dual")
    out = np.empty(len(beam), np.uint8) if out is None else out
    _select_runs(beam, amplitude, runs[0], runs[1], RETURN_MODES.index(mode), out)
    return out


@numba.njit(cache=True, nogil=True)
def _first_max(a, i0, i1):
    """Index of the first highest of a[i0:i1] (the nearest of equal peaks)."""
    best = i0
    for i in range(i0 + 1, i1):
        if a[i] > a[best]:
            best = i
    return best


@numba.njit(cache=True, nogil=True)
def _select_runs(beam, a, starts, counts, mode, out):
    for c in range(len(counts)):
        i, end = starts[c], starts[c] + counts[c]
        while i < end:
            j = i + 1
            while j < end and beam[j] == beam[i]:
                j += 1
            for k in range(i, j):
                out[k] = 0
            if mode == _FIRST:
                out[i] = _RT_FIRST
            elif mode == _LAST:
                out[j - 1] = _RT_LAST
            elif mode == _STRONGEST:
                out[_first_max(a, i, j)] = _RT_STRONGEST
            elif j - i == 1:  # dual, one echo: one point
                out[i] = _RT_IDENTICAL
            else:
                strongest = _first_max(a, i, j)
                if strongest == j - 1:
                    out[j - 1] = _RT_LAST_STRONGEST
                    out[_first_max(a, i, j - 1)] = _RT_SECOND_STRONGEST
                else:
                    out[j - 1] = _RT_LAST
                    out[strongest] = _RT_STRONGEST
            i = j
