"""The receiver's AC coupling (sensor.ac_coupling) against the high-pass written out by quadrature, and what it
makes of fog's volume return in the physical atmosphere."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.integrate import cumulative_trapezoid

from lidar_weather_sim.regions.base import RegionEffect
from lidar_weather_sim.regions.physical_air import PhysicalAir
from lidar_weather_sim.sensor.ac_coupling import highpass_slabs
from lidar_weather_sim.sensor.echo import detect_echoes
from lidar_weather_sim.sensor.profile import SensorProfile
from lidar_weather_sim.sensor.radiometry import Threshold
from lidar_weather_sim.sim.simulator import _volume
from lidar_weather_sim.testing.fixtures import beams_along_x, receiver_variant


def brute_force_highpass(density, r: np.ndarray, tau: float) -> np.ndarray:
    """y(r) = x(r) - (1/tau) integral_0^r x(r') exp(-(r - r') / tau) dr' on the fine grid ``r``, the integral by
    trapezoids as exp(-r / tau) integral_0^r x(r') exp(r' / tau) dr'."""
    x = density(r)
    return x - np.exp(-r / tau) / tau * cumulative_trapezoid(x * np.exp(r / tau), r, initial=0.0)


@pytest.mark.parametrize("tau", [0.05, 0.1, 0.3])
def test_slabs_lose_what_the_highpass_takes_from_them(tau):
    """Slabs of uneven widths (thinner than tau and thicker), with a gap: each slab's filtered amount equals
    the high-pass of the piecewise-uniform density, integrated over the slab by quadrature, to 0.5 % of the
    largest slab (the quadrature's own error); clipped at 0 where the integral is negative."""
    edges = np.concatenate([np.geomspace(0.3, 2.0, 12), np.arange(2.3, 6.0, 0.4)])
    lower, upper = edges[:-1], edges[1:]
    gap = np.ones(len(lower), bool)
    gap[14] = False  # a slab left out: its density is 0 and the tails decay across it
    lower, upper = lower[gap], upper[gap]
    centres = 0.5 * (lower + upper)
    rises = np.clip((centres - 0.3) / 1.5, 0.0, 1.0) / np.maximum(centres, 0.5) ** 2  # an overlap rise, then 1/r^2
    amount = rises * (upper - lower)

    def density(r):
        k = np.searchsorted(upper, r, side="right")
        inside = (k < len(lower)) & (r >= lower[np.minimum(k, len(lower) - 1)])
        return np.where(inside, rises[np.minimum(k, len(lower) - 1)], 0.0)

    grid = np.linspace(0.0, 6.0, 60001)
    y = brute_force_highpass(density, grid, tau)
    expected = np.array([np.trapezoid(y[(grid >= a) & (grid <= b)], grid[(grid >= a) & (grid <= b)])
                         for a, b in zip(lower, upper)])  # fmt: skip
    got = highpass_slabs(amount, lower, upper, np.zeros(len(amount), np.int64), tau)
    assert (expected < 0).any() and (expected > 0).any()  # a lobe and an undershoot
    np.testing.assert_allclose(got, np.maximum(expected, 0.0), atol=5e-3 * amount.max())
    # beams apart: the second beam's slabs start with no tail of the first's
    two = highpass_slabs(np.tile(amount, 2), np.tile(lower, 2), np.tile(upper, 2), np.repeat([0, 1], len(amount)), tau)
    np.testing.assert_array_equal(two[len(amount):], got)
    np.testing.assert_array_equal(highpass_slabs(amount, lower, upper, np.zeros(len(amount), np.int64), 0.0), amount)


def first_echoes(profile: SensorProfile, visual_range_m: float, n_beams: int = 300):
    """(share of beams with an echo, median range m, median EPW m) of the first echo of fog alone (no hit)."""
    air = PhysicalAir(profile, visual_range_m, None)
    rays = beams_along_x(np.full(n_beams, np.inf))
    _, terms = air.scatterers(rays, np.random.default_rng(0))
    effect = RegionEffect(transmission=np.ones(rays.shape), range_offset_m=np.zeros(rays.shape), volume=terms)
    none = np.zeros(0)
    e = detect_echoes(none.astype(np.int64), none, none, none.astype(np.uint8), none.astype(np.uint32),
                      threshold=Threshold.under_sun(profile.detection), fwhm_m=profile.pulse.fwhm_m,
                      resolution_m=profile.range.resolution_m, max_echoes=3, volume=_volume(rays, effect))  # fmt: skip
    rows = np.concatenate([np.arange(a, a + c) for a, c in zip(*e.runs)] + [np.zeros(0, np.int64)]).astype(np.int64)
    first = rows[e.echo[rows] == 1]
    if not len(first):
        return 0.0, np.nan, np.nan
    return len(first) / n_beams, float(np.median(e.range_m[first])), float(np.median(e.epw_m[first]))


def test_ac_coupling_turns_fogs_long_volume_echo_into_a_short_near_one():
    """scala4's optics with the aperture's defocus. DC-coupled, fog at 30 m and at 2 km visual range gives every beam
    one echo 5-12 m long starting in the near field. AC-coupled (tau 0.1 m) the dense fog's echo is its rise only,
    ~2 m long near 1.2 m (Hahner et al. 2021 measured a soft echo of ~1.5 m EPW near 1.1 m in their fog chamber),
    and fog of 2 km visual range falls below the threshold."""
    dc_dense, dc_thin = first_echoes(receiver_variant("scala4", "defocus", 0.0), 30.0), first_echoes(receiver_variant("scala4", "defocus", 0.0), 2000.0)
    assert dc_dense[0] == dc_thin[0] == 1.0 and dc_dense[2] > 10.0 and dc_thin[2] > 5.0
    share, range_m, epw = first_echoes(receiver_variant("scala4", "defocus", 0.1), 30.0)
    assert share == 1.0 and 0.9 < range_m < 1.5 and 1.2 < epw < 2.5
    assert first_echoes(receiver_variant("scala4", "defocus", 0.1), 2000.0)[0] < 0.05
