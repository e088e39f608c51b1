"""The volume return as the echo stage's pulses (lidar_weather_sim.regions.volume_return) against the
LIDAR-equation integral computed apart, by adaptive quadrature, for fog, rain and snow on scala4 and OS1."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.integrate import quad

from lidar_weather_sim.physics.coefficients import medium
from lidar_weather_sim.regions.volume_return import VolumeReturn
from lidar_weather_sim.sensor.profile import load_profile
from lidar_weather_sim.sensor.radiometry import FWHM_TO_SIGMA, MIN_RANGE_M


def volume(profile_name: str, kind: str, value: float) -> VolumeReturn:
    p = load_profile(profile_name)
    m = medium(kind, value, p.optics.wavelength_nm or 905.0)
    return VolumeReturn(p.detection.power_constant, m.alpha, m.beta, p.pulse.fwhm_m * FWHM_TO_SIGMA,
                        p.optics.overlap_start_m, p.optics.overlap_full_m)  # fmt: skip


def reference(v: VolumeReturn, r: float, hit_m: float) -> float:
    """The integral of the module doc by scipy's adaptive quadrature, written from the equation alone."""

    def integrand(x: float) -> float:
        x = max(x, 0.05)
        if x < v.overlap_start_m:
            o = 0.0
        elif x >= v.overlap_full_m:
            o = 1.0
        else:
            u = (x - v.overlap_start_m) / (v.overlap_full_m - v.overlap_start_m)
            o = u * u * (3 - 2 * u)
        return o * np.exp(-2 * v.alpha * x) / x**2 * np.exp(-((r - x) ** 2) / (2 * v.sigma_m**2))

    # the pulse is below e^-50 beyond 10 sigma: integrate there only (quad misses a narrow peak on a long interval)
    lo = max(v.overlap_start_m, MIN_RANGE_M, r - 10 * v.sigma_m)  # the medium from the simulator's nearest range
    hi = min(hit_m, 20.0 / v.alpha, r + 10 * v.sigma_m)
    if hi <= lo:
        return 0.0
    breaks = [x for x in (r, v.overlap_full_m) if lo < x < hi]
    value, _ = quad(integrand, lo, hi, points=breaks or None, limit=400)
    return v.power_constant * np.pi * v.beta * value


@pytest.mark.parametrize("profile", ["scala4", "os1_128_2048"])
@pytest.mark.parametrize("kind, value", [("fog", 30.0), ("fog", 200.0), ("rain", 10.0), ("snow", 2.0)])
def test_pulses_sum_to_the_lidar_equation_integral(profile, kind, value):
    v = volume(profile, kind, value)
    ranges = np.array([0.5, 1.0, 2.0, 3.5, 6.0, 15.0, 40.0])
    for hit in (np.inf, 4.0):
        got = v.waveform(ranges, hit)
        want = np.array([reference(v, r, hit) for r in ranges])
        np.testing.assert_allclose(got, want, rtol=2e-3, atol=1e-9 * want.max())


def test_denser_fog_returns_more_near_and_less_far():
    thin, thick = volume("scala4", "fog", 200.0), volume("scala4", "fog", 30.0)
    assert thick.waveform(np.array([3.0]))[0] > 3 * thin.waveform(np.array([3.0]))[0]
    assert thick.waveform(np.array([60.0]))[0] < thin.waveform(np.array([60.0]))[0]


def test_nothing_behind_the_hit():
    v = volume("scala4", "fog", 50.0)
    centres, _ = v.pulses(hit_m=7.0)
    assert centres.max() < 7.0 and centres.min() >= v.overlap_start_m
