"""Fog as a narrow shell: two-way Beer-Lambert loss plus soft echoes in a 0.3 m range band.

Models: a homogeneous fog of visual range ``V`` (m), ``alpha = 3.912 / V`` (1/m, Koschmieder), whose
backscatter a receiver sees only in a thin shell, where its overlap opens (as on a sensor with a sharp
overlap edge that moves in as the fog's loss steepens).

- **Loss**: every return at range ``R`` (m) has its power multiplied by ``exp(-2 alpha R)``; returns left below
  the detection threshold (intensity byte 0, :mod:`.echoes`) are removed.
- **Shell**: inner range ``r_s = 1.0 m + 3.0 m * exp(-alpha * 25 m)`` (3.35 m at V = 400 m, 1.26 m at V = 40 m),
  width 0.3 m. Each beam with a return in the clear recording gets one fog echo with probability
  ``f = min(0.9, alpha * 8 m)`` (0.08 at V = 400 m, 0.78 at V = 40 m), at a range uniform in
  ``[r_s, r_s + 0.3 m]``, with log ratio over the threshold ``L = ln(A / T)`` uniform in
  ``[0.05, 0.05 + alpha * 20 m]``; label FOG, EPW of an isolated pulse of the profile's width, along the beam's
  direction. An echo behind the beam's nearest attenuated return is not added; the returns each beam reports
  follow the return mode (:func:`.echoes.merge`).

Parameters: ``visual_range_m`` in [20, 1000] m; the seed of the ``numpy.random.Generator`` passed to ``apply``.

Leaves out: fog light outside the shell, multiple scattering, echoes on beams without a return in the clear
recording (sky), background light.
"""

from __future__ import annotations

import numpy as np

from lidar_weather_sim.core.points import Label
from lidar_weather_sim.references.generators.echoes import (Receiver, attenuate, beam_rows, echoes_at, merge,
                                                           nearest_on_beam)

KOSCHMIEDER = 3.912
VISUAL_RANGE_M = (20.0, 1000.0)
SHELL_NEAR_M, SHELL_SPAN_M, SHELL_LENGTH_M = 1.0, 3.0, 25.0  # r_s = near + span * exp(-alpha * length)
SHELL_WIDTH_M = 0.3
SHARE_LENGTH_M, SHARE_MAX = 8.0, 0.9  # f = min(SHARE_MAX, alpha * SHARE_LENGTH_M)
LOG_RATIO_MIN, LOG_RATIO_LENGTH_M = 0.05, 20.0  # L uniform in [min, min + alpha * length]


class FogShell:
    """Fog of visual range ``visual_range_m`` (m) with soft echoes in a narrow shell (module doc)."""

    def __init__(self, rx: Receiver, visual_range_m: float) -> None:
        lo, hi = VISUAL_RANGE_M
        if not lo <= visual_range_m <= hi:
            raise ValueError(f"visual_range_m: fog visual range must be in [{lo:g}, {hi:g}] m, got {visual_range_m:g}")
        self.rx = rx
        self.alpha = KOSCHMIEDER / visual_range_m
        self.shell_m = SHELL_NEAR_M + SHELL_SPAN_M * np.exp(-self.alpha * SHELL_LENGTH_M)
        self.share = min(SHARE_MAX, self.alpha * SHARE_LENGTH_M)

    def apply(self, points: np.ndarray, rng: np.random.Generator) -> np.ndarray:
        """``points`` (the project's layout) in the fog: attenuated, shell echoes added."""
        hard = attenuate(points, 2.0 * self.alpha * points["distance"].astype(np.float64), self.rx)
        rows = beam_rows(points)
        rows = rows[rng.random(len(rows)) < self.share]
        ranges = self.shell_m + SHELL_WIDTH_M * rng.random(len(rows))
        ratio = LOG_RATIO_MIN + self.alpha * LOG_RATIO_LENGTH_M * rng.random(len(rows))
        soft = echoes_at(points, rows, ranges, ratio, Label.FOG, self.rx)
        return merge(hard, soft[soft["distance"] < nearest_on_beam(hard, soft)], self.rx)
