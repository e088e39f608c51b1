"""The receiver's radiometry: the numba kernels' scalar twins compute what the numpy functions compute."""

import numba
import numpy as np
import pytest

from lidar_weather_sim.sensor import radiometry as rad
from lidar_weather_sim.sensor.profile import load_profile


@numba.njit
def _kernel_path(power, weight, refl, retro, cos_inc, rng, two_way, start, full):
    """What the surface-return kernel does per sub-ray."""
    n = len(refl)
    out = np.empty(n)
    for k in range(n):
        rho = rad.surface_reflectance_at(refl[k], retro[k], cos_inc[k])
        out[k] = rad.peak_amplitude_at(power, weight[k], rho, rng[k], two_way[k], rad.overlap_at(rng[k], start, full))
    return out


@pytest.mark.parametrize("start, full", [(0.3, 2.5), (1.0, 1.0)])
def test_scalar_twins_agree_bit_for_bit(start, full):
    rng = np.random.default_rng(4)
    n = 5000
    refl, retro, weight = rng.uniform(0, 1, n), rng.choice([0.0, 0.0, 0.3, 1.0], n), rng.uniform(0.01, 1, n)
    cos_inc, two_way = rng.uniform(-0.2, 1.2, n), rng.uniform(0, 1, n)
    ranges = np.concatenate([rng.uniform(0.0, 0.2, 100), rng.uniform(0, 200, n - 100)])  # below MIN_RANGE_M too
    numpy_path = rad.peak_amplitude(
        7.5e5, weight, rad.surface_reflectance(refl, retro, cos_inc), ranges, two_way,
        rad.overlap_factor(ranges, start, full),
    )  # fmt: skip
    kernel = _kernel_path(7.5e5, weight, refl, retro, cos_inc, ranges, two_way, start, full)
    assert np.array_equal(numpy_path, kernel)
    assert (kernel[ranges < start] == 0).all() and kernel.max() > 0


def test_reflectance_for_peak_inverts_the_lidar_equation():
    r = np.array([0.01, 0.5, 3.0, 40.0])
    rho = rad.reflectance_for_peak(np.array([5.0, 5.0, 5.0, 5.0]), 2.0e4, 0.25, r)
    assert np.allclose(rad.peak_amplitude(2.0e4, 0.25, rho, r, 1.0, 1.0), 5.0)
    assert rho[0] == rho[0] and rho[0] == pytest.approx(5.0 * rad.MIN_RANGE_M**2 / 5.0e3)  # clamped below 5 cm


def test_threshold_rises_with_sun_and_intensity_spans_the_dynamic_range():
    det = load_profile("scala4").detection
    dark = rad.Threshold.under_sun(det, 0.0)
    assert dark.level == pytest.approx(rad.dark_level(det))
    sunny = rad.Threshold.under_sun(det, 500.0)
    assert sunny.level == pytest.approx(dark.level + 500 * (det.sun_noise_per_w_m2 + det.threshold_sigma * det.sun_sigma_per_w_m2))
    span = np.log(det.intensity_dynamic_range)
    assert rad.intensity_byte(0.0, span) == 0
    assert rad.intensity_byte(span, span) == 255
    assert rad.intensity_byte(0.5 * span, span) in (127, 128)
    assert rad.intensity_byte(2 * span, span) == 255 and rad.intensity_byte(-1.0, span) == 0
