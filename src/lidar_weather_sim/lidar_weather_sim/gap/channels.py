"""Per-channel departures read off a recording: the gap search's ``sensor.dead_channels``,
``sensor.weak_channels`` and ``sensor.elevation_offsets`` candidates, and the beams' origin
(``sensor.beam_origin`` and ``sensor.beam_origin_radial``) those are read with.

Each is proposed as one set, read off the calibration frames, and kept only if it earns the same held-out
margin as any other effect. Channels are scan-pattern rows, 0 = lowest elevation.

- **Dead**: the re-simulation of the same frames returns at least ``MIN_SIMULATED_PER_FRAME`` points per
  frame on the channel and the recording at most ``MAX_MEASURED_SHARE`` of that: a channel the model sees
  but the unit does not report.
- **Weak** (a receiver with less gain ``g``, region ``faults``, ``channel_gains``): every return of the
  channel is ``g`` times weaker. Points carry their peak ``A`` over the threshold ``T`` in their intensity
  (0-255, logarithmic up to the profile's ``intensity_dynamic_range``): a return survives when ``g A >= T``
  and is reported ``ln g`` lower. Against the re-simulated points of the same channel, ``g`` is read beam by
  beam where the channel has ``MIN_PAIRS`` beams that both return on off the same surface: their mean
  intensity change, less the median channel's, on the model's byte scale: each recorded byte is first taken
  back through the response every channel shares (the median recorded byte of all pairs at each simulated
  byte, :func:`_shared_response`). An intensity gamma or scale moves dark and bright returns by different
  amounts and channels see surfaces of different brightness, so without that a shared response would read as
  a trend of weak channels, and a weak channel's gain would be read through the gamma. Otherwise it is
  found from the share of returns the channel loses when that is more than what every channel loses (the
  median channel: ray drop is not a weak channel), as the quantile of ``A / T`` that leaves the recording's
  share above it; else (strong returns, e.g. the road near the car, all survive) from the median intensity,
  less the median channel's shift. Named when ``g`` is ``MIN_GAIN``-``MAX_WEAK_GAIN``.
- **Elevation offsets** (``sensor.elevation_offsets_deg``): the median departure of the elevation,
  atan2(z, hypot(x, y)) in the sensor frame, of the channel's recorded points at ``MIN_ELEVATION_RANGE_M``
  or more from the profile's elevation for that channel, where it is at least ``MIN_OFFSET_DEG`` and the
  channel has ``MIN_ELEVATION_POINTS`` points. A points' frame whose origin is not the beams' (the
  ``sensor.beam_origin`` effects: dz above it, b off the spin axis; a real Ouster's points lie a few cm
  below and inside its beams' origin) moves every point by (dz cos(e) - b sin(e)) / r in elevation, which
  falls with range: that term, common to all channels, is fitted first and removed, so it is not taken for
  offsets; the fit (:func:`beam_origin`) is proposed as the two beam-origin effects' starting values (on the
  real OS1-128 recording it reads 36.2 mm up and 15.8 mm out: Ouster's os_sensor frame below os_lidar, and
  its lidar_origin_to_beam_origin_mm). Offsets that would move a channel past a neighbour are left
  out (the channel's identity is then in doubt).
"""

from __future__ import annotations

import numpy as np

from lidar_weather_sim.gap.signatures import SAME_SURFACE_M
from lidar_weather_sim.replay import paired_beams

MIN_SIMULATED_PER_FRAME = 10.0
MAX_MEASURED_SHARE = 0.05
MAX_WEAK_GAIN = 0.8  # a channel at least this strong is not named weak
MIN_GAIN = 0.02  # a weaker channel than this is as good as dead
MIN_PAIRS = 50  # beams a channel must return on in both recordings for its paired intensity shift
MIN_LEVEL_PAIRS = 20  # pairs at a simulated byte for its shared response (else interpolated from the neighbours)
PAIRED_WINDOW_BYTES = 6.0
MIN_ELEVATION_POINTS = 20
MIN_ELEVATION_RANGE_M = 3.0
MIN_OFFSET_DEG = 0.03
MIN_ORIGIN_M = 0.002  # a beams' origin nearer than this to the points' frame is not proposed


def channel_counts(frames: list[np.ndarray], channels: int) -> np.ndarray:
    """Points per channel (``channels``,) summed over ``frames`` (structured points with ``channel``)."""
    counts = np.zeros(channels, np.int64)
    for points in frames:
        counts += np.bincount(np.clip(points["channel"].astype(np.int64), 0, channels - 1), minlength=channels)
    return counts


def _seen(measured: list[np.ndarray], simulated: list[np.ndarray], channels: int):
    """(measured counts, simulated counts, channels the model sees well enough to judge), or None."""
    if not measured or len(measured) != len(simulated):
        return None
    got, expected = channel_counts(measured, channels), channel_counts(simulated, channels)
    return got, expected, expected >= MIN_SIMULATED_PER_FRAME * len(simulated)


def dead_channels(measured: list[np.ndarray], simulated: list[np.ndarray], channels: int) -> list[int]:
    """Channels the simulated frames return on (>= MIN_SIMULATED_PER_FRAME points per frame) and the
    measured frames, the same ones, (almost) never do (<= MAX_MEASURED_SHARE of the simulated count)."""
    seen = _seen(measured, simulated, channels)
    if seen is None:
        return []
    got, expected, judged = seen
    return [int(c) for c in np.flatnonzero(judged & (got <= MAX_MEASURED_SHARE * expected))]


def weak_channels(measured: list[np.ndarray], simulated: list[np.ndarray], channels: int, dynamic_range: float,
                  columns: int | None = None) -> dict[int, float]:  # fmt: skip
    """Channel -> receiver gain (0-1) of the channels whose returns are weaker than the others' (module doc).
    ``measured`` and ``simulated`` (the same frames re-simulated without effects): points with ``channel`` and
    ``intensity`` (with ``columns``, the scan's azimuth columns, also ``azimuth`` and ``distance``: the shift is
    then read beam by beam); ``dynamic_range``: the profile's ``detection.intensity_dynamic_range``."""
    seen = _seen(measured, simulated, channels)
    if seen is None:
        return {}
    got, expected, judged = seen
    judged &= got > MAX_MEASURED_SHARE * expected  # dead ones are dead_channels'
    if not judged.any():
        return {}
    per_byte = np.log(dynamic_range) / 255.0
    paired = _paired_shifts(measured, simulated, channels, columns) if columns else np.full(channels, np.nan)
    log_measured, log_simulated = ([per_byte * np.concatenate([p["intensity"][p["channel"] == c] for p in frames])
                                    .astype(np.float64) for c in range(channels)] for frames in (measured, simulated))  # fmt: skip
    lost = 1.0 - got / np.maximum(expected, 1)
    shift = np.array([np.median(log_measured[c]) - np.median(log_simulated[c]) if judged[c] and len(log_measured[c])
                      else np.nan for c in range(channels)])  # fmt: skip
    common_shift, common_lost = np.nanmedian(shift), np.median(lost[judged])  # what every channel shares
    common_paired = np.nanmedian(paired[judged]) if np.isfinite(paired[judged]).any() else np.nan
    gains = {}
    for c in np.flatnonzero(judged):
        if np.isfinite(paired[c]):
            gain = float(min(1.0, np.exp(per_byte * (paired[c] - common_paired))))
        else:
            gain = _gain(log_measured[c] - common_shift, log_simulated[c], lost[c] - common_lost)
        if MIN_GAIN <= gain <= MAX_WEAK_GAIN:
            gains[int(c)] = round(gain, 4)
    return gains


def _paired_shifts(measured: list[np.ndarray], simulated: list[np.ndarray], channels: int, columns: int) -> np.ndarray:
    """Per channel, the mean intensity change (bytes) from the simulated to the measured return of the same beam,
    over the beams both return on off the same surface and neither at an end of the byte range (a surviving
    return of a weak channel is ``ln g`` lower, whatever its strength), the recorded byte taken back through the
    response all channels share (:func:`_shared_response`): the mean within ``PAIRED_WINDOW_BYTES`` of the median,
    which averages the bytes' rounding out; NaN with fewer than ``MIN_PAIRS`` pairs."""
    recorded, chans, levels = [], [], []
    for m, s in zip(measured, simulated):
        im, is_ = paired_beams(m, s, columns)
        a, b = m["intensity"][im].astype(np.float64), s["intensity"][is_].astype(np.float64)
        ok = ((np.abs(m["distance"][im].astype(np.float64) - s["distance"][is_]) <= SAME_SURFACE_M)
              & (a > 0) & (a < 255) & (b > 0) & (b < 255))  # fmt: skip
        recorded.append(a[ok])
        chans.append(m["channel"][im][ok].astype(np.int64))
        levels.append(b[ok])
    a, chan, b = np.concatenate(recorded), np.concatenate(chans), np.concatenate(levels)
    response = _shared_response(a, b.astype(np.int64))
    diff = np.interp(a, response, np.arange(256.0)) - b  # the recorded byte on the model's scale, less the model's
    out = np.full(channels, np.nan)
    for c in range(channels):
        d = diff[chan == c]
        if len(d) >= MIN_PAIRS:
            near = d[np.abs(d - np.median(d)) <= PAIRED_WINDOW_BYTES]
            out[c] = near.mean()
    return out


def _shared_response(recorded: np.ndarray, level: np.ndarray) -> np.ndarray:
    """(256,) increasing: at each simulated byte, the median ``recorded`` byte of all pairs at that byte
    ``level``, where it has ``MIN_LEVEL_PAIRS`` pairs; between such bytes the change is interpolated linearly,
    beyond them it stays that of the nearest (the identity when no byte has enough pairs)."""
    order = np.argsort(level, kind="stable")
    values, starts, counts = np.unique(level[order], return_index=True, return_counts=True)
    known = counts >= MIN_LEVEL_PAIRS
    levels = np.arange(256.0)
    if not known.any():
        return levels
    medians = np.array([np.median(recorded[order[i : i + n]]) for i, n in zip(starts[known], counts[known])])
    response = levels + np.interp(levels, values[known], medians - values[known])
    return np.maximum.accumulate(response) + 1e-6 * levels  # increasing, as np.interp needs to invert it


def _gain(log_measured: np.ndarray, log_simulated: np.ndarray, lost: float) -> float:
    """The gain g (0-1) under which the simulated log peak ratios ``log_simulated`` (ln A/T of each point)
    match the measured ones: those with ln A/T + ln g >= 0 survive, shifted by ln g. Matched on the share
    lost when the channel loses returns beyond what every channel does (``lost`` > MAX_MEASURED_SHARE),
    else on the median."""
    if lost > MAX_MEASURED_SHARE:
        return float(min(1.0, 1.0 / np.exp(np.quantile(log_simulated, lost))))
    grid = np.linspace(np.log(MIN_GAIN) - 0.1, 0.0, 400)
    target = np.median(log_measured)
    medians = np.array([np.median(kept) if len(kept := log_simulated[log_simulated + g >= 0] + g) else -np.inf
                        for g in grid])  # fmt: skip
    return float(np.exp(grid[int(np.argmin(np.abs(medians - target)))]))


def _elevation_fit(measured: list[np.ndarray], nominal_deg: np.ndarray):
    """The measured points' elevation departures from the table and the beams' origin fitted to them (module
    doc): (channel of each point, departure (rad), the two levers (2, n), points used, points per channel,
    (dz, b) in m); None without enough points."""
    channels = len(nominal_deg)
    if not measured:
        return None
    points = np.concatenate([p[["x", "y", "z", "channel"]] for p in measured])
    x, y, z = (points[k].astype(np.float64) for k in ("x", "y", "z"))
    horizontal = np.hypot(x, y)
    distance = np.hypot(horizontal, z)
    channel = np.clip(points["channel"].astype(np.int64), 0, channels - 1)
    nominal = np.radians(np.asarray(nominal_deg, dtype=np.float64))
    departure = np.arctan2(z, horizontal) - nominal[channel]
    # a beams' origin dz above the points' frame and b off its axis moves a point at range r by
    # (dz cos(e) - b sin(e)) / r in elevation: common to every channel, fitted once within each channel (so the
    # channels' own offsets do not enter)
    levers = np.stack([np.cos(nominal[channel]), -np.sin(nominal[channel])]) / np.maximum(distance, 1e-3)
    ok = distance >= MIN_ELEVATION_RANGE_M
    counts = np.bincount(channel[ok], minlength=channels)
    used = ok & (counts[channel] >= MIN_ELEVATION_POINTS)
    if not used.any():
        return None

    def centred(v: np.ndarray) -> np.ndarray:
        return v[used] - (np.bincount(channel[used], v[used], channels) / np.maximum(counts, 1))[channel[used]]

    a = np.stack([centred(lever) for lever in levers], axis=1)
    origin = np.linalg.lstsq(a, centred(departure), rcond=None)[0] if np.linalg.matrix_rank(a) == 2 else np.zeros(2)
    return channel, departure, levers, used, counts, origin


def beam_origin(measured: list[np.ndarray], nominal_deg: np.ndarray) -> tuple[float, float]:
    """(dz, b) in m: the beams' origin above and off the axis of the measured points' frame, from how their
    elevation departs from the table ``nominal_deg`` with range (module doc); (0, 0) without enough points."""
    fit = _elevation_fit(measured, nominal_deg)
    return (0.0, 0.0) if fit is None else (round(float(fit[5][0]), 5), round(float(fit[5][1]), 5))


def elevation_offsets(measured: list[np.ndarray], nominal_deg: np.ndarray) -> dict[int, float]:
    """Channel -> elevation offset (deg) of the measured points (sensor frame, with ``channel``) from the
    profile's per-channel elevations ``nominal_deg`` (channel 0 first), the beams' origin term removed
    (module doc)."""
    fit = _elevation_fit(measured, nominal_deg)
    if fit is None:
        return {}
    channel, departure, levers, used, counts, origin = fit
    channels = len(nominal_deg)
    residual = np.degrees(departure - origin @ levers)
    offsets = np.zeros(channels)
    for c in np.flatnonzero(counts >= MIN_ELEVATION_POINTS):
        offsets[c] = np.median(residual[used & (channel == c)])
    offsets[np.abs(offsets) < MIN_OFFSET_DEG] = 0.0
    moved = np.asarray(nominal_deg, dtype=np.float64) + offsets
    crossed = np.zeros(channels, bool)
    crossed[:-1] |= np.diff(moved) < 0
    crossed[1:] |= np.diff(moved) < 0
    offsets[crossed] = 0.0
    return {int(c): round(float(offsets[c]), 4) for c in np.flatnonzero(offsets)}
