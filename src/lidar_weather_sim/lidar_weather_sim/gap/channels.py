"""Dead channels read off a recording: the ``sensor.dead_channels`` candidate of the gap search.

A channel (scan-pattern row) is dead in the recording when the re-simulation of the same frames
returns at least ``MIN_SIMULATED_PER_FRAME`` points on it per frame and the recording at most
``MAX_MEASURED_SHARE`` of what the simulation has there: a channel the model sees but the unit does
not report. The search then tries that one set (region ``faults``); it is kept only if it earns the
same held-out margin as any other effect. Weak channels (a lower gain, not silence) are not named
here: a channel with half its returns is left to the intensity and ray-drop effects.
"""

from __future__ import annotations

import numpy as np

MIN_SIMULATED_PER_FRAME = 10.0
MAX_MEASURED_SHARE = 0.05


def channel_counts(frames: list[np.ndarray], channels: int) -> np.ndarray:
    """Points per channel (``channels``,) summed over ``frames`` (structured points with ``channel``)."""
    counts = np.zeros(channels, np.int64)
    for points in frames:
        counts += np.bincount(np.clip(points["channel"].astype(np.int64), 0, channels - 1), minlength=channels)
    return counts


def dead_channels(measured: list[np.ndarray], simulated: list[np.ndarray], channels: int) -> list[int]:
    """Channels the simulated frames return on (>= MIN_SIMULATED_PER_FRAME points per frame) and the
    measured frames, the same ones, (almost) never do (<= MAX_MEASURED_SHARE of the simulated count)."""
    if not measured or len(measured) != len(simulated):
        return []
    got, expected = channel_counts(measured, channels), channel_counts(simulated, channels)
    dead = (expected >= MIN_SIMULATED_PER_FRAME * len(simulated)) & (got <= MAX_MEASURED_SHARE * expected)
    return [int(c) for c in np.flatnonzero(dead)]
