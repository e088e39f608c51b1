"""The reality gap's signature sees what a single-return driver leaves out."""

from __future__ import annotations

import numpy as np

from lidar_weather_sim.core.points import empty_points, fill_polar
from lidar_weather_sim.gap.search import MIN_ABS_GAIN
from lidar_weather_sim.gap.signatures import FrameContext, Signature, gap_value

CHANNELS = 16
POINTS_PER_FRAME = 24_000
SECOND_ECHO_SHARE = 0.021  # the VLP-16 re-simulation of ouster_street: 513 second echoes in 24 359 points


def street_frame(rng: np.random.Generator, single_return: bool) -> np.ndarray:
    """A street-like frame (ranges 2-60 m, a road 1.8 m below the sensor) whose beams give a second echo
    (behind the first, weaker) at ``SECOND_ECHO_SHARE`` of the points, or none when ``single_return``."""
    n = POINTS_PER_FRAME
    second = rng.random(n) < SECOND_ECHO_SHARE
    if single_return:
        second[:] = False
    pts = empty_points(n, ground_truth=False)
    rng_m = rng.uniform(2.0, 60.0, n)
    rng_m[second] += rng.uniform(0.5, 10.0, int(second.sum()))
    azimuth = rng.uniform(-np.pi, np.pi, n)
    channel = rng.integers(0, CHANNELS, n)
    elevation = np.radians(-15.0 + 2.0 * channel)
    pts["x"] = rng_m * np.cos(elevation) * np.cos(azimuth)
    pts["y"] = rng_m * np.cos(elevation) * np.sin(azimuth)
    pts["z"] = rng_m * np.sin(elevation)
    pts["channel"] = channel
    pts["intensity"] = np.where(second, rng.uniform(0, 40, n), rng.uniform(0, 255, n))
    pts["echo"] = np.where(second, 2, 1)
    pts["epw"] = rng.uniform(0.3, 1.5, n)
    fill_polar(pts)
    return pts


def signature(seed: int, single_return: bool, frames: int = 2) -> Signature:
    rng = np.random.default_rng(seed)
    sig = Signature(channels=CHANNELS)
    for _ in range(frames):
        sig.add(street_frame(rng, single_return), FrameContext(road_z_m=-1.8))
    return sig


def test_a_single_return_recording_is_farther_from_every_echo_than_the_search_margin():
    """2 % second echoes are below the counting noise of the per-zone histograms; their own histogram makes
    a recording without them (driver in first / strongest single return) differ by many times the margin,
    while two draws of the same mode stay within it."""
    all_echoes, single, redraw = signature(1, False), signature(2, True), signature(3, False)
    assert gap_value(single, all_echoes) > 10 * MIN_ABS_GAIN
    assert gap_value(redraw, all_echoes) < MIN_ABS_GAIN
