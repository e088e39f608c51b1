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


def test_a_calibrated_reflectivity_is_the_byte_the_simulator_gives_that_surface():
    """``reflectivity_intensity`` (make-measured --on --intensity-scale reflectivity, for Ouster's calibrated
    reflectivity): a recorded reflectivity of rho percent at R m is the intensity the simulator reports for a
    Lambertian wall of reflectance rho hit square-on at R m; 10 % at 20 m on os1_128_1024 is byte 99 (C 576000:
    255 ln(576000 x 0.1 / 20^2 / 4) / ln 1e4), not the barely detected return byte 10 would be on that scale."""
    import yaml

    from lidar_weather_sim.core.paths import config_dir
    from lidar_weather_sim.sim.simulator import LidarSimulator
    from lidar_weather_sim.testing.fixtures import one_frame, scene_of, simple_profile, wall

    concrete = yaml.safe_load((config_dir() / "materials.yaml").read_text())["materials"]["concrete"]
    profile = simple_profile()
    points = one_frame(LidarSimulator(profile, scene_of(wall(20.0, "concrete", 1)), seed=0)).points
    square_on = points[np.argmin(np.abs(points["azimuth"]))]
    assert abs(square_on["azimuth"]) < 1e-6 and square_on["distance"] == pytest.approx(20.0, abs=1e-4)
    byte = rad.reflectivity_intensity(100.0 * concrete["reflectivity"], 20.0, profile)
    assert byte == square_on["intensity"] and 0 < byte < 255
    os1 = load_profile("os1_128_1024")
    assert rad.reflectivity_intensity(np.array([10.0]), np.array([20.0]), os1)[0] == 99
