"""A synthetic spinning-LiDAR frame for wiring checks (RViz, recorders, DDS).

Not a sensor model: a 16-channel, 0.5 deg sweep that hits a flat ground plane
and a cylindrical wall, with every point field filled so that downstream tools
see the full layout of :mod:`lidar_weather_sim.core.points`.
"""

from __future__ import annotations

import numpy as np

from lidar_weather_sim.core.points import Label, empty_points, fill_polar


def synthetic_frame(
    frame_index: int,
    *,
    channels: int = 16,
    columns: int = 720,
    mount_height_m: float = 1.8,
    wall_radius_m: float = 20.0,
    period_s: float = 0.1,
    ground_truth: bool = True,
) -> np.ndarray:
    """Points of one sweep in the sensor frame (m, rad, ns after the frame stamp).

    Beams from -15 to +15 deg elevation; the ground is ``mount_height_m`` below the
    sensor, the wall a cylinder of ``wall_radius_m`` around it. A 6 deg sector
    labelled OBSTACLE (object id 1) turns once per 36 frames, so colouring by
    label shows the frames advancing.
    """
    elevation = np.deg2rad(np.linspace(-15.0, 15.0, channels))
    azimuth = np.deg2rad(np.arange(columns) * 360.0 / columns) - np.pi
    el, az = np.meshgrid(elevation, azimuth, indexing="ij")
    down = np.tan(-el)
    with np.errstate(divide="ignore"):
        horizontal_to_ground = np.where(down > 0, mount_height_m / np.where(down > 0, down, 1.0), np.inf)
    horizontal = np.minimum(horizontal_to_ground, wall_radius_m)
    rng_xy = horizontal.ravel()
    points = empty_points(rng_xy.size, ground_truth=ground_truth)
    points["x"] = rng_xy * np.cos(az.ravel())
    points["y"] = rng_xy * np.sin(az.ravel())
    points["z"] = rng_xy * np.tan(el.ravel())
    fill_polar(points)
    points["channel"] = np.repeat(np.arange(channels, dtype=np.uint16), columns)
    column = np.tile(np.arange(columns), channels)
    points["time_stamp"] = (column * (period_s * 1e9 / columns)).astype(np.uint32)
    points["intensity"] = np.where(horizontal_to_ground.ravel() < wall_radius_m, 20, 120)
    points["return_type"] = 1
    points["echo"] = 1
    points["epw"] = np.where(horizontal_to_ground.ravel() < wall_radius_m, 0.9, 1.4).astype(np.float32)
    if ground_truth:
        points["label"] = Label.STATIC
        marker = np.abs(np.angle(np.exp(1j * (points["azimuth"] - frame_index * np.pi / 18)))) < np.deg2rad(3)
        points["label"][marker] = Label.OBSTACLE
        points["object_id"][marker] = 1
    return points
