"""The volume return as the echo stage's pulses (lidar_weather_sim.regions.volume_return) against the
LIDAR-equation integral computed apart, by adaptive quadrature, for fog, rain and snow on scala4 and OS1."""

from __future__ import annotations

import numpy as np
import pytest

from lidar_weather_sim.regions.volume_return import VolumeReturn
from lidar_weather_sim.sensor.profile import load_profile
from lidar_weather_sim.testing.lidar_integral import lidar_integral, medium_return


def volume(profile_name: str, kind: str, value: float) -> VolumeReturn:
    return medium_return(load_profile(profile_name), kind, value)


@pytest.mark.parametrize("profile", ["scala4", "os1_128_2048"])
@pytest.mark.parametrize("kind, value", [("fog", 30.0), ("fog", 200.0), ("rain", 10.0), ("snow", 2.0)])
def test_pulses_sum_to_the_lidar_equation_integral(profile, kind, value):
    v = volume(profile, kind, value)
    ranges = np.array([0.5, 1.0, 2.0, 3.5, 6.0, 15.0, 40.0])
    for hit in (np.inf, 4.0):
        got = v.waveform(ranges, hit)
        want = np.array([lidar_integral(v, r, hit) for r in ranges])
        np.testing.assert_allclose(got, want, rtol=2e-3, atol=1e-9 * want.max())


def test_denser_fog_returns_more_near_and_less_far():
    thin, thick = volume("scala4", "fog", 200.0), volume("scala4", "fog", 30.0)
    assert thick.waveform(np.array([3.0]))[0] > 3 * thin.waveform(np.array([3.0]))[0]
    assert thick.waveform(np.array([60.0]))[0] < thin.waveform(np.array([60.0]))[0]


def test_nothing_behind_the_hit():
    v = volume("scala4", "fog", 50.0)
    centres, _ = v.pulses(hit_m=7.0)
    assert centres.max() < 7.0 and centres.min() >= v.overlap_start_m
