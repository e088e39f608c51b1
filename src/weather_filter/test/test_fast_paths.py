"""The learned filter's fast paths give the exact features: the polynomial azimuth (bins re-read from np.arctan2
where in doubt) and the range image's dense first-echo plane."""

import numpy as np
import pytest

import weather_filter.learned.features as features
from lidar_weather_sim.core.points import empty_points
from weather_filter.learned.azimuth import AZIMUTH_ERROR_RAD, approx_azimuth
from weather_filter.learned.features import FEATURE_NAMES, PointFeatures


def _scan(seed=0, n_channels=16, n_cols=900):
    """A synthetic organised scan: ``n_channels`` x ``n_cols`` beams over 360 deg, ranges 1-60 m, every 7th beam a
    second echo (some 6 echoes in one beam: more than a range-image cell keeps), and points on the axes (y = +-0
    with x < 0: azimuth +-pi) and at whole degrees."""
    rng = np.random.default_rng(seed)
    az = np.repeat(np.linspace(-np.pi, np.pi, n_cols, endpoint=False), n_channels)
    ch = np.tile(np.arange(n_channels), n_cols)
    el = np.radians(-15 + 2 * ch)
    r = rng.uniform(1, 60, len(az))
    extra = np.arange(0, len(az), 7)
    crowd = np.full(5, 3 * n_channels + 2)
    az, ch, el = (np.concatenate([v, v[extra], v[crowd]]) for v in (az, ch, el))
    r = np.concatenate([r, r[extra] * rng.uniform(1.001, 1.5, len(extra)), 2 + np.arange(5.0)])
    echo = np.concatenate([np.ones(len(az) - len(extra) - 5), np.full(len(extra) + 5, 2)])
    pts = empty_points(len(az) + 4)
    pts["x"][: len(az)] = r * np.cos(el) * np.cos(az)
    pts["y"][: len(az)] = r * np.cos(el) * np.sin(az)
    pts["z"][: len(az)] = r * np.sin(el)
    pts["channel"][: len(az)], pts["echo"][: len(az)] = ch, echo
    pts["x"][-4:], pts["y"][-4:] = [-5.0, -5.0, 3.0, -0.0], [0.0, -0.0, 0.0, 4.0]
    pts["channel"][-4:], pts["echo"][-4:] = 1, 1
    pts["epw"], pts["intensity"] = rng.uniform(0, 5, len(pts)), rng.integers(0, 255, len(pts))
    return pts


def test_log10_clamped_equals_the_compiled_log10_on_every_float32_it_sees():
    """Exhaustive over [1e-3, 1) (83.7M values, in chunks), plus values beyond both ends."""
    from numba import njit

    from weather_filter.learned.log10f import log10_clamped

    @njit
    def compiled(v, out):
        for i in range(len(v)):
            out[i] = np.log10(max(v[i], np.float32(1e-3))) if v[i] < 1 else np.float32(0.0)

    lo, hi = int(np.float32(1e-3).view(np.uint32)), int(np.float32(1.0).view(np.uint32))
    for start in range(lo - 1000, hi + 1000, 1 << 23):
        bits = np.arange(start, min(start + (1 << 23), hi + 1000), dtype=np.uint32)
        values = bits.view(np.float32)
        expected = np.empty_like(values)
        compiled(values, expected)
        log10_clamped(values, bits)
        assert np.array_equal(values.view(np.uint32), expected.view(np.uint32)), start


def test_approx_azimuth_is_within_its_bound():
    rng = np.random.default_rng(1)
    x = (rng.standard_normal(200_000) * 10 ** rng.uniform(-3, 3, 200_000)).astype(np.float32)
    y = (rng.standard_normal(200_000) * 10 ** rng.uniform(-3, 3, 200_000)).astype(np.float32)
    x[:8], y[:8] = [1, -1, 0, 0, 1, -1, 1, -1], [0, 1, 1, -1, 1, 1, -1, -1]
    a = np.empty(len(x))
    approx_azimuth(x, y, a)
    assert np.abs(a - np.arctan2(y.astype(float), x.astype(float))).max() < AZIMUTH_ERROR_RAD / 100


@pytest.mark.parametrize("offset", [-0.999, 0.999, "random"])
def test_features_do_not_depend_on_the_azimuth_error(monkeypatch, offset):
    """Any azimuth within the bound (here the exact one moved by up to 0.999 of it) gives bit-identical features."""
    pts = _scan()
    reference = PointFeatures()(pts)  # the polynomial azimuth
    exact = np.arctan2(pts["y"].astype(float), pts["x"].astype(float))
    shift = np.random.default_rng(2).uniform(-1, 1, len(pts)) if offset == "random" else offset

    def perturbed(x, y, azimuth):
        azimuth[:] = exact + shift * AZIMUTH_ERROR_RAD

    monkeypatch.setattr(features, "approx_azimuth", perturbed)
    out = PointFeatures()(pts)
    assert np.array_equal(out.view(np.uint32), reference.view(np.uint32))


def test_bins_of_points_on_the_negative_x_axis_follow_the_sign_of_y():
    pts = _scan()
    out = PointFeatures()(pts)
    n_radial = out[:, FEATURE_NAMES.index("n_radial")]
    az = np.degrees(np.arctan2(pts["y"].astype(float), pts["x"].astype(float)))
    counts = np.bincount(np.clip(((az + 180) / 1.0).astype(int), 0, 359), minlength=360)
    assert az[-4] == 180 and az[-3] == -180  # y = +0 and -0 at x = -5 m
    assert n_radial[-4] == counts[359] and n_radial[-3] == counts[0]


@pytest.mark.parametrize("window", [(2, 2), (1, 1), (3, 0)])
def test_range_image_features_with_crowded_cells_equal_a_direct_computation(window):
    """Second echoes and a beam of six returns (more than a cell keeps) against the numpy reference, for the
    shipped window (2 columns, 2 channels: compiled with constant bounds) and others."""
    import importlib.util
    from pathlib import Path

    spec = importlib.util.spec_from_file_location("_sim_trained", Path(__file__).with_name("test_sim_trained.py"))
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    pts = _scan()
    extractor = PointFeatures(ri_columns=window[0], ri_channels=window[1])
    out = extractor(pts)
    reference = module._range_image_reference(pts, extractor.last_step_rad, columns=window[0], channels=window[1])
    for name, expected in reference.items():
        assert np.allclose(out[:, FEATURE_NAMES.index(name)], expected, atol=1e-5), name


def test_stage_timing_runs_each_stage():
    from weather_filter.learned.filter import LearnedFilter
    from weather_filter.stage_timing import stages

    pts = _scan()
    filt = LearnedFilter.load()
    expected = filt(pts).remove
    for fn in stages(filt, pts).values():
        fn()
    filt.reset()  # the stages ran the filter (the frame-difference state)
    assert np.array_equal(filt(pts).remove, expected)
