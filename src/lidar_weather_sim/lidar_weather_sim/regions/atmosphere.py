"""Region plugin ``atmosphere``: fog, rain and snow along the ray (thesis paper 2).

Inputs: the scenario's weather block (OpenSCENARIO names: ``fog.visual_range_m``,
``precipitation.type`` / ``intensity_mm_h``), overridable in the parameters, and
one physical parameter set per weather class from ``config/atmosphere_fit.yaml``
(written by ``benchmarks/calibration/fit_atmosphere.py``). Sunlight is not handled here: it
raises the receiver's noise floor in the simulator.

Effects per batch (world frame rays, ranges in m along the ray):

Two models (parameter ``model``). ``fitted`` (the default, described below) is a per-weather-class fit of
one sensor's rooftop statistics; ``physical`` replaces the extinction, the near field and the path drops by
physics at the profile's wavelength (:mod:`lidar_weather_sim.regions.physical_air`: drop-size distributions,
Mie, the beam's volume, the volume return as pulses); the road surface is the same in both.

- extinction: Beer-Lambert ``alpha`` = fog (Koschmieder) + rain/snow
  (:mod:`lidar_weather_sim.regions.extinction`); the echo stage applies exp(-2 alpha R);
- near-field scatterers 0-5 m per beam (:mod:`lidar_weather_sim.regions.near_field`): cover
  multipath (wet cover, exponential 0-0.5 m) and drops/flakes/droplets (plateau with
  the overlap peak); their rate scales with alpha / alpha_reference of the fit. A fog (visual range
  below 1 km) with rain or snow draws both classes, each at its own extinction over its reference
  (volume scatterers labelled FOG and RAIN / SNOW; the road is the precipitation's).
  Their EPW and echo numbers come from the echo stage;
- drops in front of the street: per beam hitting the scene beyond the near field,
  Poisson scatterers between the end of the near field and the hit, at least ``path_gap_m``
  from both (the near field ends ``near_field_max_m`` ahead horizontally along the sensor's
  axis, the paper's x: at (5 m + gap) / (cos(elevation) cos(azimuth)) along a ray), which turn
  street returns into second echoes; and (class parameter ``splash_rate_per_beam``) splash
  drops above up-facing hits, in the last ``splash_depth_m`` of range before that gap (paper 2:
  the street region "includes reflections coming from water drops splash");
- road surface (scene hits on up-facing surfaces, |n_z| > 0.9): wetness w scales the
  reflectance by (rho_wet / rho_dry)^w (materials ``asphalt_wet`` / ``asphalt_dry``).
  w is the weather class's fitted wetness, or, when a water film h is given (``weather.road.
  water_film_mm``, or this region's ``road_water_film_mm``), w = 1 - exp(-h / T_s) with T_s the
  road's mean texture depth (``weather.road.texture_depth_mm``): the film darkens the
  road as it fills the texture and turns it into a mirror once it covers it;
  a snow cover of depth d (``weather.road.snow_depth_m``, else the weather class's fitted
  depth) replaces the reflectance by that of ``snow`` and moves the hit forward along the ray
  by d / cos(incidence).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import ClassVar, Literal

import numpy as np
from pydantic import Field

from lidar_weather_sim.core.config import ConfigError, ConfigModel, load_yaml
from lidar_weather_sim.core.points import Label
from lidar_weather_sim.regions.base import RayBatch, RegionContext, RegionEffect, Scatterers
from lidar_weather_sim.regions.extinction import total_alpha
from lidar_weather_sim.regions.near_field import NearFieldModel, sample_near_field
from lidar_weather_sim.regions.physical_air import PhysicalAir
from lidar_weather_sim.regions.weather import Weather
from lidar_weather_sim.scene.materials import MaterialTable
from lidar_weather_sim.sensor.radiometry import dark_level, reflectance_for_peak

WEATHER_CLASSES = ("clear", "rain", "fog", "snow")
VOLUME_LABEL = {"clear": Label.NOISE, "rain": Label.RAIN, "fog": Label.FOG, "snow": Label.SNOW}
FOG_VISUAL_RANGE_LIMIT_M = 1000.0  # fog: visibility below 1 km (WMO)
PHYSICAL_FOG_LIMIT_M = 10000.0  # physical model: haze up to 10 km visual range is still a medium; beyond, clear air



class ClassParams(ConfigModel):
    """Physical parameters of one weather class (fitted; see benchmarks/calibration/fit_atmosphere.py)."""

    rate_per_beam: float = Field(ge=0, description="Near-field scatterers per beam and frame at the reference weather")
    cover_share: float = Field(ge=0, le=1, description="Share of near-field scatterers that are cover multipath")
    cover_scale_m: float = Field(gt=0, description="Exponential range scale of cover returns (m)")
    amplitude_median: float = Field(gt=0, description="Median near-field peak over the dark threshold (at 1.8 m for volume)")
    amplitude_sigma_ln: float = Field(ge=0, description="Log-sd of the near-field peak amplitude")
    path_rate_per_beam: float = Field(0.0, ge=0, description="Scatterers between 5 m and the scene hit per beam and frame")
    path_amplitude_median: float = Field(1.0, gt=0, description="Median peak of path scatterers over the dark threshold")
    path_amplitude_sigma_ln: float | None = Field(None, ge=0, description="Log-sd of the path scatterers' peak "
                                                                          "(none: amplitude_sigma_ln)")
    splash_rate_per_beam: float = Field(0.0, ge=0, description="Splash drops per beam and frame just above an up-facing "
                                                                 "hit (the paper's street region includes splash, line 1550)")
    wetness: float = Field(0.0, ge=0, le=1, description="Road wetness: reflectance x (rho_wet/rho_dry)^wetness")
    cover_amp_scale_m: float = Field(0.0, ge=0, description="Cover multipath amplitude falls as exp(-R / scale) (0: flat)")
    snow_depth_m: float = Field(0.0, ge=0, description="Snow cover on up-facing surfaces (m)")


class FitFile(ConfigModel):
    source: str = ""
    reference: dict[str, float] = Field(description="Reference weather of the fit: fog_visual_range_m, rain_mm_h, snow_mm_h")
    day_irradiance_w_m2: float = Field(343.0, ge=0, description="Irradiance used for the 'with sun' rows of the fit (W/m^2)")
    street_gain: float = Field(1.0, gt=0, description="Rooftop scene only: backscatter of the lot's asphalt at 46 deg "
                                                      "relative to a Lambertian surface of its albedo (fitted on clear)")
    classes: dict[Literal["clear", "rain", "fog", "snow"], ClassParams]
    fit_report: dict = Field(default_factory=dict)


def fit_path() -> Path:
    from lidar_weather_sim.core.paths import config_dir

    return config_dir() / "atmosphere_fit.yaml"


class AtmosphereParams(ConfigModel):
    fit_file: str | None = Field(None, description="Fitted parameter file (default config/atmosphere_fit.yaml)")
    weather_class: Literal["auto", "clear", "rain", "fog", "snow"] = Field("auto", description="auto: from the weather")
    visual_range_m: float | None = Field(None, gt=0, description="Overrides weather.fog.visual_range_m (m)")
    precipitation_type: Literal["dry", "rain", "snow"] | None = Field(None, description="Overrides weather.precipitation.type")
    intensity_mm_h: float | None = Field(None, ge=0, le=300, description="Overrides weather.precipitation.intensity_mm_h (mm/h; <= 300 as there)")
    near_field_max_m: float = Field(5.0, gt=0.5, description="Far end of the near-field volume (m)")
    path_gap_m: float = Field(0.8, ge=0, description="Path scatterers end this far before the scene hit (m)")
    splash_depth_m: float = Field(1.5, gt=0, description="Splash drops lie up to this far (range) before the path gap (m)")
    air: bool = Field(True, description="Extinction and scatterers in the air; false: only the road surface changes")
    model: Literal["fitted", "physical"] = Field(
        "fitted", description="fitted: the near field and path drops fitted per weather class (fit_file); physical: "
                              "drops and volume from the drop-size distribution at the profile's wavelength "
                              "(regions.physical_air)")  # fmt: skip
    road_water_film_mm: float | None = Field(None, ge=0, le=10, description="Overrides weather.road.water_film_mm "
                                             "for this region (mm); both none: the weather class's wetness")

    moved_keys: ClassVar[dict[str, str]] = {"road_texture_depth_mm": "moved to weather.road.texture_depth_mm"}


@dataclass(frozen=True)
class AirComponent:
    """One weather class's part of the fitted air: its parameters, the factor on their rates (the weather's
    extinction over the fit's reference) and the label of its volume scatterers."""

    c: ClassParams
    rate_scale: float
    label: int
    near_field: NearFieldModel


def classify(visual_range_m: float, precipitation: str) -> str:
    if precipitation in ("rain", "snow"):
        return precipitation
    return "fog" if visual_range_m < FOG_VISUAL_RANGE_LIMIT_M else "clear"


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
        self.weather_class = classify(self.visual_range_m, self.precipitation) if params.weather_class == "auto" \
            else params.weather_class  # fmt: skip
        path = Path(params.fit_file) if params.fit_file else fit_path()
        fit = load_yaml(path, FitFile)
        if self.weather_class not in fit.classes:
            raise ConfigError(f"{path}: key 'classes.{self.weather_class}' missing (weather class of the scenario)")
        self.c = fit.classes[self.weather_class]
        self.alpha = total_alpha(self.visual_range_m, self.precipitation, self.intensity)
        self.components = self._fitted_components(fit, params)
        mats = context.materials or MaterialTable.default()
        self._refl = np.append(mats.reflectivity, 1.0)
        film = params.road_water_film_mm if params.road_water_film_mm is not None else w.road.water_film_mm
        self.wetness = self.c.wetness if film is None else 1.0 - float(np.exp(-film / w.road.texture_depth_mm))
        self._wet_scale = (mats["asphalt_wet"].reflectivity / mats["asphalt_dry"].reflectivity) ** self.wetness
        self.snow_depth_m = self.c.snow_depth_m if w.road.snow_depth_m is None else w.road.snow_depth_m
        self._snow_refl = mats["snow"].reflectivity
        self.physical = None
        if params.model == "physical":
            fog = self.visual_range_m if self.visual_range_m < PHYSICAL_FOG_LIMIT_M else None
            precip = (self.precipitation, self.intensity) if self.precipitation != "dry" and self.intensity > 0 else None
            self.physical = PhysicalAir(context.profile, fog, precip)
            self.alpha = self.physical.alpha

    def _fitted_components(self, fit: FitFile, params: AtmosphereParams) -> list[AirComponent]:
        """The fitted air: one weather class scaled by the total extinction, or, when a fog (visual range
        below 1 km) falls with rain or snow and the class is automatic, each from its own class scaled by its
        own extinction (the classes are fits of one weather each: rain's near field scaled by a fog's
        extinction is no rain, and ~20x the scatterers)."""
        ref = fit.reference
        ref_alpha = {
            "clear": None,
            "fog": total_alpha(ref["fog_visual_range_m"], "dry", 0.0),
            "rain": total_alpha(1.0e5, "rain", ref["rain_mm_h"]),
            "snow": total_alpha(1.0e5, "snow", ref["snow_mm_h"]),
        }
        mixed = params.weather_class == "auto" and self.precipitation in ("rain", "snow") \
            and self.visual_range_m < FOG_VISUAL_RANGE_LIMIT_M  # fmt: skip
        if not mixed:
            reference = ref_alpha[self.weather_class]
            return [self.component(self.c, 1.0 if reference is None else self.alpha / reference,
                                   VOLUME_LABEL[self.weather_class])]  # fmt: skip
        if "fog" not in fit.classes:
            raise ConfigError(f"{params.fit_file or fit_path()}: key 'classes.fog' missing (fog with "
                              f"{self.precipitation} in the scenario)")  # fmt: skip
        precip_alpha = total_alpha(1.0e5, self.precipitation, self.intensity)
        fog_alpha = total_alpha(self.visual_range_m, "dry", 0.0)
        return [self.component(self.c, precip_alpha / ref_alpha[self.precipitation], VOLUME_LABEL[self.precipitation]),
                self.component(fit.classes["fog"], fog_alpha / ref_alpha["fog"], Label.FOG)]  # fmt: skip

    def component(self, c: ClassParams, rate_scale: float, label: int) -> AirComponent:
        """The near field and path drops of class parameters ``c`` at ``rate_scale`` x their fitted rates."""
        near_field = NearFieldModel(c.rate_per_beam, c.cover_share, c.cover_scale_m, c.amplitude_median,
                                    c.amplitude_sigma_ln, volume_range_m=(0.5, self.p.near_field_max_m),
                                    cover_amp_scale_m=c.cover_amp_scale_m)  # fmt: skip
        return AirComponent(c, rate_scale, label, near_field)

    def step(self, t0_s: float, t1_s: float) -> None:
        """Stationary weather: nothing to advance."""

    def apply(self, batch: RayBatch, rng: np.random.Generator) -> RegionEffect:
        n, s = batch.shape
        scatterers, volume = None, None
        if self.p.air and self.physical is not None:
            scatterers, volume = self.physical.scatterers(batch, rng)
        elif self.p.air:
            parts = []
            for air in self.components:
                parts.append(sample_near_field(air.near_field, n, batch.weights, self.profile, rng, Label.COVER,
                                               air.label, air.rate_scale))  # fmt: skip
                parts.append(self._path_scatterers(batch, rng, air))
            scatterers = Scatterers.concatenate(parts)
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

    def _path_scatterers(self, batch: RayBatch, rng: np.random.Generator, air: AirComponent) -> Scatterers | None:
        """Drops between the near field and the scene hit of each beam (on the central sub-ray's hit range)."""
        c, p, label, rate_scale = air.c, self.p, air.label, air.rate_scale
        if c.path_rate_per_beam <= 0 and c.splash_rate_per_beam <= 0:
            return None
        w = np.asarray(batch.weights, dtype=np.float64)
        core = int(np.argmax(w))
        hit = batch.distance[:, core]
        far = np.where(np.isfinite(hit), hit - p.path_gap_m, -np.inf)
        # the near-field volume ends near_field_max_m ahead horizontally along the sensor's axis (the
        # paper's x, not the range); path drops keep path_gap_m from it, as from the hit
        # (a sensor without roll: the ray's lateral component is its sensor-frame y, the rest of its
        # horizontal part lies along the axis)
        horizontal_sq = batch.directions[:, core, 0] ** 2 + batch.directions[:, core, 1] ** 2
        along_axis = np.sqrt(np.maximum(horizontal_sq - batch.sensor_directions[:, core, 1] ** 2, 0.0))
        near = (p.near_field_max_m + p.path_gap_m) / np.maximum(along_axis, 0.1)
        eligible = far > near
        counts = rng.poisson(c.path_rate_per_beam * rate_scale, len(hit)) * eligible
        beam = np.repeat(np.arange(len(hit)), counts)
        r = rng.uniform(near[beam], far[beam])
        if c.splash_rate_per_beam > 0:
            # splash: drops bouncing off a surface hit from above (up-facing), in the last splash_depth_m
            # of the path before the gap
            up = eligible & (np.abs(batch.normal[:, core, 2]) > 0.9)
            n_splash = rng.poisson(c.splash_rate_per_beam * rate_scale, len(hit)) * up
            b_splash = np.repeat(np.arange(len(hit)), n_splash)
            r_splash = far[b_splash] - rng.uniform(0.0, p.splash_depth_m, len(b_splash))
            beam, r = np.concatenate([beam, b_splash]), np.concatenate([r, np.maximum(r_splash, near[b_splash])])
        m = len(beam)
        if m == 0:
            return None
        sigma_ln = c.amplitude_sigma_ln if c.path_amplitude_sigma_ln is None else c.path_amplitude_sigma_ln
        amp = c.path_amplitude_median * np.exp(sigma_ln * rng.standard_normal(m))
        det = self.profile.detection
        refl = reflectance_for_peak(amp * dark_level(det), det.power_constant, w[core], r)
        return Scatterers(beam=beam, subray=np.full(m, core), range_m=r, reflectance=refl, occlusion=np.zeros(m),
                          label=np.full(m, label, np.uint8), object_id=np.zeros(m, np.uint32),
                          bypass_overlap=np.zeros(m, bool))  # fmt: skip
