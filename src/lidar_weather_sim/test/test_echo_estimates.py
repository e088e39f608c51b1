"""The echo detector's sample estimates: within their error bound of the exact samples, and the
echoes of overlapping pulses those of the exactly sampled waveform."""

import numpy as np
import pytest

from lidar_weather_sim.sensor import echo, radiometry


def _cluster(rng, n, spread):
    r = np.sort(rng.uniform(20.0, 20.0 + spread, n))
    a = np.exp(rng.uniform(0.0, 12.0, n))
    return r, a


@pytest.mark.parametrize(("pulses", "spread"), [(5, 0.1), (5, 1.0), (5, 4.0), (5, 5.5), (120, 15.0), (2, 30.0)])
def test_estimates_are_within_their_bound(pulses, spread):
    """Clusters of a few pulses, a fog-like volume (120 pulses over 15 m) and two pulses 100 widths apart."""
    rng = np.random.default_rng(3)
    s = 0.75 * radiometry.FWHM_TO_SIGMA
    dx = s / 8.0
    for _ in range(20):
        r, a = _cluster(rng, int(rng.integers(2, pulses + 1)), spread)
        lo = r[0] - 6.0 * s
        n = int((r[-1] - r[0] + 12.0 * s) / dx)
        buf = np.empty(n)
        tol, eps = echo._fill_estimates(r, a, 0, len(r), s, lo, dx, 0, n, buf)
        exact = np.array([echo._sample(r, a, 0, len(r), s, lo + k * dx) for k in range(n)])
        assert tol == echo.ESTIMATE_TOLERANCE and 0.0 < eps < 1e-190 * a.sum()
        assert np.all(np.abs(buf - exact) <= 1e-3 * tol * exact + eps)


def test_windows_longer_than_the_estimates_are_sampled_exactly():
    r, a = np.array([10.0, 400.0]), np.array([50.0, 60.0])
    s = 0.3
    n = echo.ESTIMATE_SAMPLES + 1
    buf = np.empty(n)
    assert echo._fill_estimates(r, a, 0, 2, s, 9.0, s / 8.0, 0, n, buf) == (0.0, 0.0)
    assert buf[100] == echo._sample(r, a, 0, 2, s, 9.0 + 100 * (s / 8.0))


def test_a_fog_like_volume_gives_the_echo_of_its_exactly_sampled_waveform():
    """100 pulses one sigma apart, decaying as 1/r^2 (a volume return): its echo found from the estimates is
    the one a brute-force scan of the exact samples on the detector's grid gives (to rounding: numba may
    fuse the grid's multiply-add); its range is the vertex of the parabola through the highest sample and
    its neighbours."""
    fwhm, thr = 0.75, 4.0
    s = fwhm * radiometry.FWHM_TO_SIGMA
    r = 3.0 + s * np.arange(100)
    a = 400.0 / r**2
    out = echo.detect_echoes(np.zeros(len(r), np.int64), r, a, np.full(len(r), 5, np.uint8),
                             np.zeros(len(r), np.uint32), threshold=radiometry.Threshold(1.0, 1.0, 3.0),
                             fwhm_m=fwhm, resolution_m=0.01, max_echoes=4)  # fmt: skip
    (start,), (count,) = out.runs
    dx = s / 8.0
    lo = min(r - np.array([echo._reach(x, thr, s) for x in a]))
    x = lo + dx * np.arange(int((r[-1] + 8.0 * s - lo) / dx))
    w = np.array([echo._sample(r, a, 0, len(r), s, xi) for xi in x])
    above = np.flatnonzero(w > thr)
    assert count == 1 and np.all(np.diff(above) == 1)
    k = int(np.argmax(w))
    w_lo, w_hi = (echo._sample(r, a, 0, len(r), s, x[k] + d) for d in (-dx, dx))
    vertex = x[k] + dx * 0.5 * (w_lo - w_hi) / (w_lo - 2.0 * w[k] + w_hi)
    assert out.range_m[start] == pytest.approx(vertex, abs=1e-9)
    assert out.amplitude[start] == pytest.approx(w.max(), rel=1e-12)
    assert out.epw_m[start] == pytest.approx((above[-1] - above[0]) * dx, abs=dx)


def test_two_pulses_match_a_sampled_waveform():
    """Two pulses 0.5 m apart: one echo, its range, peak and EPW those of the waveform (sampled
    every s / 8 on the detector's own grid: within a sample)."""
    fwhm, thr = 0.75, 4.0
    s = fwhm * radiometry.FWHM_TO_SIGMA
    r, a = np.array([30.0, 30.5]), np.array([200.0, 100.0])
    out = echo.detect_echoes(np.zeros(2, np.int64), r, a, np.array([1, 2], np.uint8), np.array([7, 8], np.uint32),
                             threshold=radiometry.Threshold(1.0, 1.0, 3.0), fwhm_m=fwhm, resolution_m=0.03, max_echoes=2)  # fmt: skip
    (start,), (count,) = out.runs
    assert count == 1
    x = np.arange(r[0] - 8.0, r[1] + 8.0, s / 64.0)
    w = (a[:, None] * np.exp(-0.5 * ((x[None, :] - r[:, None]) / s) ** 2)).sum(0)
    above = np.flatnonzero(w > thr)
    assert out.range_m[start] == pytest.approx(x[np.argmax(w)], abs=s / 8.0)
    assert out.amplitude[start] == pytest.approx(w.max(), rel=1e-2)
    width = (above[-1] - above[0]) * (s / 64.0)
    assert out.epw_m[start] == pytest.approx(width, abs=s / 8.0)
    assert (out.label[start], out.object_id[start]) == (1, 7)


def test_the_range_of_overlapping_pulses_is_the_waveforms_maximum_between_the_samples():
    """Seeded random clusters of 2-4 overlapping pulses: the echo's range is the waveform's maximum found by a
    fine scan (s / 2000) to 5 % of the detector's sample step s / 8 (median 0.5 %); the highest sample alone is
    up to half a step off (what the range was before the parabolic refinement)."""
    fwhm, thr = 0.75, 4.0
    s = fwhm * radiometry.FWHM_TO_SIGMA
    rng = np.random.default_rng(11)
    errors, grid_errors = [], []
    for _ in range(60):
        k = int(rng.integers(2, 5))
        r = np.sort(20.0 + rng.uniform(0.0, 1.2 * s * k, k))
        a = rng.uniform(20.0, 300.0, k)
        out = echo.detect_echoes(np.zeros(k, np.int64), r, a, np.ones(k, np.uint8), np.zeros(k, np.uint32),
                                 threshold=radiometry.Threshold(1.0, 1.0, 3.0), fwhm_m=fwhm, resolution_m=0.001,
                                 max_echoes=4)  # fmt: skip
        x = np.arange(r[0] - 3 * s, r[-1] + 3 * s, s / 2000.0)
        w = (a[:, None] * np.exp(-0.5 * ((x[None, :] - r[:, None]) / s) ** 2)).sum(0)
        (start,), (count,) = out.runs
        if count != 1 or np.sum(np.diff(np.sign(np.diff(w))) < 0) != 1:
            continue  # one echo with one maximum: the maximum is the echo's range
        true_max = x[np.argmax(w)]
        errors.append(abs(out.range_m[start] - true_max))
        lo = min(r - np.array([echo._reach(v, thr, s) for v in a]))  # the detector's grid
        grid = lo + (s / 8.0) * np.arange(int((r[-1] + 3 * s - lo) / (s / 8.0)))
        samples = [echo._sample(r, a, 0, k, s, g) for g in grid]
        grid_errors.append(abs(grid[int(np.argmax(samples))] - true_max))
    assert len(errors) >= 30
    assert max(errors) <= 0.05 * s / 8.0 and np.median(errors) <= 0.005 * s / 8.0
    assert max(grid_errors) > 0.3 * s / 8.0  # the highest sample alone: up to half a step off


@pytest.mark.parametrize("profile_name, seed", [("os1_128_2048", 11), ("vlp16", 12), ("hdl64e", 13)])
def test_pulses_in_a_faint_volume_give_the_whole_windows_echo_from_their_deciding_samples(profile_name, seed):
    """A hard target's pulses (1-3 within 0.25 m, 1.2-3000 thresholds) in a rain volume scaled to 0.05-0.9 of the
    threshold and cut at the target, on seeded draws: the echo of ``_isolated_echo`` (the samples in the two
    crossing bands and around the peak) equals, field for field and bit for bit, the one ``_open_echoes`` finds
    over the whole window; it decides most draws, and leaves to the window those it cannot (pulses near the
    threshold, or far apart)."""
    from lidar_weather_sim.sensor.profile import load_profile
    from lidar_weather_sim.sensor.volume_tables import INTERPOLATION_GAIN, build_table, stack_volume
    from lidar_weather_sim.testing.lidar_integral import medium_return

    profile = load_profile(profile_name)
    dark = radiometry.Threshold.under_sun(profile.detection)
    rain = medium_return(profile, "rain", 50.0)
    tables = [build_table(rain.density, sigma_m=rain.sigma_m, r_max_m=float(profile.range.max_m), label=4,
                          start_m=max(rain.overlap_start_m, radiometry.MIN_RANGE_M),
                          tau_m=float(profile.detection.ac_coupling_tau_m), floor=0.02 * dark.level)]  # fmt: skip
    thr = dark.level
    s = float(profile.pulse.fwhm_m) * radiometry.FWHM_TO_SIGMA
    dx = s / 8.0
    detector = echo.Detector(thr, s, 0.0, 2)
    rng = np.random.default_rng(seed)
    decided = 0
    draws = 300
    for _ in range(draws):
        k = int(rng.integers(1, 4))
        r = np.sort(rng.uniform(0.5, 15.0) + rng.uniform(0.0, 0.25, k))
        a = thr * 10 ** rng.uniform(np.log10(1.2), np.log10(3000.0), k) / k
        scale = rng.uniform(0.05, 0.9) * thr / (INTERPOLATION_GAIN * tables[0].wave.max())
        volume = stack_volume(tables, np.zeros((1, 1), np.int64), np.array([[scale]]), r[:1, None] + 0.05)
        v_max = thr * 1e-9 + INTERPOLATION_GAIN * scale * volume.peak[0]
        pulses = echo.Pulses(r, a, np.array([echo._reach(x, thr, s) for x in a]), np.full(k, 1, np.uint8),
                             np.arange(1, k + 1, dtype=np.uint32))  # fmt: skip
        outs = [echo.EchoBuffers(*(np.zeros(4, t) for t in (np.int64, np.uint8, np.float64, np.float64, np.float64,
                                                             np.uint8, np.uint32))) for _ in range(2)]  # fmt: skip
        scratch = echo.VolumeScratch(np.empty(0), np.empty(0, np.uint8), np.empty(0))
        got, _ = echo._isolated_echo(pulses, (0, k), detector, volume, 0, v_max, outs[0], 0, scratch)
        first = int(np.floor((r[0] - 12.0 * s) / dx))
        n = int(np.ceil((r[-1] + 12.0 * s) / dx)) - first
        whole, _ = echo._open_echoes(pulses, (0, k), detector, volume, (0, first, n), outs[1], 0, 2, np.empty(n + 2),
                                     scratch)  # fmt: skip
        if got < 0:
            continue
        decided += 1
        assert got == whole == 1
        for field in ("range_m", "amplitude", "epw_m", "label", "object_id"):
            assert getattr(outs[0], field)[0] == getattr(outs[1], field)[0], field
    assert decided > 0.6 * draws
    far = echo.Pulses(np.array([5.0, 5.0 + 6.0 * s]), np.array([10.0 * thr, 10.0 * thr]), np.zeros(2),
                      np.ones(2, np.uint8), np.ones(2, np.uint32))  # fmt: skip
    assert echo._isolated_echo(far, (0, 2), detector, volume, 0, v_max, outs[0], 0, scratch)[0] == -1
