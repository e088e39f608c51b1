"""The gap search's frames: the recording's calibration and held-out frame indices, each within its budget."""

from __future__ import annotations

import numpy as np

from lidar_weather_sim.gap.split import DataSplit


def thin_evenly(indices: list[int], budget: int) -> list[int]:
    """At most ``budget`` of ``indices``, evenly spaced."""
    if len(indices) <= budget:
        return list(indices)
    return [indices[int(k)] for k in np.linspace(0, len(indices) - 1, budget).round()]


def split_frames(n: int, fit_frames: int, heldout_frames: int, split: DataSplit | None = None) -> tuple[list[int], list[int]]:
    """Calibration (even) and held-out (odd) frame indices, each thinned evenly to its budget; with a
    ``split`` (a twin's split.yaml), its parts' frames instead (the same frames for a sector split)."""
    for name, budget in (("fit_frames", fit_frames), ("heldout_frames", heldout_frames)):
        if budget < 1:
            raise ValueError(f"gap: {name} must be at least 1, got {budget}")
    if split is not None:
        beyond = [i for i in split.calibration_frames + split.heldout_frames if not 0 <= i < n]
        if beyond:
            raise ValueError(f"gap: the split names frames {beyond[:5]} but the recording has {n} frames")
        return thin_evenly(split.calibration_frames, fit_frames), thin_evenly(split.heldout_frames, heldout_frames)
    if n < 2:
        raise ValueError(f"gap needs at least 2 frames with poses (one to fit, one held out), the recording has {n}")
    return thin_evenly(list(range(0, n, 2)), fit_frames), thin_evenly(list(range(1, n, 2)), heldout_frames)
