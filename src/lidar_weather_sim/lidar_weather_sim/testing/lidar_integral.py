"""An independent reference for the volume return, for tests: the LIDAR equation's integral over a medium,
written from the equation alone and computed by scipy's adaptive quadrature (slow, simple).

At range r (m along the beam) the received return of a homogeneous medium in front of a hard target at
``hit_m`` is ``C pi beta int O(x) exp(-2 alpha x) / x^2 exp(-(r - x)^2 / (2 s^2)) dx`` (noise units), with the
smoothstep overlap O between the profile's overlap start and full overlap, from the simulator's nearest range on.
"""

from __future__ import annotations

import numpy as np
from scipy.integrate import quad

from lidar_weather_sim.physics.coefficients import medium
from lidar_weather_sim.regions.volume_return import VolumeReturn
from lidar_weather_sim.sensor.profile import SensorProfile
from lidar_weather_sim.sensor.radiometry import FWHM_TO_SIGMA, MIN_RANGE_M


def medium_return(profile: SensorProfile, kind: str, value: float) -> VolumeReturn:
    """The volume return of ``kind`` (fog: visual range m; rain, snow: mm/h) seen by ``profile``."""
    m = medium(kind, value, profile.optics.wavelength_nm or 905.0)
    return VolumeReturn(profile.detection.power_constant, m.alpha, m.beta, profile.pulse.fwhm_m * FWHM_TO_SIGMA,
                        profile.optics.overlap_start_m, profile.optics.overlap_full_m)  # fmt: skip


def lidar_integral(v: VolumeReturn, r: float, hit_m: float) -> float:
    """The integral of the module doc at range ``r`` (m) for the medium in front of ``hit_m`` (m; inf: none)."""

    def integrand(x: float) -> float:
        if x < v.overlap_start_m:
            o = 0.0
        elif x >= v.overlap_full_m:
            o = 1.0
        else:
            u = (x - v.overlap_start_m) / (v.overlap_full_m - v.overlap_start_m)
            o = u * u * (3 - 2 * u)
        return o * np.exp(-2 * v.alpha * x) / x**2 * np.exp(-((r - x) ** 2) / (2 * v.sigma_m**2))

    # the pulse is below e^-50 beyond 10 sigma: integrate there only (quad misses a narrow peak on a long interval)
    lo = max(v.overlap_start_m, MIN_RANGE_M, r - 10 * v.sigma_m)
    hi = min(hit_m, r + 10 * v.sigma_m)
    if hi <= lo:
        return 0.0
    breaks = [x for x in (r, v.overlap_full_m) if lo < x < hi]
    value, _ = quad(integrand, lo, hi, points=breaks or None, limit=400, epsabs=0.0, epsrel=1e-10)
    return v.power_constant * np.pi * v.beta * value
