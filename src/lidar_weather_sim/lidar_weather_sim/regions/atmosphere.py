"""Region plugin ``atmosphere``: fog, rain and snow along the ray (thesis paper 2), as physics at the profile's
wavelength.

Inputs: the scenario's weather block (OpenSCENARIO names: ``fog.visual_range_m``, ``precipitation.type`` /
``intensity_mm_h``, ``road``), overridable in the parameters. Sunlight is not handled here: it raises the
receiver's noise floor in the simulator. Nothing is fitted to a sensor: the media come from drop-size
distributions and Mie or geometric cross-sections at the profile's wavelength, seen through the profile's beam,
pulse, overlap and threshold (:mod:`lidar_weather_sim.regions.physical_air`).

Effects per batch (world frame rays, ranges in m along the ray):

- extinction: the media's ``alpha`` (1/m), summed; the echo stage applies exp(-2 alpha R);
- drops and flakes one by one where they can be detected alone, in front of each beam's hit;
- the volume return of the fog and of the drops too small to be seen alone: per-beam tables of the echo stage,
  cut at the beam's hit (:mod:`lidar_weather_sim.regions.air_volume`);
- road surface (scene hits on up-facing surfaces, |n_z| > 0.9): wetness w scales the reflectance by
  (rho_wet / rho_dry)^w (materials ``asphalt_wet`` / ``asphalt_dry``), w = 1 - exp(-h / T_s) for a water film
  h (``weather.road.water_film_mm``, or this region's ``road_water_film_mm``; none given: eq. 1's film of the
  rain, :meth:`lidar_weather_sim.regions.weather.Road.film_mm`, 0 when dry) and the road's mean texture depth
  T_s (``weather.road.texture_depth_mm``): the film darkens the road as it fills the texture and turns it into
  a mirror once it covers it; a snow cover of depth d (``weather.road.snow_depth_m``, none: 0) replaces the
  reflectance by that of ``snow`` and moves the hit forward along the ray by d / cos(incidence).

A fitted model (one sensor's rooftop statistics per weather class) was the default until 2026-11-29; it was removed,
and ``model: fitted`` is refused with one line. The physical model is not yet at clear-weather speed on dense
sensors (docs/speed.md).
"""

from __future__ import annotations

from typing import Any, ClassVar, Literal

import numpy as np
from pydantic import Field, model_validator
from pydantic_core import PydanticCustomError

from lidar_weather_sim.core.config import ConfigModel
from lidar_weather_sim.regions.base import RayBatch, RegionContext, RegionEffect
from lidar_weather_sim.regions.physical_air import PhysicalAir
from lidar_weather_sim.regions.weather import Weather
from lidar_weather_sim.scene.materials import MaterialTable

PHYSICAL_FOG_LIMIT_M = 10000.0  # haze up to 10 km visual range is still a medium; beyond, clear air
#: Why a key of the removed fitted model is refused.
FITTED_REMOVED = ("the fitted atmosphere model was removed: the atmosphere is physical (drop-size distributions, Mie, "
                  "the profile's optics)")  # fmt: skip


class AtmosphereParams(ConfigModel):
    visual_range_m: float | None = Field(None, gt=0, description="Overrides weather.fog.visual_range_m (m)")
    precipitation_type: Literal["dry", "rain", "snow"] | None = Field(None, description="Overrides weather.precipitation.type")
    intensity_mm_h: float | None = Field(None, ge=0, le=300, description="Overrides weather.precipitation.intensity_mm_h (mm/h; <= 300 as there)")
    air: bool = Field(True, description="Extinction and scatterers in the air; false: only the road surface changes")
    road_water_film_mm: float | None = Field(None, ge=0, le=10, description="Overrides weather.road.water_film_mm "
                                             "for this region (mm); both none: eq. 1's film of the rain")
    fog_backscatter_gain: float = Field(1.0, ge=0, le=1, description="Share (0-1) of the fog's backscatter that the "
                                        "receiver turns into signal, at every range, its extinction untouched: 1 the "
                                        "profile's optics alone, 0 a fog that is loss only (a unit whose pulse "
                                        "discrimination, near-range gain or blanking keeps the fog's soft echoes out)")

    moved_keys: ClassVar[dict[str, str]] = {
        "road_texture_depth_mm": "moved to weather.road.texture_depth_mm",
        "near_field_gain": "replaced by fog_backscatter_gain (the fog's alone, at every range)",
        **{key: FITTED_REMOVED for key in ("fit_file", "weather_class", "near_field_max_m", "path_gap_m", "splash_depth_m")},
    }

    @model_validator(mode="before")
    @classmethod
    def _only_the_physical_model(cls, data: Any) -> Any:
        """``model: physical`` (the one model) is accepted and dropped; any other model is refused."""
        if isinstance(data, dict) and "model" in data:
            if data["model"] != "physical":
                raise PydanticCustomError("removed_model", FITTED_REMOVED)
            data = {k: v for k, v in data.items() if k != "model"}
        return data


class AtmosphereRegion:
    name = "atmosphere"
    Params = AtmosphereParams

    def __init__(self, params: AtmosphereParams, context: RegionContext) -> None:
        self.p = params
        self.profile = context.profile
        w = context.weather or Weather()
        self.visual_range_m = params.visual_range_m or w.fog.visual_range_m
        self.precipitation = params.precipitation_type or w.precipitation.type
        self.intensity = params.intensity_mm_h if params.intensity_mm_h is not None else w.precipitation.intensity_mm_h
        if self.precipitation == "dry":
            self.intensity = 0.0
        mats = context.materials or MaterialTable.default()
        self._refl = np.append(mats.reflectivity, 1.0)
        rain = self.intensity if self.precipitation == "rain" else 0.0
        film = params.road_water_film_mm if params.road_water_film_mm is not None else w.road.film_mm(rain)
        self.wetness = 1.0 - float(np.exp(-film / w.road.texture_depth_mm))
        self._wet_scale = (mats["asphalt_wet"].reflectivity / mats["asphalt_dry"].reflectivity) ** self.wetness
        self.snow_depth_m = w.road.snow_depth_m or 0.0
        self._snow_refl = mats["snow"].reflectivity
        fog = self.visual_range_m if self.visual_range_m < PHYSICAL_FOG_LIMIT_M else None
        precip = (self.precipitation, self.intensity) if self.precipitation != "dry" and self.intensity > 0 else None
        self.physical = PhysicalAir(context.profile, fog, precip, params.fog_backscatter_gain)
        self.alpha = self.physical.alpha

    def step(self, t0_s: float, t1_s: float) -> None:
        """Stationary weather: nothing to advance."""

    def apply(self, batch: RayBatch, rng: np.random.Generator) -> RegionEffect:
        n, s = batch.shape
        scatterers, volume = self.physical.scatterers(batch, rng) if self.p.air else (None, None)
        ground = np.isfinite(batch.distance) & (np.abs(batch.normal[..., 2]) > 0.9)
        scale = np.where(ground, self._wet_scale, 1.0)
        offset = np.zeros((n, s))
        if self.snow_depth_m > 0 and self.p.air:
            cos_inc = np.maximum(np.abs(np.einsum("nsk,nsk->ns", batch.normal, batch.directions)), 0.05)
            scale = np.where(ground, self._snow_refl / np.maximum(self._refl[batch.material], 1e-6), scale)
            offset = np.where(ground, -self.snow_depth_m / cos_inc, 0.0)
        return RegionEffect(
            extinction_per_m=np.full((n, s), self.alpha if self.p.air else 0.0),
            scatterers=scatterers,
            reflectance_scale=scale,
            range_offset_m=offset,
            volume=volume or None,
        )
