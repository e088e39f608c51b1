"""The weather a scenario sets and the regions read (``weather:`` in a scenario file).

Follows OpenSCENARIO's Weather concepts in snake_case with SI unit suffixes (``fog.visual_range_m``,
``precipitation.intensity_mm_h``, ``sun.irradiance_w_m2`` - the thesis' unit, not OpenSCENARIO's
lux, ``wind.speed_m_s``), plus the road surface (``road.water_film_mm``, ``road.texture_depth_mm``, eq. 1's drainage).
A region given no weather (``RegionContext.weather`` None) reads ``Weather()``: clear, dry, calm.
"""

from __future__ import annotations

from typing import ClassVar, Literal

from pydantic import Field, model_validator

from lidar_weather_sim.core.config import ConfigModel
from lidar_weather_sim.physics.road import water_film_mm


class Fog(ConfigModel):
    visual_range_m: float = Field(100000.0, gt=0, le=1.0e6, description="Meteorological visual range (m)")


class Precipitation(ConfigModel):
    type: Literal["dry", "rain", "snow"] = "dry"
    intensity_mm_h: float = Field(0.0, ge=0, le=300, description="Precipitation rate (mm/h)")

    @model_validator(mode="after")
    def _dry(self) -> "Precipitation":
        if self.type == "dry" and self.intensity_mm_h > 0:
            raise ValueError(f"precipitation type 'dry' with intensity_mm_h {self.intensity_mm_h} > 0")
        return self


class Sun(ConfigModel):
    """Sunlight acts through the receiver's noise floor only (thesis paper 2, Table 2), so its direction
    is not a key: it would be validated and never read."""

    moved_keys: ClassVar[dict[str, str]] = {
        key: "was removed: sunlight acts through weather.sun.irradiance_w_m2 only (the noise floor)"
        for key in ("azimuth_deg", "elevation_deg")
    }
    irradiance_w_m2: float = Field(0.0, ge=0, le=1400, description="Global solar irradiance (W/m^2), 0 at night")


class Wind(ConfigModel):
    speed_m_s: float = Field(0.0, ge=0, le=120, description="Wind speed (m/s; <= 120)")
    direction_deg: float = Field(0.0, ge=0, le=360, description="Direction the wind blows from, from north (deg)")


class Road(ConfigModel):
    """The road surface, one source for every region that reads it (atmosphere: wet-road reflectance
    and snow cover; spray: the film the tyres throw). A region's own ``road_water_film_mm`` / ``water_film_mm``
    parameter overrides the film for that region alone (the gap workflow's effects change one region
    each)."""

    water_film_mm: float | None = Field(
        None, ge=0, le=10, description="Water film depth h on the road (mm); null: eq. 1's film of the rain "
        "(0 when it does not rain)")
    texture_depth_mm: float = Field(1.5, gt=0, le=50, description="Mean texture depth T_s of the road (mm; thesis Table IV)")
    drainage_length_m: float = Field(11.25, gt=0, le=100, description="Drainage length L_s of eq. 1 (m; 3 lanes of "
                                     "3.75 m)")  # fmt: skip
    cross_slope: float = Field(0.025, gt=0, le=1, description="Cross slope S_s of eq. 1 (m/m)")
    snow_depth_m: float | None = Field(None, ge=0, le=1, description="Snow cover on up-facing surfaces (m); "
                                       "null: none")

    def film_mm(self, rain_mm_h: float) -> float:
        """The water film (mm): ``water_film_mm`` if given, else eq. 1's film of rain at ``rain_mm_h`` (mm/h) on
        this road (:func:`lidar_weather_sim.physics.road.water_film_mm`)."""
        if self.water_film_mm is not None:
            return self.water_film_mm
        return float(water_film_mm(rain_mm_h, self.texture_depth_mm, self.drainage_length_m, self.cross_slope))


class Weather(ConfigModel):
    fog: Fog = Field(default_factory=Fog)
    precipitation: Precipitation = Field(default_factory=Precipitation)
    sun: Sun = Field(default_factory=Sun)
    wind: Wind = Field(default_factory=Wind)
    road: Road = Field(default_factory=Road)
