"""Region plugin ``template_region``: a uniform haze, the smallest region that changes a scan.

Copy this package to write a region (``README.md``). The contract is
:mod:`lidar_weather_sim.regions.base`: a class with a ``name``, a ``Params`` model, a constructor
``cls(params, context)``, ``step(t0_s, t1_s)`` and ``apply(batch, rng) -> RegionEffect``.

What it models: a homogeneous medium of extinction coefficient alpha (1/m) filling the whole scene.
The region only reports alpha per sub-ray (``RegionEffect.extinction_per_m``); the echo stage applies
the two-way Beer-Lambert loss exp(-2 alpha R) to every return at range R, so far and dark targets fall
below the detection threshold first. It adds no returns of its own (no ``scatterers``) and changes no
material (no ``reflectance_scale`` / ``range_offset_m``).
"""

from __future__ import annotations

import numpy as np
from pydantic import Field

from lidar_weather_sim.core.config import ConfigModel
from lidar_weather_sim.regions.base import RayBatch, RegionContext, RegionEffect
from lidar_weather_sim.regions.extinction import fog_alpha


class TemplateParams(ConfigModel):
    """Set in a scenario as ``region_params: {template_region: {...}}``; unknown keys are refused."""

    visual_range_m: float = Field(1000.0, gt=0, description="Meteorological visual range V of the haze (m); "
                                                            "alpha = 3.912 / V (Koschmieder)")
    extinction_per_m: float | None = Field(None, ge=0, le=1, description="alpha (1/m) given directly; "
                                                                         "null = from visual_range_m")


class TemplateRegion:
    name = "template_region"
    Params = TemplateParams

    def __init__(self, params: TemplateParams, context: RegionContext) -> None:
        # context.profile, .weather, .materials, .actors, .pose_source, .inputs: what a region may read;
        # this one needs none of them
        self.p = params
        self.alpha = params.extinction_per_m if params.extinction_per_m is not None else fog_alpha(params.visual_range_m)

    def step(self, t0_s: float, t1_s: float) -> None:
        """Stationary haze: nothing to advance (a region with state moves it to simulated time ``t1_s`` here)."""

    def apply(self, batch: RayBatch, rng: np.random.Generator) -> RegionEffect:
        """The same alpha on every sub-ray of the batch (shape N beams x S sub-rays); draw any randomness from
        ``rng`` (seeded per frame and plugin by the simulator: same seed, same scan)."""
        return RegionEffect(extinction_per_m=np.full(batch.shape, self.alpha))
