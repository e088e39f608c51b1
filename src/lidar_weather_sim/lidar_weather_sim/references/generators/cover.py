"""A dirty sensor cover as a transmission on every return.

Models: a window of one-way transmission ``tau`` (0-1) that every pulse crosses on the way out and its echo on
the way back: each return's received power (hard returns and the weather's echoes alike, applied after the
weather generator) is multiplied by ``tau^2``; returns left below the detection threshold (intensity byte 0,
:mod:`.echoes`) are removed. Uniform over the window and over range.

Parameters: ``transmission`` (one-way) in [0.2, 1.0].

Leaves out: light the dirt scatters back (cover returns at 0-0.5 m), blur and widening of the beam, dirt that
varies over the window. Deterministic.
"""

from __future__ import annotations

import numpy as np

from lidar_weather_sim.references.generators.echoes import Receiver, attenuate

TRANSMISSION = (0.2, 1.0)


class DirtyCover:
    """A cover of one-way ``transmission`` (module doc)."""

    def __init__(self, rx: Receiver, transmission: float) -> None:
        lo, hi = TRANSMISSION
        if not lo <= transmission <= hi:
            raise ValueError(f"transmission: cover transmission must be in [{lo:g}, {hi:g}], got {transmission:g}")
        self.rx = rx
        self.loss = -2.0 * float(np.log(transmission))

    def apply(self, points: np.ndarray, rng: np.random.Generator) -> np.ndarray:
        """``points`` (the project's layout) seen through the cover."""
        return attenuate(points, self.loss, self.rx)
