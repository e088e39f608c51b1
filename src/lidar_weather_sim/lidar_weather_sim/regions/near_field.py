"""Stochastic near-field scatterers (thesis paper 2, Fig. 5 and line 742), shared by the cover and
atmosphere regions.

Range model per beam: a Poisson number of scatterers; each is a *cover*
return with probability ``cover_share`` (multipath on the sensor cover: range
exponential with scale ``cover_scale_m``, truncated to 0-``cover_max_m``, reaches
the receiver without the biaxial overlap) or else a *volume* return (drop, flake,
droplet) uniform in range over ``volume_range_m``. The volume returns' detection
probability follows from the echo stage: the overlap factor O(R) rises from
0.5 m to full at ~1.8 m and 1/R^2 falls beyond, which makes the plateau with
the overlap peak of the paper's histograms (snow: maximum near 1.8 m).

Strength: cover returns get a log-normal peak amplitude relative to the
sensor's dark threshold (median ``amplitude_median``, log-sd ``amplitude_sigma_ln``),
times exp(-R / ``cover_amp_scale_m``) when that is > 0 (longer multipath paths inside
the housing lose more: a raised threshold, e.g. sunlight, keeps only the closest);
volume returns get the same distribution *at* ``overlap_full_m`` and scale with
1/R^2 elsewhere (a particle's backscatter). A scatterer occludes the share
amplitude / ``occlusion_amplitude`` (capped at 1) of its sub-ray behind it. Both are converted into the
effective reflectance of the region protocol (P = C w rho / R^2).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from lidar_weather_sim.regions.base import Scatterers
from lidar_weather_sim.sensor.radiometry import MIN_RANGE_M, dark_level, reflectance_for_peak


@dataclass(frozen=True)
class NearFieldModel:
    rate_per_beam: float
    cover_share: float
    cover_scale_m: float
    amplitude_median: float
    amplitude_sigma_ln: float
    volume_range_m: tuple[float, float] = (0.5, 5.0)
    cover_max_m: float = 0.5
    occlusion_amplitude: float = 100.0  # a peak this many times the dark threshold blocks the whole sub-ray
    cover_amp_scale_m: float = 0.0  # > 0: cover amplitude x exp(-R / scale) (longer multipath paths are weaker)


def truncated_exponential(rng: np.random.Generator, scale_m: float, max_m: float, n: int) -> np.ndarray:
    """Exponential ranges (m) with ``scale_m``, truncated to [0, max_m] (inverse transform)."""
    u = rng.random(n)
    return -scale_m * np.log1p(-u * (1.0 - np.exp(-max_m / scale_m)))


def sample_near_field(model: NearFieldModel, n_beams: int, weights: np.ndarray, profile, rng: np.random.Generator,
                      label_cover: int, label_volume: int, rate_scale: np.ndarray | float = 1.0) -> Scatterers | None:  # fmt: skip
    """Scatterers for ``n_beams`` beams; ``rate_scale`` (scalar or (N,)) multiplies the rate per beam."""
    scale = np.asarray(rate_scale, dtype=np.float64)
    rate = np.maximum(model.rate_per_beam * scale, 0.0)
    # one rate for all: numpy draws the same counts twice as fast as from an array of it
    counts = rng.poisson(float(rate), n_beams) if scale.ndim == 0 else rng.poisson(np.broadcast_to(rate, (n_beams,)))
    beam = np.repeat(np.arange(n_beams), counts)
    n = len(beam)
    if n == 0:
        return None
    w = np.asarray(weights, dtype=np.float64)
    subray = rng.choice(len(w), size=n, p=w / w.sum())
    cover = rng.random(n) < model.cover_share
    lo, hi = model.volume_range_m
    rng_m = np.where(cover, truncated_exponential(rng, model.cover_scale_m, model.cover_max_m, n), rng.uniform(lo, hi, n))
    amp = model.amplitude_median * np.exp(model.amplitude_sigma_ln * rng.standard_normal(n))
    if model.cover_amp_scale_m > 0:
        amp = np.where(cover, amp * np.exp(-rng_m / model.cover_amp_scale_m), amp)
    det = profile.detection
    full = max(profile.optics.overlap_full_m, MIN_RANGE_M)
    r_ref = np.where(cover, np.maximum(rng_m, MIN_RANGE_M), full)  # cover: amplitude independent of range
    reflectance = reflectance_for_peak(amp * dark_level(det), det.power_constant, w[subray], r_ref)
    return Scatterers(
        beam=beam, subray=subray, range_m=rng_m, reflectance=reflectance,
        occlusion=np.clip(amp / model.occlusion_amplitude, 0.0, 1.0), label=np.where(cover, label_cover, label_volume).astype(np.uint8),
        object_id=np.zeros(n, np.uint32), bypass_overlap=cover,
    )  # fmt: skip
