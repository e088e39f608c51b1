"""Volume tables (lidar_weather_sim.sensor.volume_tables) against references written apart: scipy's adaptive
quadrature of the LIDAR integral, scipy's IIR filter for the AC coupling, the echo stage on the same waveform as
pulses, and a plain scan of the sampled waveform for the echoes of a beam with a volume."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest
from scipy.signal import lfilter

from lidar_weather_sim.regions.volume_return import VolumeReturn
from lidar_weather_sim.sensor.echo import detect_echoes
from lidar_weather_sim.sensor.profile import load_profile
from lidar_weather_sim.sensor.radiometry import MIN_RANGE_M, Threshold
from lidar_weather_sim.sensor.volume_tables import (BLOCK, REACH, build_table, cell_density, cell_nodes,
                                                     fill_block_bounds, fill_volume, realised_density, stack_volume,
                                                     tables_of_cells)  # fmt: skip
from lidar_weather_sim.testing.lidar_integral import lidar_integral, medium_return

FOG = 3


def table_of(profile, v: VolumeReturn, tau_m: float = 0.0, floor: float = 0.0):
    return build_table(v.density, sigma_m=v.sigma_m, r_max_m=float(profile.range.max_m), label=FOG,
                       start_m=max(v.overlap_start_m, MIN_RANGE_M), tau_m=tau_m, floor=floor)  # fmt: skip


@pytest.mark.parametrize("profile_name", ["scala4", "os1_128_2048"])
@pytest.mark.parametrize("kind, value", [("fog", 30.0), ("fog", 200.0), ("rain", 10.0)])
def test_table_is_the_lidar_equation_integral(profile_name, kind, value):
    profile = load_profile(profile_name)
    v = medium_return(profile, kind, value)
    table = table_of(profile, v)
    dx = table.dx_m
    ranges = np.array([0.5, 1.0, 2.0, 3.5, 6.0, 15.0, 40.0])
    for hit in (np.inf, 4.0, 7.37, 12.5):
        k = np.round(ranges / dx).astype(int)
        if np.isfinite(hit):  # the samples around the cut
            k = np.concatenate([k, np.round(hit / dx).astype(int) + np.arange(-12, 13, 3)])
        got = table.truncated(hit)[k + REACH]
        want = np.array([lidar_integral(v, j * dx, hit) for j in k])
        np.testing.assert_allclose(got, want, rtol=2e-3, atol=1e-7 * want.max())


def test_the_high_pass_is_the_first_order_filter():
    """Cells filtered by the slab recursion against scipy's IIR filter on a 1 mm grid (y = x - low-pass), clipped
    at 0: the same integral, and the same shape cell by cell."""
    profile = load_profile("scala4")
    v = medium_return(profile, "fog", 30.0)
    tau = float(profile.detection.ac_coupling_tau_m)
    assert tau > 0
    table = table_of(profile, v, tau_m=tau)
    h = 1e-3
    r = np.arange(0.0, 60.0, h) + 0.5 * h
    x = np.where(r >= max(v.overlap_start_m, MIN_RANGE_M), v.density(r), 0.0)
    decay = np.exp(-h / tau)
    low = lfilter([1.0 - decay], [1.0, -decay], x)
    y = np.clip(x - low, 0.0, None)
    dx = table.dx_m
    cells = np.floor(r / dx + 0.5).astype(int) + REACH  # the table's index of each cell
    want = np.bincount(cells, y * h, minlength=len(table.density))[: len(table.density)]
    n = REACH + int(60.0 / dx) - 1
    assert table.density[:n].sum() == pytest.approx(want[:n].sum(), rel=0.01)
    unfiltered = table_of(profile, v).density[:n].sum()
    assert table.density[:n].sum() < 0.9 * unfiltered  # the filter takes a share: the test can tell
    peak = want[:n].max()
    np.testing.assert_allclose(table.density[:n], want[:n], atol=0.03 * peak)


def detect(beams, threshold, profile, volume=None, resolution_m=0.0):
    """The echoes (arrays of the echoes' fields, only the echoes written) of pulses (beam, range, amplitude),
    label 7, object id = the pulse's index."""
    beam, range_m, amplitude = (np.asarray(x) for x in beams)
    echoes = detect_echoes(beam.astype(np.int64), range_m.astype(np.float64), amplitude.astype(np.float64),
                         np.full(len(beam), 7, np.uint8), np.arange(len(beam), dtype=np.uint32), threshold=threshold,
                         fwhm_m=profile.pulse.fwhm_m, resolution_m=resolution_m, max_echoes=8, volume=volume)  # fmt: skip
    written = np.concatenate([np.arange(a, a + c) for a, c in zip(*echoes.runs)] + [np.zeros(0, np.int64)])
    fields = ("beam", "echo", "range_m", "amplitude", "epw_m", "label", "object_id")
    return SimpleNamespace(**{name: getattr(echoes, name)[written] for name in fields})


@pytest.mark.parametrize("profile_name", ["scala4", "os1_128_2048"])
@pytest.mark.parametrize("visual_range", [30.0, 100.0, 500.0])
def test_a_table_gives_the_echoes_of_its_cells_as_pulses(profile_name, visual_range):
    """A beam carrying only the table against the echo stage on the same waveform as pulses, one per cell
    (the cut cell's share at its centre): the same echoes, on another sampling grid."""
    profile = load_profile(profile_name)
    v = medium_return(profile, "fog", visual_range)
    dark = Threshold.under_sun(profile.detection)
    table = table_of(profile, v, tau_m=float(profile.detection.ac_coupling_tau_m), floor=0.02 * dark.level)
    dx = table.dx_m
    hits = [np.inf, 3.0, 8.0, 25.0]
    scale = 1.0 if visual_range < 400 else 8.0  # thin fog: a beam that shows its echo
    for factor in (1.0, 1.5):
        threshold = Threshold(dark.level * factor, 0.0, 0.0)  # a brighter sky
        volume = stack_volume([table], np.zeros((len(hits), 1), np.int64), np.full((len(hits), 1), scale),
                              np.array(hits)[:, None])  # fmt: skip
        got = detect(([], [], []), threshold, profile, volume)
        k = np.arange(len(table.density)) - REACH
        beams, ranges, amps = [], [], []
        for b, hit in enumerate(hits):
            u = hit / dx + 0.5 if np.isfinite(hit) else np.inf
            cut = int(np.floor(u)) if np.isfinite(u) else len(k)
            share = np.where(k < cut, 1.0, np.where(k == cut, u - cut if np.isfinite(u) else 0.0, 0.0))
            a = scale * table.density * share
            keep = a > 0
            beams.append(np.full(int(keep.sum()), b))
            ranges.append(k[keep] * dx)
            amps.append(a[keep])
        want = detect((np.concatenate(beams), np.concatenate(ranges), np.concatenate(amps)), threshold, profile)
        assert len(want.beam) >= len(hits) - 1  # the fog echoes are there to compare
        np.testing.assert_array_equal(got.beam, want.beam)
        np.testing.assert_allclose(got.range_m, want.range_m, atol=dx / 20)
        np.testing.assert_allclose(got.epw_m, want.epw_m, rtol=0.01)
        np.testing.assert_allclose(got.amplitude, want.amplitude, rtol=1e-3)
        assert set(got.label) == {FOG}


def scan_echoes(w: np.ndarray, dx: float, thr: float):
    """Echoes of samples ``w`` (at k dx) by a plain scan: runs above ``thr``, crossings interpolated linearly,
    range at the vertex of the parabola through the highest sample and its neighbours, EPW end - start."""
    over = w > thr
    edges = np.flatnonzero(np.diff(over.astype(int)))
    out = []
    for ks, ke in zip(edges[::2] + 1, edges[1::2] + 1):
        start = ks * dx - dx * (w[ks] - thr) / (w[ks] - w[ks - 1])
        end = ke * dx - dx * (thr - w[ke]) / (w[ke - 1] - w[ke])
        m = ks + int(np.argmax(w[ks:ke]))
        curvature = w[m - 1] - 2 * w[m] + w[m + 1]
        shift = np.clip(0.5 * (w[m - 1] - w[m + 1]) / curvature, -0.5, 0.5) if curvature < 0 else 0.0
        out.append(((m + shift) * dx, w[m], end - start))
    return np.array(out).reshape(-1, 3)


@pytest.mark.parametrize("profile_name, target_m, amplitude", [
    ("scala4", 0.9, 0.3), ("scala4", 1.5, 3.0), ("os1_128_2048", 2.6, 0.6), ("os1_128_2048", 3.1, 3.0),
    ("os1_128_2048", 6.0, 40.0), ("os1_128_2048", 1.9, 0.3)])  # fmt: skip
def test_a_hard_target_inside_the_volume_echo(profile_name, target_m, amplitude):
    """A beam with fog (cut at its hard target, inside the fog's echo: scala4's AC coupling keeps only its first
    two metres) and the target's pulse, as the sampled waveform says: the echoes of a plain scan of the samples;
    the label of the largest contributor at the peak."""
    profile = load_profile(profile_name)
    v = medium_return(profile, "fog", 30.0)
    threshold = Threshold.under_sun(profile.detection)
    table = table_of(profile, v, tau_m=float(profile.detection.ac_coupling_tau_m), floor=0.02 * threshold.level)
    dx, s = table.dx_m, v.sigma_m
    thr = threshold.level
    peak = amplitude * thr
    volume = stack_volume([table], np.zeros((1, 1), np.int64), np.ones((1, 1)), np.array([[target_m]]))
    got = detect(([0], [target_m], [peak]), threshold, profile, volume)
    x = table.range_m
    w = table.truncated(target_m) + peak * np.exp(-0.5 * ((x - target_m) / s) ** 2)
    want = scan_echoes(w, dx, thr) - [REACH * dx, 0.0, 0.0]
    assert len(want) >= 1
    np.testing.assert_allclose(np.c_[got.range_m, got.amplitude, got.epw_m], want, rtol=1e-9, atol=1e-9)
    volume_part = table.truncated(target_m)[np.round(got.range_m / dx).astype(int) + REACH]
    target_part = peak * np.exp(-0.5 * ((np.round(got.range_m / dx) * dx - target_m) / s) ** 2)
    np.testing.assert_array_equal(got.label, np.where(target_part > volume_part, 7, FOG))


def test_a_far_target_behind_thin_fog_is_detected_as_without_a_volume():
    """The clusters that do not reach the volume's window are found as on a clear beam, bit for bit."""
    profile = load_profile("scala4")
    v = medium_return(profile, "fog", 30.0)
    threshold = Threshold.under_sun(profile.detection)
    table = table_of(profile, v, tau_m=float(profile.detection.ac_coupling_tau_m), floor=0.02 * threshold.level)
    pulses = ([0, 0, 0], [70.0, 70.3, 120.0], [5.0, 3.0, 9.0])
    volume = stack_volume([table], np.zeros((1, 1), np.int64), np.ones((1, 1)), np.array([[70.0]]))
    with_fog = detect(pulses, threshold, profile, volume)
    clear = detect(pulses, threshold, profile)
    far = with_fog.range_m > 60.0
    assert far.sum() == len(clear.range_m) == 2 and (~far).sum() >= 1
    for name in ("range_m", "amplitude", "epw_m", "label", "object_id"):
        np.testing.assert_array_equal(getattr(with_fog, name)[far], getattr(clear, name))


def test_block_bounds_hold_every_beams_volume():
    """The echo stage samples a beam only where its block bounds reach the threshold: on seeded draws of two
    layers (fog and rain tables of OS1-128, random scales, hits anywhere or none), every sample's volume is at
    most its block's bound, and the bound is within 1.5 times the block's largest untruncated value (1.25 from the
    interpolation of the cut rows, the rest from the layers' peaks within a block)."""
    profile = load_profile("os1_128_2048")
    tables = [table_of(profile, medium_return(profile, kind, value)) for kind, value in (("fog", 50.0), ("rain", 10.0))]
    rng = np.random.default_rng(7)
    n = 200
    table = np.stack([np.zeros(n, np.int64), np.where(rng.random(n) < 0.8, 1, -1)], axis=1)
    scale = rng.uniform(0.05, 1.0, (n, 2))
    hit = np.where(rng.random((n, 2)) < 0.7, rng.uniform(0.3, 40.0, (n, 2)), np.inf)
    volume = stack_volume(tables, table, scale, hit)
    first, count = -REACH, max(t.support[1] for t in tables) + 2 * REACH
    q0, nq = first // BLOCK, (first + count - 1) // BLOCK - first // BLOCK + 1
    values, labels, bounds = np.empty(count), np.empty(count, np.uint8), np.empty(nq)
    whole = stack_volume(tables, table, scale, np.full((n, 2), np.inf))
    whole_values = np.empty(count)
    block = (first + np.arange(count)) // BLOCK - q0
    ratios = []
    for b in range(n):
        fill_volume(volume, b, first, count, values, labels)
        fill_block_bounds(volume, b, q0, nq, bounds)
        assert np.all(np.abs(values) <= bounds[block]), f"beam {b}: a sample above its block's bound"
        fill_volume(whole, b, first, count, whole_values, labels)
        largest = np.zeros(nq)
        np.maximum.at(largest, block, np.abs(whole_values))
        tight = bounds[largest > 0] / largest[largest > 0]
        ratios.append(tight.max())
    assert max(ratios) <= 1.25 * 1.2, f"a bound {max(ratios):.2f}x its block's largest value"


def test_batched_tables_are_the_module_doc_sums():
    """The cut rows (a recursion) and the waveform (from the cut rows) of a batch of tables against the module
    doc's sums: the cells convolved with the pulse, and each row the cells in front of its boundary."""
    rng = np.random.default_rng(1)
    density = rng.random((3, 300)) * (rng.random((3, 300)) < 0.3)
    density[2] = 0.0
    kernel = np.exp(-0.5 * (np.arange(-REACH, REACH + 1) / 8.0) ** 2)
    o = np.arange(2 * REACH)
    for d, t in zip(density, tables_of_cells(density, 0.05, FOG, floor=0.5)):
        full = np.convolve(d, kernel)[REACH : REACH + len(d)]
        above = np.flatnonzero(full > 0.5)
        assert t.support == ((above[0] - REACH, above[-1] + 1 - REACH) if len(above) else (-REACH, -REACH))
        inside = np.zeros(len(d), bool)
        inside[t.support[0] + REACH : t.support[1] + REACH] = True
        assert np.allclose(t.wave, np.where(inside, full, 0.0), rtol=1e-13, atol=0.0)
        assert len(t.cut) == (t.support[1] + REACH + 2 - t.cut_first if len(above) else 0)
        for K, row in zip(range(t.cut_first, t.cut_first + len(t.cut)), t.cut):
            k = np.arange(K - 2 * REACH, K)[:, None]  # the cells reaching the row
            j = K - REACH + o[None, :] - k
            cells = np.where((k + REACH >= 0) & (k + REACH < len(d)), d[np.clip(k + REACH, 0, len(d) - 1)], 0.0)
            want = (cells * np.where(np.abs(j) <= REACH, kernel[np.clip(j + REACH, 0, 2 * REACH)], 0.0)).sum(axis=0)
            assert np.allclose(row, want, rtol=1e-13, atol=1e-13)


def test_realisations_are_the_mean_scaled_per_slab():
    """Each realisation's cells (batched, node-wise factors) are those of its density, the mean times its slab's
    factor, integrated on its own (high-pass included)."""
    mean = lambda r: 1.0 / (1.0 + r * r)  # noqa: E731
    edges = np.array([1.0, 1.3, 2.0, 2.1])
    factors = np.random.default_rng(2).uniform(0.0, 2.0, (4, len(edges) - 1))
    nodes, lower, upper = cell_nodes(sigma_m=0.3, r_max_m=4.0, start_m=0.5)
    slab = np.searchsorted(edges, nodes, side="right") - 1
    slab[(slab < 0) | (slab >= len(factors[0]))] = len(factors[0])
    got = realised_density(mean(nodes), factors, slab, lower, upper, tau_m=0.4)
    for f, cells in zip(factors, got):
        def realised(r, f=f):
            i = np.searchsorted(edges, r, side="right") - 1
            return mean(r) * np.where((i >= 0) & (i < len(f)), f[np.clip(i, 0, len(f) - 1)], 1.0)

        want = cell_density(realised, sigma_m=0.3, r_max_m=4.0, start_m=0.5, tau_m=0.4)
        assert np.allclose(cells, want, rtol=1e-13, atol=1e-15 * want.max())
