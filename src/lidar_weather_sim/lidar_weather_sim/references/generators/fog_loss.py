"""Fog as loss only: two-way Beer-Lambert extinction of every hard return, no soft echoes.

Models: a homogeneous fog of visual range ``V`` (m) between the sensor and every surface. The extinction
coefficient at the sensor's wavelength is Koschmieder's ``alpha = 3.912 / V`` (1/m; taken wavelength-independent
at 850-905 nm for fog droplets of a few um, whose extinction efficiency is ~2). Each return at range ``R`` (m,
its ``distance``) has its received power multiplied by ``exp(-2 alpha R)``; a return whose attenuated power falls
below the detection threshold is removed. The threshold is the profile's dark threshold, which its intensity
scale puts at byte 0 (:mod:`.echoes`): a return of log ratio ``L = ln(A / T)`` survives iff
``L - 2 alpha R >= 0``, and its byte drops by ``255 * 2 alpha R / ln(DR)``.

Parameters: ``visual_range_m`` in [20, 1000] m.

Leaves out: the fog's own (soft) echoes, multiple scattering, forward-scattered light, beams that had no return
in the clear recording, background light. Deterministic (the seed is not used).
"""

from __future__ import annotations

import numpy as np

from lidar_weather_sim.references.generators.echoes import Receiver, attenuate

KOSCHMIEDER = 3.912
VISUAL_RANGE_M = (20.0, 1000.0)


def extinction(visual_range_m: float) -> float:
    """Koschmieder's ``alpha`` (1/m) of a visual range (m), checked against :data:`VISUAL_RANGE_M`."""
    lo, hi = VISUAL_RANGE_M
    if not lo <= visual_range_m <= hi:
        raise ValueError(f"visual_range_m: fog visual range must be in [{lo:g}, {hi:g}] m, got {visual_range_m:g}")
    return KOSCHMIEDER / visual_range_m


class FogLoss:
    """Fog of visual range ``visual_range_m`` (m) as loss only (module doc)."""

    def __init__(self, rx: Receiver, visual_range_m: float) -> None:
        self.rx = rx
        self.alpha = extinction(visual_range_m)

    def apply(self, points: np.ndarray, rng: np.random.Generator) -> np.ndarray:
        """``points`` (the project's layout) seen through the fog."""
        return attenuate(points, 2.0 * self.alpha * points["distance"].astype(np.float64), self.rx)
