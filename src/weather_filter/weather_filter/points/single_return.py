"""What a single-return driver (Velodyne, Ouster, Hesai, Livox in their default mode) would have published of a
multi-echo simulated cloud: :func:`single_return_cloud`.

The simulator's ``return_mode: all`` clouds carry every echo of a beam (``echo`` 1, 2, ...) and the EPW. A real
driver's default is ``strongest`` (Velodyne's factory setting, Ouster's single-return profile): one point per
beam, the echo of the highest peak amplitude, the nearer on a tie (``lidar_weather_sim.sensor.echo.select_returns``,
``core.names.RETURN_MODES``), and no EPW. The cloud's ``intensity`` is a monotone function of the peak amplitude
(``sim.kernels.intensity_byte`` of the log amplitude ratio), so the strongest echo is the one of highest intensity,
the nearer (the first in the beam's range order) on a tie. ``first`` and ``last`` are offered too.

A beam's echoes are consecutive in a simulated cloud and share ``channel`` and ``azimuth`` (``time_stamp`` where
there is no ``azimuth``): a run of equal (channel, azimuth) is one beam.
"""

from __future__ import annotations

import numpy as np

#: Fields a single-return driver does not publish (dropped by :func:`single_return_cloud`).
MULTI_ECHO_FIELDS = ("epw", "echo", "return_type")
SINGLE_RETURN_MODES = ("strongest", "first", "last")


def beam_starts(points: np.ndarray) -> np.ndarray:
    """Indices where a new beam starts (a change of ``channel`` or ``azimuth`` / ``time_stamp`` from the previous point)."""
    n = len(points)
    if n == 0:
        return np.zeros(0, np.int64)
    names = points.dtype.names or ()
    key = "azimuth" if "azimuth" in names else "time_stamp"
    new = np.ones(n, bool)
    new[1:] = (points["channel"][1:] != points["channel"][:-1]) | (points[key][1:] != points[key][:-1])
    return np.flatnonzero(new)


def single_return_index(points: np.ndarray, mode: str = "strongest") -> np.ndarray:
    """Indices (ascending) of the one point each beam reports under ``mode`` (strongest, first, last)."""
    if mode not in SINGLE_RETURN_MODES:
        raise ValueError(f"return mode {mode!r}: one of {', '.join(SINGLE_RETURN_MODES)}")
    if len(points) == 0:
        return np.zeros(0, np.int64)
    starts = beam_starts(points)
    ends = np.append(starts[1:], len(points))
    if mode == "first":
        return starts
    if mode == "last":
        return ends - 1
    intensity = points["intensity"].astype(np.float64)
    best = np.maximum.reduceat(intensity, starts)
    beam = np.repeat(np.arange(len(starts)), ends - starts)
    is_best = intensity == best[beam]
    # the first (nearest) index of each beam holding its maximum
    candidates = np.flatnonzero(is_best)
    first_of_beam = np.unique(beam[candidates], return_index=True)[1]
    return candidates[first_of_beam]


def single_return_cloud(points: np.ndarray, mode: str = "strongest", intensity_scale: float = 1.0) -> np.ndarray:
    """``points`` as a single-return driver publishes them: one point per beam (``mode``), without
    :data:`MULTI_ECHO_FIELDS`, ``intensity`` as float32 times ``intensity_scale`` (drivers scale it differently:
    Velodyne 0-255, Ouster photon counts). Clouds without ``echo`` are taken as single-return already."""
    names = points.dtype.names or ()
    kept = points[single_return_index(points, mode)] if "echo" in names else points
    fields = [n for n in names if n not in MULTI_ECHO_FIELDS]
    dtype = [(n, np.float32 if n == "intensity" else points.dtype[n]) for n in fields]
    out = np.empty(len(kept), dtype)
    for n in fields:
        out[n] = kept[n]
    if "intensity" in fields and intensity_scale != 1.0:
        out["intensity"] *= np.float32(intensity_scale)
    return out
