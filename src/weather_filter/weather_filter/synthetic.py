"""Constructed labelled clouds with known weather points, for tests and classifier training.

A simple analytic scene (flat road, axis-aligned boxes) is scanned with a
multi-layer pattern; weather scatterers (rain/fog/snow near-field clutter,
spray behind a vehicle) are inserted in front of the solid hit of a beam, so
that the weather return is echo 1 and the solid surface becomes echo 2, as in
the multi-echo sensor. Weather points are weak (low intensity, short EPW).
This is *not* the project's physical weather simulation (the cover/atmosphere
and spray regions); it is a stand-in with the same point layout and labels.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from lidar_weather_sim.core.points import Label, empty_points, fill_polar


@dataclass(frozen=True)
class Box:
    """Axis-aligned box in the sensor frame (m) with a label, object id and reflectance (0-1)."""

    lo: tuple[float, float, float]
    hi: tuple[float, float, float]
    label: int = Label.VEHICLE
    object_id: int = 1
    reflectance: float = 0.5


def _ray_box(dirs: np.ndarray, box: Box) -> np.ndarray:
    """Entry distance of rays from the origin into ``box`` (inf if missed); slab method, vectorised."""
    with np.errstate(divide="ignore", invalid="ignore"):
        inv = 1.0 / dirs
        t1 = np.asarray(box.lo)[None, :] * inv
        t2 = np.asarray(box.hi)[None, :] * inv
    tmin = np.nanmax(np.minimum(t1, t2), axis=1)
    tmax = np.nanmin(np.maximum(t1, t2), axis=1)
    hit = (tmax >= np.maximum(tmin, 0.0)) & (tmin > 0)
    return np.where(hit, tmin, np.inf)


def scan(
    boxes: list[Box],
    *,
    sensor_height_m: float = 0.5,
    channels: int = 16,
    elevation_deg: tuple[float, float] = (-6.0, 3.0),
    azimuth_deg: tuple[float, float] = (-72.5, 72.5),
    azimuth_step_deg: float = 0.25,
    max_range_m: float = 120.0,
    weather: str | None = None,
    weather_rate: float = 0.0,
    weather_max_range_m: float = 8.0,
    spray_volume: tuple[tuple[float, float, float], tuple[float, float, float]] | None = None,
    spray_rate: float = 0.0,
    frame: int = 0,
    seed: int = 0,
) -> np.ndarray:
    """One labelled frame (project point layout with ground truth).

    ``weather`` ('rain', 'fog', 'snow' or None) adds, with probability ``weather_rate`` per beam, a return at a
    random range up to ``weather_max_range_m``; ``spray_volume`` (lo, hi corners) adds, with probability
    ``spray_rate`` per beam crossing it, a return inside it (label spray, object id 100).
    """
    rng = np.random.default_rng([seed, frame])
    elev = np.radians(np.linspace(*elevation_deg, channels))
    az = np.radians(np.arange(azimuth_deg[0], azimuth_deg[1] + 1e-9, azimuth_step_deg))
    ch, col = np.meshgrid(np.arange(channels), np.arange(len(az)), indexing="ij")
    ch, col = ch.ravel(), col.ravel()
    e, a = elev[ch], az[col]
    dirs = np.column_stack([np.cos(e) * np.cos(a), np.cos(e) * np.sin(a), np.sin(e)])
    n = len(dirs)
    # solid hits: ground plane z = -sensor_height and boxes
    with np.errstate(divide="ignore"):
        t_ground = np.where(dirs[:, 2] < 0, -sensor_height_m / dirs[:, 2], np.inf)
    t = t_ground.copy()
    label = np.full(n, Label.STATIC, np.uint8)
    obj = np.zeros(n, np.uint32)
    refl = np.full(n, 0.15)
    for box in boxes:
        shifted = Box((box.lo[0], box.lo[1], box.lo[2] + sensor_height_m), (box.hi[0], box.hi[1], box.hi[2] + sensor_height_m))
        tb = _ray_box(dirs, shifted)  # boxes given with z from the ground up
        closer = tb < t
        t[closer], label[closer], obj[closer], refl[closer] = tb[closer], box.label, box.object_id, box.reflectance
    solid = np.isfinite(t) & (t <= max_range_m)
    t_solid = t + rng.normal(0, 0.02, n)
    # weather scatterers in front of the solid hit
    w_range = np.full(n, np.inf)
    w_label = np.zeros(n, np.uint8)
    if weather and weather_rate > 0:
        code = {"rain": Label.RAIN, "fog": Label.FOG, "snow": Label.SNOW}[weather]
        pick = rng.random(n) < weather_rate
        r = 0.5 + rng.exponential(weather_max_range_m / 3, n)
        pick &= (r < weather_max_range_m) & (r < t_solid - 0.5)
        w_range[pick], w_label[pick] = r[pick], code
    if spray_volume is not None and spray_rate > 0:
        lo, hi = (np.asarray(c, float) for c in spray_volume)
        lo, hi = lo + [0, 0, sensor_height_m], hi + [0, 0, sensor_height_m]
        with np.errstate(divide="ignore", invalid="ignore"):
            t1, t2 = lo / dirs, hi / dirs
        tin = np.clip(np.nanmax(np.minimum(t1, t2), axis=1), 0, None)
        tout = np.nanmin(np.maximum(t1, t2), axis=1)
        crosses = tout > tin
        pick = crosses & (rng.random(n) < spray_rate)
        with np.errstate(invalid="ignore"):
            r = tin + rng.random(n) * (np.minimum(tout, t_solid - 0.3) - tin)
        pick &= (r > tin) & (r < t_solid - 0.3) & (r < w_range)
        w_range[pick], w_label[pick] = r[pick], Label.SPRAY
    has_w = np.isfinite(w_range)
    # assemble: weather echo 1, solid echo 1 or 2
    rows_solid = np.flatnonzero(solid)
    rows_w = np.flatnonzero(has_w)
    pts = empty_points(len(rows_solid) + len(rows_w))
    rng_all = np.concatenate([t_solid[rows_solid], w_range[rows_w]])
    beam = np.concatenate([rows_solid, rows_w])
    pts["x"], pts["y"], pts["z"] = (dirs[beam] * rng_all[:, None]).T
    pts["z"] -= 0.0
    pts["channel"] = ch[beam]
    pts["time_stamp"] = (col[beam] * 10_000).astype(np.uint32)
    pts["return_type"] = 1
    ns = len(rows_solid)
    pts["label"][:ns] = label[rows_solid]
    pts["object_id"][:ns] = obj[rows_solid]
    pts["echo"][:ns] = np.where(has_w[rows_solid], 2, 1)
    cos_inc = np.clip(np.abs(dirs[rows_solid, 2]) * 3 + 0.3, 0.3, 1.0)
    power = refl[rows_solid] * cos_inc / np.maximum(t_solid[rows_solid], 1.0) ** 0.5
    pts["intensity"][:ns] = np.clip(60 + 400 * power + rng.normal(0, 5, ns), 30, 255).astype(np.uint8)
    pts["epw"][:ns] = np.clip(1.0 + 0.8 * refl[rows_solid] + rng.normal(0, 0.1, ns), 0.6, 2.2)
    pts["label"][ns:] = w_label[rows_w]
    pts["object_id"][ns:] = np.where(w_label[rows_w] == Label.SPRAY, 100, 0)
    pts["echo"][ns:] = 1
    pts["intensity"][ns:] = np.clip(rng.gamma(2.0, 9.0, len(rows_w)), 1, 255).astype(np.uint8)
    pts["epw"][ns:] = np.clip(rng.normal(0.5, 0.15, len(rows_w)), 0.1, 1.5)
    fill_polar(pts)
    return pts


def highway_frame(weather: str | None = "rain", frame: int = 0, seed: int = 0, rate: float = 0.05,
                  spray: bool = True, obstacle_in_spray: bool = False) -> np.ndarray:  # fmt: skip
    """Highway-like constructed frame: leading vehicle 17.5 m ahead in the left lane with spray behind it,
    a truck in the right lane, guard rails; optional obstacle box standing inside the spray cloud."""
    boxes = [
        Box((17.5, 2.8, 0.0), (22.2, 4.65, 1.45), Label.VEHICLE, 1, 0.6),
        Box((35.0, -5.5, 0.0), (45.0, -3.0, 3.0), Label.VEHICLE, 2, 0.4),
        Box((0.0, 8.0, 0.0), (120.0, 8.3, 0.8), Label.STATIC, 0, 0.3),
        Box((0.0, -9.0, 0.0), (120.0, -8.7, 0.8), Label.STATIC, 0, 0.3),
    ]
    if obstacle_in_spray:
        boxes.append(Box((11.0, 3.1, 0.0), (11.6, 3.9, 0.6), Label.OBSTACLE, 3, 0.2))
    spray_volume = ((8.0, 2.4, 0.0), (17.5, 5.0, 1.5)) if spray else None
    return scan(boxes, weather=weather, weather_rate=rate if weather else 0.0, spray_volume=spray_volume,
                spray_rate=0.3 if spray else 0.0, frame=frame, seed=seed)  # fmt: skip
