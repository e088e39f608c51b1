"""The near-field ghost rate (``sensor.near_field_ghost``) read off the calibration scans' cover-zone counts.

A unit's ghosts (returns of its clean window and housing, thesis lines 329 and 498) show only as returns in
the cover zone (range < 0.5 m), and only the few beyond the profile's minimum range: a VLP-16 reports about
5 % of them, two scans of a rate of 0.02 per beam some 40 points. The count is then all the scans hold about
the rate, and fitting the rate on the gap (a sum over many histograms) reads it less well than the count
itself (the ghost draws of ``config/ghost_effect_cases.yaml``, ``git show f643197:benchmarks/ghost_count_limit.py``).

:func:`ghost_rate` finds the rate at which the model's expected count, over the same scans, equals the
recorded count: secant steps from no ghosts (the count grows about linearly with the rate, less at high
rates where ghosts of one beam merge), each at most a factor 10, until the model's count is within 2 % (or its own
standard error), at most four. It is the ghost's starting value in the search, tried before any fitted effect,
and proposed only when the recorded count is above the model's without ghosts by ``MIN_SIGMA`` Poisson
standard deviations.
"""

from __future__ import annotations

from typing import Callable

import numpy as np

from lidar_weather_sim.gap.signatures import COVER_M

MIN_SIGMA = 3.0
REFERENCE_RATE = 0.1  # ghosts per beam and frame of the first model count
MAX_STEPS, TOLERANCE = 4, 0.02  # secant steps, at most; done when the model's count is this close (share)
MAX_FACTOR = 10.0  # a step changes the rate by at most this factor


def cover_returns(frames: list[np.ndarray]) -> int:
    """Returns closer than the cover zone's 0.5 m in ``frames`` (sensor frame)."""
    return int(sum(int((f["distance"] < COVER_M).sum()) for f in frames))


def ghost_rate(recorded: int, without: float, expected: Callable[[float], float], bounds: tuple[float, float],
               draws: int = 1) -> float | None:  # fmt: skip
    """The ghost rate (per beam and frame, within ``bounds``) whose ``expected(rate)`` cover-zone count (a mean
    over ``draws`` model draws) equals the ``recorded`` one, ``without`` being the model's count without ghosts;
    None when the recorded count is not above it by :data:`MIN_SIGMA` standard deviations. A model count within
    :data:`TOLERANCE` or its own Poisson standard error of the recorded one ends the steps."""
    excess = recorded - without
    if excess <= MIN_SIGMA * np.sqrt(max(recorded + without, 1.0)):
        return None
    last, rate = (0.0, 0.0), REFERENCE_RATE  # (rate, count gained): no ghosts gain nothing
    for _ in range(MAX_STEPS):
        gained = expected(rate) - without
        if abs(gained - excess) <= max(TOLERANCE * excess, np.sqrt(max(gained + without, 1.0) / draws)):
            break
        slope = (gained - last[1]) / (rate - last[0])
        if slope <= 0:  # the count must grow with the rate
            return None
        step = float(np.clip(rate + (excess - gained) / slope, rate / MAX_FACTOR, rate * MAX_FACTOR))
        if float(np.clip(step, *bounds)) == rate:  # held at a bound
            break
        last, rate = (rate, gained), float(np.clip(step, *bounds))
    return round(rate, 5)
