"""Radiometry of the receiver: the one home of the LIDAR equation, the detection threshold and intensity.

- Peak amplitude of a return (noise units), the LIDAR equation for an extended target::

      A = C w rho / max(R, R_min)^2 * T_two_way * O(R)

  ``C`` the profile's power constant (noise units m^2), ``w`` the sub-ray's share of the beam energy,
  ``rho`` the effective reflectance (:func:`surface_reflectance`), ``R`` the range (m), ``T_two_way`` the
  product of all losses out and back (cover ~ tau^2, Beer-Lambert exp(-2 alpha R), occlusion) and ``O`` the
  biaxial overlap factor (:func:`overlap_factor`).
- Threshold ``T = mu + x sigma`` (thesis paper 2, eq. 3-5); background light (sun irradiance, W/m^2) raises
  mu and sigma linearly (:meth:`Threshold.under_sun`). The *dark* threshold (no background light) is the
  reference of intensity and of region scatterer strengths (:func:`dark_level`).
- Intensity 0-255: logarithmic in the peak amplitude over the dark threshold, 0 at the threshold,
  255 at ``intensity_dynamic_range`` times above it (:func:`intensity_byte`).

Each formula exists once as a numpy function and, where a numba kernel needs it per element, once as a
scalar ``@njit`` twin next to it with the same operations in the same order (the tests check they agree
bit for bit).
"""

from __future__ import annotations

from dataclasses import dataclass

import numba
import numpy as np

FWHM_TO_SIGMA = 1.0 / (2.0 * np.sqrt(2.0 * np.log(2.0)))
#: Power returned by a retro-reflective surface relative to a Lambertian one of the
#: same albedo at normal incidence. Retro-reflective sheeting has R_A ~ 30-250
#: cd/(lx m^2) at small observation angles (EN 12899-1 class RA1/RA2), a Lambertian
#: white surface 1/pi ~ 0.32: a gain of ~100-800; we use the low end.
RETRO_GAIN = 100.0
#: Ranges below this are clamped in 1/R^2 (m), so cover returns stay finite.
MIN_RANGE_M = 0.05


@dataclass(frozen=True)
class Threshold:
    """Receiver noise and threshold, in the profile's noise units."""

    noise_mean: float
    noise_sigma: float
    threshold_sigma: float

    @property
    def level(self) -> float:
        return self.noise_mean + self.threshold_sigma * self.noise_sigma

    @classmethod
    def under_sun(cls, detection, irradiance_w_m2: float = 0.0) -> "Threshold":
        """The threshold of a profile's ``detection`` block with background light ``irradiance_w_m2`` (W/m^2)."""
        e = irradiance_w_m2
        return cls(detection.noise_mean + detection.sun_noise_per_w_m2 * e,
                   detection.noise_sigma + detection.sun_sigma_per_w_m2 * e, detection.threshold_sigma)  # fmt: skip


def dark_level(detection) -> float:
    """The threshold mu + x sigma without background light (noise units) of a profile's ``detection`` block."""
    return detection.noise_mean + detection.threshold_sigma * detection.noise_sigma


def surface_reflectance(reflectivity, retro_share, cos_incidence):
    """Effective reflectance of a surface hit: Lambertian share x cos(theta) + retro share x gain."""
    cos_incidence = np.clip(cos_incidence, 0.0, 1.0)
    return reflectivity * ((1.0 - retro_share) * cos_incidence + retro_share * RETRO_GAIN)


@numba.njit(cache=True, inline="always")
def surface_reflectance_at(reflectivity, retro_share, cos_incidence):
    """:func:`surface_reflectance` of one hit, for numba kernels."""
    cos_incidence = min(max(cos_incidence, 0.0), 1.0)
    return reflectivity * ((1.0 - retro_share) * cos_incidence + retro_share * RETRO_GAIN)


def peak_amplitude(power_constant, weight, reflectance, range_m, two_way_transmission, overlap):
    """LIDAR equation for an extended target: ``C w rho / R^2 * T_two_way * O(R)`` (noise units)."""
    r = np.maximum(range_m, MIN_RANGE_M)
    return power_constant * weight * reflectance / (r * r) * two_way_transmission * overlap


@numba.njit(cache=True, inline="always")
def peak_amplitude_at(power_constant, weight, reflectance, range_m, two_way_transmission, overlap):
    """:func:`peak_amplitude` of one return, for numba kernels."""
    r = max(range_m, MIN_RANGE_M)
    return power_constant * weight * reflectance / (r * r) * two_way_transmission * overlap


def reflectance_for_peak(peak, power_constant, weight, range_m):
    """The reflectance that gives a return of amplitude ``peak`` (noise units) at ``range_m`` (m) with full
    transmission and overlap: the LIDAR equation solved for rho (regions state scatterer strengths as peaks)."""
    return peak * np.maximum(range_m, MIN_RANGE_M) ** 2 / (power_constant * weight)


def overlap_factor(range_m, start_m: float, full_m: float):
    """Biaxial optics: 0 before ``start_m``, smoothstep to 1 at ``full_m``, then 1."""
    if full_m <= start_m:
        return (np.asarray(range_m) >= start_m).astype(np.float64)
    u = np.clip((np.asarray(range_m) - start_m) / (full_m - start_m), 0.0, 1.0)
    return u * u * (3.0 - 2.0 * u)


@numba.njit(cache=True, inline="always")
def overlap_at(range_m, start_m, full_m):
    """:func:`overlap_factor` at one range, for numba kernels."""
    if full_m <= start_m:
        return 1.0 if range_m >= start_m else 0.0
    u = min(max((range_m - start_m) / (full_m - start_m), 0.0), 1.0)
    return u * u * (3.0 - 2.0 * u)


def reflectivity_intensity(reflectivity_percent, range_m, profile) -> np.ndarray:
    """Intensity bytes (0-255, ``profile``'s scale) of returns a sensor reported as a calibrated reflectivity
    (percent of a Lambertian target at normal incidence, > 100 for retro-reflectors: Ouster's REFLECTIVITY
    channel, which ``import-ouster`` writes as intensity): the peak ``A = C rho / max(R, R_min)^2 O(R)`` of a
    full beam in clear air (``R`` the range, m) on the profile's log scale over its dark threshold."""
    det, optics = profile.detection, profile.optics
    rho = np.asarray(reflectivity_percent, dtype=np.float64) / 100.0
    r = np.asarray(range_m, dtype=np.float64)
    peak = peak_amplitude(det.power_constant, 1.0, rho, r, 1.0, overlap_factor(r, optics.overlap_start_m,
                                                                               optics.overlap_full_m))
    log_ratio = np.log(np.maximum(peak, 1e-300) / dark_level(det))
    return np.clip(np.rint(255.0 * log_ratio / np.log(det.intensity_dynamic_range)), 0, 255).astype(np.uint8)


@numba.njit(cache=True, inline="always")
def intensity_byte(log_ratio, log_span):
    """Intensity 0-255 of an echo whose peak is exp(``log_ratio``) times the dark threshold;
    ``log_span`` = ln(intensity_dynamic_range)."""
    return np.uint8(min(max(np.rint(255.0 * (log_ratio / log_span)), 0.0), 255.0))
