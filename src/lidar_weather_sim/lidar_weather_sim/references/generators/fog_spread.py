"""Fog with soft echoes spread over 0.6-5 m: two-way Beer-Lambert loss plus one fog echo on a share of beams.

Models: a homogeneous fog of visual range ``V`` (m), ``alpha = 3.912 / V`` (1/m, Koschmieder).

- **Loss**: every return at range ``R`` (m) has its power multiplied by ``exp(-2 alpha R)``; returns left below
  the detection threshold (intensity byte 0, :mod:`.echoes`) are removed.
- **Soft echoes**: each beam with a return in the clear recording gets a fog echo with probability
  ``f = 1 - exp(-alpha * 15 m)`` (0.14 at V = 400 m, 0.77 at V = 40 m): denser fog beats the threshold on more
  beams. Its range is drawn from the fog volume's received power ``p(r) ∝ w(r) exp(-2 alpha r) / r^2`` on
  0.6-5 m, ``w`` the receiver overlap ramp rising linearly from 0 at 0.6 m to 1 at 1.5 m (the same ramp for every
  sensor). Its log ratio over the threshold ``L = ln(A / T)`` is exponential with mean ``0.3 + alpha * 10 m``
  (0.40 at V = 400 m, 1.28 at V = 40 m). The echo lies along the beam's direction (a copy of one of its points),
  label FOG, EPW of an isolated pulse of the profile's width; an echo behind the beam's nearest attenuated
  return is not added. The returns each beam reports follow the return mode (:func:`.echoes.merge`).

Parameters: ``visual_range_m`` in [20, 1000] m; the seed of the ``numpy.random.Generator`` passed to ``apply``.

Leaves out: multiple scattering, the pulse's shape over the volume (one echo per beam at one range), echoes
on beams without a return in the clear recording (sky), background light.
"""

from __future__ import annotations

import numpy as np

from lidar_weather_sim.core.points import Label
from lidar_weather_sim.references.generators.echoes import (Receiver, attenuate, beam_rows, echoes_at, merge,
                                                           nearest_on_beam)

KOSCHMIEDER = 3.912
VISUAL_RANGE_M = (20.0, 1000.0)
NEAR_M, FAR_M = 0.6, 5.0  # the soft echoes' range band (m)
RAMP_FULL_M = 1.5  # overlap ramp: 0 at NEAR_M, 1 here (m)
SHARE_LENGTH_M = 15.0  # f = 1 - exp(-alpha * SHARE_LENGTH_M)
LOG_RATIO_BASE, LOG_RATIO_LENGTH_M = 0.3, 10.0  # mean L = base + alpha * length
GRID_M = 1e-3  # step of the inverse-CDF table of the range law (m)


class FogSpread:
    """Fog of visual range ``visual_range_m`` (m) with soft echoes spread over 0.6-5 m (module doc)."""

    def __init__(self, rx: Receiver, visual_range_m: float) -> None:
        lo, hi = VISUAL_RANGE_M
        if not lo <= visual_range_m <= hi:
            raise ValueError(f"visual_range_m: fog visual range must be in [{lo:g}, {hi:g}] m, got {visual_range_m:g}")
        self.rx = rx
        self.alpha = KOSCHMIEDER / visual_range_m
        self.share = 1.0 - np.exp(-self.alpha * SHARE_LENGTH_M)
        self.mean_log_ratio = LOG_RATIO_BASE + self.alpha * LOG_RATIO_LENGTH_M
        self._r = np.arange(NEAR_M, FAR_M + GRID_M / 2, GRID_M)
        cdf = np.concatenate([[0.0], np.cumsum(0.5 * (self.density(self._r[1:]) + self.density(self._r[:-1])))])
        self._cdf = cdf / cdf[-1]

    def density(self, r: np.ndarray) -> np.ndarray:
        """The unnormalised range law ``w(r) exp(-2 alpha r) / r^2`` of the soft echoes (0 outside 0.6-5 m)."""
        r = np.asarray(r, np.float64)
        w = np.clip((r - NEAR_M) / (RAMP_FULL_M - NEAR_M), 0.0, 1.0)
        return np.where((r >= NEAR_M) & (r <= FAR_M), w * np.exp(-2.0 * self.alpha * r) / r**2, 0.0)

    def cdf(self, r: np.ndarray) -> np.ndarray:
        """The normalised cumulative range law at ``r`` (m)."""
        return np.interp(r, self._r, self._cdf)

    def apply(self, points: np.ndarray, rng: np.random.Generator) -> np.ndarray:
        """``points`` (the project's layout) in the fog: attenuated, soft echoes added."""
        hard = attenuate(points, 2.0 * self.alpha * points["distance"].astype(np.float64), self.rx)
        rows = beam_rows(points)
        rows = rows[rng.random(len(rows)) < self.share]
        ranges = np.interp(rng.random(len(rows)), self._cdf, self._r)
        ratio = rng.exponential(self.mean_log_ratio, len(rows))
        soft = echoes_at(points, rows, ranges, ratio, Label.FOG, self.rx)
        return merge(hard, soft[soft["distance"] < nearest_on_beam(hard, soft)], self.rx)
