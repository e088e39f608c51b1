"""The sensor profile of a recording: given, matched among the shipped ones, or derived from the cloud.

Matching (:func:`lidar_weather_sim.augment.obstacles.profile_for_cloud`): a shipped profile
(``config/sensors``) fits when the cloud's channels exist in it and the points' elevations lie within
0.5 deg (median) of their channels'; of several, the one whose column count is nearest the cloud's.
When none fits, :func:`derive_profile` writes one from the cloud: channels (highest channel + 1),
elevation per channel (median of its points, deg; channels without points interpolated), columns per
revolution (360 deg over the median azimuth step between a channel's neighbouring returns), the
horizontal field of view (full circle when the returns cover more than 300 deg) and the frame rate
(from the frame stamps; 10 Hz for a single frame); optics, pulse, detection and range (but its minimum) are
those of the shipped profile with the nearest channel count (named in ``source``). The cover zone (range below
:data:`COVER_M`, where the window's and the housing's returns lie) is what the recording shows, not the other
sensor's: the minimum range is the nearest return of the calibration frames (to the cm below) when they hold
returns in the cover zone, else :data:`COVER_M` (the recording reports none there, so neither does the
profile). :func:`cover_zone` counts what the recording shows there (for the report, whatever the profile).
"""

from __future__ import annotations

import math

import numpy as np

from lidar_weather_sim.augment.obstacles import check_profile, profile_for_cloud
from lidar_weather_sim.augment.boxes import ObstacleError
from lidar_weather_sim.sensor.profile import SensorProfile, load_profile, profiles_dir

DEFAULT_FRAME_RATE_HZ = 10.0
COVER_M = 0.5  # the cover zone: returns nearer than this (as gap.signatures' cover histogram)


def choose_profile(points: np.ndarray, given: str | None = None, frame_rate_hz: float | None = None,
                   frames: list[np.ndarray] | None = None) -> tuple[str, SensorProfile, str]:  # fmt: skip
    """(name, profile, how) for a cloud (structured points of one frame, sensor frame): how is "given",
    "matched" or "derived" (its cover zone from ``frames``, default ``[points]``). A given profile that does
    not fit the cloud is a ValueError."""
    if given:
        profile = load_profile(given)
        try:
            check_profile(points, profile, given)
        except ObstacleError as exc:
            raise ValueError(str(exc)) from None
        return given, profile, "given"
    try:
        name = profile_for_cloud(points)
        return name, load_profile(name), "matched"
    except ObstacleError:
        profile = derive_profile(points, frame_rate_hz, frames=frames)
        return profile.name, profile, "derived"


def recorded_min_range(frames: list[np.ndarray]) -> float:
    """The minimum range the recording shows (module doc): its nearest positive return (m, to the cm below) when
    some lie in the cover zone, else :data:`COVER_M`."""
    d = np.concatenate([f["distance"].astype(np.float64) for f in frames]) if frames else np.zeros(0)
    d = d[(d > 0) & (d < COVER_M)]
    return math.floor(float(d.min()) * 100.0) / 100.0 if len(d) else COVER_M


def cover_zone(frames: list[np.ndarray], profile: SensorProfile) -> dict:
    """What ``frames`` (structured points, sensor frame) show in the cover zone: returns below :data:`COVER_M`
    (and per frame), the share of the profile's beams (channels x columns per frame) with at least one, the
    nearest return (m; None without any) and the profile's minimum range."""
    scan = profile.scan
    columns = scan.columns
    width = math.radians(scan.azimuth_max_deg - scan.azimuth_min_deg) or 2 * math.pi
    beams, returns, nearest = 0, 0, None
    for points in frames:
        d = points["distance"].astype(np.float64)
        near = (d > 0) & (d < COVER_M)
        returns += int(near.sum())
        if near.any():
            nearest = min(float(d[near].min()), nearest if nearest is not None else math.inf)
            az = np.arctan2(points["y"][near].astype(np.float64), points["x"][near].astype(np.float64))
            col = np.floor((az - math.radians(scan.azimuth_min_deg)) % (2 * math.pi) / width * columns).astype(np.int64)
            beams += len(np.unique(points["channel"][near].astype(np.int64) * (columns + 1) + col))
    total = len(frames) * len(profile.beams) * columns
    return {"below_m": COVER_M, "returns": returns, "returns_per_frame": returns / max(len(frames), 1),
            "beams_with_return_share": beams / total if total else 0.0,
            "nearest_m": None if nearest is None else round(nearest, 4), "profile_min_range_m": profile.range.min_m}  # fmt: skip


def derive_profile(points: np.ndarray, frame_rate_hz: float | None = None, name: str = "derived",
                   frames: list[np.ndarray] | None = None) -> SensorProfile:  # fmt: skip
    """A profile from a cloud (module doc); its minimum range from ``frames`` (default ``[points]``)."""
    channel = points["channel"].astype(np.int64)
    n = int(channel.max()) + 1
    elevation = np.degrees(points["elevation"].astype(np.float64))
    counts = np.bincount(channel, minlength=n)
    order = np.lexsort((elevation, channel))
    per = np.full(n, np.nan)  # median elevation per channel: the middle element of each channel's sorted run
    starts = np.concatenate([[0], np.cumsum(counts)[:-1]])
    has = counts > 0
    per[has] = elevation[order][starts[has] + (counts[has] - 1) // 2]
    known = np.flatnonzero(has)
    per = np.interp(np.arange(n), known, per[known])
    azimuth = points["azimuth"].astype(np.float64)
    order = np.lexsort((azimuth, channel))
    steps = np.diff(azimuth[order])
    same = np.diff(channel[order]) == 0
    steps = steps[same & (steps > 1e-5)]
    step = float(np.median(steps)) if len(steps) else math.radians(0.2)
    occupied = np.unique(np.floor(np.degrees(azimuth)).astype(np.int64)).size
    if occupied > 300:
        az_min, az_max = -180.0, 180.0
    else:
        az_min, az_max = float(np.degrees(azimuth.min())), float(np.degrees(azimuth.max()))
    columns = max(1, int(round(math.radians(az_max - az_min) / step)))
    base_name = min((p.stem for p in profiles_dir().glob("*.yaml")),
                    key=lambda s: (abs(len(load_profile(s).beams) - n), s))  # fmt: skip
    base = load_profile(base_name)
    scan = base.scan.model_copy(update={"frame_rate_hz": float(frame_rate_hz or DEFAULT_FRAME_RATE_HZ),
                                        "azimuth_min_deg": az_min, "azimuth_max_deg": az_max, "columns": columns,
                                        "sweep_fraction": 1.0 if occupied > 300 else base.scan.sweep_fraction,
                                        "layer_schedule": None})  # fmt: skip
    min_m = recorded_min_range([points] if frames is None else frames)
    return SensorProfile.model_validate({
        "name": name,
        "description": f"derived from a recording by lidar-weather-sim twin: {n} channels, {columns} columns",
        "source": f"geometry and minimum range ({min_m:g} m, the cover zone below {COVER_M:g} m): the recording's "
                  f"points; range, optics, pulse, detection: {base_name}",
        "beams": [{"elevation_deg": float(e)} for e in per],
        "scan": scan.model_dump(), "range": {**base.range.model_dump(), "min_m": min_m}, "optics": base.optics.model_dump(),
        "pulse": base.pulse.model_dump(), "detection": base.detection.model_dump(),
    })  # fmt: skip
