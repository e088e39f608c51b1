"""Obstacle points merged into a recorded frame with occlusion per beam (paper 4, thesis ~line 2761).

A beam is a channel and a column of the recording's scan pattern (the radial histogram per layer of
the paper, with bins one column wide). In every beam that holds an obstacle point (the nearest one of
the beam; a box hides its own far side):

- recorded returns in front of it stay, with their echo numbers;
- the obstacle point becomes the next echo (the highest echo number in front + 1), or is lost when
  that is beyond the profile's ``max_echoes`` (the beam's echoes are used up);
- recorded returns behind it are removed, except those within ``NEAR_FIELD_M`` of the sensor (the
  paper leaves 0-5 m alone: its rain was already in the rendering), so beyond 5 m the first
  detection of the beam is kept;
- Nebula return types of the beam's points are set again (first / second / last / identical).

Then, after occlusion as in the paper, the obstacle points get Gaussian range noise along their beam
(m). Units: m, rad; frame: the sensor frame (REP-103).
"""

from __future__ import annotations

import numpy as np

from lidar_weather_sim.core.points import ReturnType, add_range_noise
from lidar_weather_sim.sensor.scan import ScanPattern

#: Recorded returns this close (m) are never removed by an obstacle (paper 4: "the region from 0 to 5 m").
NEAR_FIELD_M = 5.0


def beam_key(pattern: ScanPattern, channel: np.ndarray, azimuth: np.ndarray) -> np.ndarray:
    """Beam index (channel x columns + column) of points (channel, azimuth rad in the sensor frame);
    -1 outside the scan's azimuth range or for a channel the profile does not have."""
    channel = np.asarray(channel, np.int64)
    known = channel < pattern.n_channels
    ch = np.where(known, channel, 0)
    lo = np.deg2rad(pattern.profile.scan.azimuth_min_deg)
    step = np.deg2rad(pattern.profile.scan.azimuth_max_deg - pattern.profile.scan.azimuth_min_deg) / pattern.n_columns
    a = np.mod(np.asarray(azimuth, np.float64) - pattern.azimuth_offset[ch] - lo, 2.0 * np.pi)
    idx = np.floor(a / step).astype(np.int64)
    inside = known & (idx < pattern.n_columns)
    col = idx if pattern.profile.scan.direction != "cw" else pattern.n_columns - 1 - idx
    return np.where(inside, ch * pattern.n_columns + col, -1)


def _return_types(key: np.ndarray, distance: np.ndarray, echo: np.ndarray) -> np.ndarray:
    """Nebula return type of each point from its beam's points (any order)."""
    order = np.lexsort((distance, key))
    k = key[order]
    last = np.ones(len(k), bool)
    last[:-1] = k[1:] != k[:-1]
    first = echo[order] == 1
    types = np.where(first, np.where(last, ReturnType.IDENTICAL, ReturnType.FIRST),
                     np.where(last, ReturnType.LAST, ReturnType.SECOND)).astype(np.uint8)  # fmt: skip
    out = np.empty(len(k), np.uint8)
    out[order] = types
    return out


def merge_obstacles(recorded: np.ndarray, obstacle: np.ndarray, pattern: ScanPattern, max_echoes: int,
                    noise_sigma_m: float, rng: np.random.Generator) -> np.ndarray:  # fmt: skip
    """``recorded`` (any layout with channel, azimuth, distance, echo) with the ``obstacle`` points
    (project layout) merged in as the module doc says, in ``recorded``'s layout (fields it lacks are
    dropped); obstacle points last. ``noise_sigma_m``: sigma (m) of the range noise on obstacle points."""
    rec_key = beam_key(pattern, recorded["channel"], recorded["azimuth"])
    obs_key = beam_key(pattern, obstacle["channel"], obstacle["azimuth"])
    # the nearest obstacle point of each beam
    order = np.lexsort((obstacle["distance"], obs_key))
    first = np.ones(len(order), bool)
    first[1:] = obs_key[order][1:] != obs_key[order][:-1]
    obs = obstacle[order[first]]
    okey = obs_key[order[first]]
    obs = obs[okey >= 0]
    okey = okey[okey >= 0]
    if not len(okey):
        return recorded.copy()
    # each recorded point's obstacle range (inf: its beam has none)
    pos = np.clip(np.searchsorted(okey, rec_key), 0, len(okey) - 1)
    has = okey[pos] == rec_key
    obs_range = np.where(has, obs["distance"][pos].astype(np.float64), np.inf)
    rec_d = recorded["distance"].astype(np.float64)
    front = rec_d < obs_range
    keep = front | (rec_d < NEAR_FIELD_M)
    # obstacle echo number: 1 + the highest echo in front of it
    front_echo = np.zeros(len(okey), np.int64)
    np.maximum.at(front_echo, pos[has & front], recorded["echo"][has & front].astype(np.int64))
    echo = front_echo + 1
    alive = echo <= max_echoes
    obs, okey, echo = obs[alive], okey[alive], echo[alive]
    kept = recorded[keep]
    out = np.zeros(len(kept) + len(obs), dtype=recorded.dtype)
    out[: len(kept)] = kept
    added = out[len(kept) :]
    for name in recorded.dtype.names:
        if name in obs.dtype.names:
            added[name] = obs[name]
    added["echo"] = echo
    # return types of every point in the obstacle beams
    all_key = np.concatenate([rec_key[keep], okey])
    touched = np.isin(all_key, okey)
    if "return_type" in out.dtype.names and touched.any():
        out["return_type"][touched] = _return_types(all_key[touched], out["distance"][touched].astype(np.float64),
                                                    out["echo"][touched])  # fmt: skip
    add_range_noise(added, noise_sigma_m, rng)
    return out

