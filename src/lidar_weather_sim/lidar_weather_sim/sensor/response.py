"""How a real unit's output departs from the sensor model after detection (the sensor-side effects).

A recording's sensor differs from the model in ways no weather explains; ``sensor.response`` in a
scenario states them, and the gap search fits them (:mod:`lidar_weather_sim.scenario.effects`,
``sensor.*``):

- **intensity response**: the reported 0-255 intensity I becomes
  ``255 * min(1, intensity_scale * (I / 255) ** intensity_gamma)`` (rounded): a unit whose
  intensity is, e.g., calibrated reflectivity rather than our logarithmic amplitude scale
  (:func:`lidar_weather_sim.sensor.radiometry.intensity_byte`) has another gamma and gain;
- **range bias** ``range_bias_m`` (m, signed) added to every return's range, and **range noise**
  ``range_noise_m`` (m): Gaussian noise of that sigma added on top of the profile's own
  (``range.noise_sigma_m``), both along the ray: x, y, z scale with the range;
- **ray drop** ``drop_probability``: each return is lost with probability
  ``drop_probability * (1 - I / 255)``: dark returns (near the threshold: low intensity) go first,
  as on dark or glancing surfaces.

Applied to a finished frame's points (the points are changed in place where the dtype allows and
returned), with its own random stream per frame (:func:`~lidar_weather_sim.regions.base.region_entropy`,
name ``sensor_response``): the same seed gives the same output, and a response at its defaults
leaves the points untouched (bit for bit). Returns closer than the profile's minimum range after
the bias are dropped, as the echo stage drops them.
"""

from __future__ import annotations

import numpy as np
from pydantic import Field

from lidar_weather_sim.core.config import ConfigModel


class SensorResponse(ConfigModel):
    intensity_scale: float = Field(1.0, gt=0, le=100, description="Gain on the normalised intensity (I/255)")
    intensity_gamma: float = Field(1.0, gt=0, le=20, description="Exponent on the normalised intensity (I/255)")
    range_bias_m: float = Field(0.0, ge=-5, le=5, description="Added to every range (m)")
    range_noise_m: float = Field(0.0, ge=0, le=5, description="Extra Gaussian range noise sigma (m)")
    drop_probability: float = Field(0.0, ge=0, le=1, description="Loss probability of a return at intensity 0 "
                                                                  "(falls linearly to 0 at 255)")  # fmt: skip

    @property
    def identity(self) -> bool:
        return self == SensorResponse()


def intensity_table(response: SensorResponse) -> np.ndarray:
    """The 256-entry uint8 map of the intensity response."""
    level = np.arange(256, dtype=np.float64) / 255.0
    return np.round(255.0 * np.minimum(1.0, response.intensity_scale * level**response.intensity_gamma)).astype(np.uint8)


def apply_response(points: np.ndarray, response: SensorResponse, rng: np.random.Generator, min_range_m: float) -> np.ndarray:
    """``points`` (the project's structured layout: x, y, z, distance, intensity) after ``response``."""
    if response.identity or not len(points):
        return points
    keep = np.ones(len(points), bool)
    if response.drop_probability > 0:
        keep &= rng.random(len(points)) >= response.drop_probability * (1.0 - points["intensity"] / 255.0)
    if response.range_bias_m != 0 or response.range_noise_m > 0:
        distance = points["distance"].astype(np.float64)
        new = distance + response.range_bias_m
        if response.range_noise_m > 0:
            new += rng.normal(0.0, response.range_noise_m, len(points))
        keep &= new >= max(min_range_m, 1e-3)
        scale = np.where(distance > 0, new / np.maximum(distance, 1e-9), 1.0)
        for axis in ("x", "y", "z"):
            points[axis] = points[axis] * scale
        points["distance"] = new
    if response.intensity_scale != 1 or response.intensity_gamma != 1:
        points["intensity"] = intensity_table(response)[points["intensity"]]
    return points if keep.all() else points[keep]
