"""The volume return of a homogeneous medium (fog, rain, snow) in one beam: the waveform the medium alone
gives, in the simulator's noise units, before any hard target.

Single scattering, the LIDAR equation for a distributed target: a slab of thickness dr at range r
backscatters ``beta dr`` per sr, as a Lambertian surface of albedo ``rho = pi beta dr`` does
(a Lambertian surface backscatters ``rho / pi`` per sr). With the simulator's extended-target equation
(:func:`lidar_weather_sim.sensor.radiometry.peak_amplitude`, the whole beam: sub-ray weights sum to 1)
and its Gaussian pulse of sigma ``s`` in range, the received waveform is::

    w(r) = C pi beta * integral_0^R_hit O(r') exp(-2 alpha r') / r'^2 * exp(-(r - r')^2 / (2 s^2)) dr'

with ``C`` the profile's power constant, ``O`` its overlap function, ``alpha`` (1/m) and ``beta``
(1/(m sr)) the medium's extinction and backscatter (:mod:`lidar_weather_sim.physics.coefficients`) and
``R_hit`` the range of the beam's hard target (the medium behind it is hidden). The integral starts at the
overlap's start, and not before ``MIN_RANGE_M`` (:mod:`lidar_weather_sim.sensor.radiometry`), the nearest
range the simulator's LIDAR equation knows: a profile without biaxial optics (overlap 1 from 0 m) would
otherwise see an unbounded 1/r^2.

:meth:`VolumeReturn.pulses` writes the integral as a sum of the echo stage's own Gaussian pulses, one
per slab of ``spacing`` (midpoint rule): each is a candidate return of amplitude
``C pi beta h O(r_k) exp(-2 alpha r_k) / r_k^2``, so the echo stage finds the volume echo, its range and
its EPW as it finds any other. Slabs are ``spacing`` thick (default s / 2) and, near the sensor, no thicker
than a tenth of their range: the sum is then within 0.2 % of the integral.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from lidar_weather_sim.sensor.radiometry import MIN_RANGE_M, overlap_factor


@dataclass(frozen=True)
class VolumeReturn:
    """A homogeneous medium seen by one profile's beam (ranges in m along the beam, sensor frame)."""

    power_constant: float  # C of the LIDAR equation (noise units m^2)
    alpha: float  # extinction (1/m)
    beta: float  # backscatter (1/(m sr))
    sigma_m: float  # the pulse's Gaussian sigma in range (m)
    overlap_start_m: float
    overlap_full_m: float
    overlap_fn: Callable[[np.ndarray], np.ndarray] | None = None  # O(r) itself (else the smoothstep of the two)

    def overlap(self, range_m: np.ndarray) -> np.ndarray:
        """O(r): ``overlap_fn`` when given, else the simulator's smoothstep from start to full."""
        if self.overlap_fn is not None:
            return self.overlap_fn(range_m)
        return overlap_factor(range_m, self.overlap_start_m, self.overlap_full_m)

    def density(self, range_m: np.ndarray) -> np.ndarray:
        """The integrand without the pulse: ``C pi beta O(r) exp(-2 alpha r) / r^2`` (noise units per m)."""
        r = np.maximum(np.asarray(range_m, dtype=np.float64), MIN_RANGE_M)
        overlap = self.overlap(r)
        return self.power_constant * np.pi * self.beta * overlap * np.exp(-2.0 * self.alpha * r) / (r * r)

    def slabs(self, hit_m: float, spacing_m: float | None = None, r_max_m: float | None = None):
        """(centres, thicknesses) in m of the slabs in front of a hit at ``hit_m`` (inf: none) out to ``r_max_m``
        (default: the hit, or 20 / alpha): ``spacing_m`` thick (default s / 2) and, near the sensor, where
        1/r^2 changes fast, no thicker than a tenth of their range."""
        h = float(spacing_m or self.sigma_m / 2.0)
        end = min(hit_m, r_max_m if r_max_m is not None else 20.0 / max(self.alpha, 1e-6))
        start = max(self.overlap_start_m, MIN_RANGE_M)
        if end <= start:
            return np.zeros(0), np.zeros(0)
        switch = max(start, 10.0 * h)
        near = np.geomspace(start, switch, max(int(np.ceil(np.log(switch / start) / np.log(1.1))), 1) + 1)
        edges = np.unique(np.concatenate([near, np.arange(switch, end, h), [end]]))
        edges = edges[edges <= end]
        return 0.5 * (edges[1:] + edges[:-1]), np.diff(edges)

    def pulses(self, hit_m: float, spacing_m: float | None = None, r_max_m: float | None = None,
               floor: float = 0.0) -> tuple[np.ndarray, np.ndarray]:  # fmt: skip
        """(ranges, amplitudes) of the slabs' pulses (:meth:`slabs`); pulses below ``floor`` (noise units) are
        left out."""
        centres, width = self.slabs(hit_m, spacing_m, r_max_m)
        amplitude = self.density(centres) * width
        keep = amplitude > floor
        return centres[keep], amplitude[keep]

    def waveform(self, range_m: np.ndarray, hit_m: float = np.inf, spacing_m: float | None = None) -> np.ndarray:
        """w(r) at ``range_m`` from :meth:`pulses` (noise units)."""
        r = np.asarray(range_m, dtype=np.float64)
        centres, amplitude = self.pulses(hit_m, spacing_m)
        d = (r[..., None] - centres) / self.sigma_m
        return np.sum(amplitude * np.exp(-0.5 * d * d), axis=-1)
