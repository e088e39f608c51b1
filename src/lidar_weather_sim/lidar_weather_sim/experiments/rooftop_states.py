"""Scene and sensor states of the physical-atmosphere rooftop runs (paper 2).

Paper 2 reports weather classes, not the weather: no visual range, no rain or snow rate, no state
of the window or of the street. With the physical atmosphere (drop-size distributions, Mie, the
profile's optics) these states are the rooftop reproduction's free parameters, fitted by
``benchmarks/calibration/fit_physical_rooftop.py`` into ``config/rooftop_physical.yaml``:

- per weather class, the scene: the fog's visual range (m); the rain or snow rate (mm/h, snow as
  water equivalent); the street's water film (mm) or snow cover (m);
- per weather class, the sensor's window: its one-way transmission (a film of water or snow) and
  its near-field ghosts per beam (multiple reflection in the window and housing, thesis lines 329
  and 498; clean in clear weather, wet or snowy otherwise: "the presence of water or dirt on the
  cover caused by the different weather types also influences the form of the distribution", line
  1626);
- shared by the classes, the window ghosts' range scale (m), median peak over the dark threshold,
  log-sd of that peak, and their relative rate per channel (the window's reflections need not reach
  every layer's receiver alike: paper 2's street beams carry ~2x the near-field echoes of an average
  beam, Table 4 n_e2 against Table 3 n_total).

The receiver's day mode (its automatic gain control, thesis line 1536: one state for every sunlit
frame) is the profile's sun noise at ``day_irradiance_w_m2``, fitted on the sunlit rows or on Table 2's
day row alone. Not free: the asphalt's 905 nm backscatter (``street_gain``, fitted once on the clear-night street)
and the geometry, both in ``config/rooftop.yaml``.
"""

from __future__ import annotations

from pathlib import Path
from typing import Literal, get_args

from pydantic import Field, model_validator

from lidar_weather_sim.core.config import ConfigModel, load_yaml
from lidar_weather_sim.regions.weather import Weather

WeatherClass = Literal["clear", "rain", "fog", "snow"]
#: The weather classes of paper 2, in the order of its tables.
WEATHER_CLASSES: tuple[str, ...] = get_args(WeatherClass)
CLEAR_AIR_VISUAL_RANGE_M = 1.0e5


class WindowGhosts(ConfigModel):
    """The window's near-field returns (the cover region's ghosts), shared by the weather classes."""

    scale_m: float = Field(gt=0, description="Exponential range scale of the ghosts (m)")
    amplitude: float = Field(gt=0, description="Median ghost peak over the dark threshold")
    sigma_ln: float = Field(ge=0, description="Log-sd of the ghost peak")
    channel_weights: list[float] | None = Field(None, description="Relative ghost rate of each channel (channel 0 = "
                                                "lowest); none = 1 for every channel")  # fmt: skip


class ClassState(ConfigModel):
    """One weather class's scene and window state."""

    window_ghosts_per_beam: float = Field(ge=0, le=10, description="Window ghosts per beam and frame")
    window_transmission: float = Field(1.0, gt=0, le=1, description="One-way transmission of the window (a uniform "
                                                                     "film of water or snow; 1 = clean)")  # fmt: skip
    fog_visual_range_m: float = Field(CLEAR_AIR_VISUAL_RANGE_M, gt=0, le=1.0e6,
                                      description="Fog visual range (m); 1e5 = clear air")  # fmt: skip
    precipitation_mm_h: float = Field(0.0, ge=0, le=300, description="Rain (rain class) or snow water-equivalent "
                                                                      "(snow class) rate (mm/h)")  # fmt: skip
    road_water_film_mm: float = Field(0.0, ge=0, le=10, description="Water film on the street (mm)")
    road_snow_depth_m: float = Field(0.0, ge=0, le=1, description="Snow cover on the street (m)")


class RooftopStates(ConfigModel):
    source: str = ""
    day_irradiance_w_m2: float = Field(343.0, ge=0, le=1400, description="Irradiance of every 'with sun' row "
                                       "(W/m^2): the receiver's automatic gain control has one day mode (thesis line "
                                       "1536), here the profile's sun noise at this irradiance; 343 = the clear days' "
                                       "mean (Fig. A3)")  # fmt: skip
    window_ghosts: WindowGhosts
    classes: dict[WeatherClass, ClassState]
    fit_report: dict = Field(default_factory=dict)

    def weather(self, weather_class: str) -> Weather:
        """The class's weather block (fog, precipitation, road) for the physical atmosphere."""
        s = self.state(weather_class)
        kind = weather_class if weather_class in ("rain", "snow") and s.precipitation_mm_h > 0 else "dry"
        return Weather.model_validate({
            "fog": {"visual_range_m": s.fog_visual_range_m},
            "precipitation": {"type": kind, "intensity_mm_h": s.precipitation_mm_h if kind != "dry" else 0.0},
            "road": {"water_film_mm": s.road_water_film_mm, "snow_depth_m": s.road_snow_depth_m},
        })  # fmt: skip

    def cover_params(self, weather_class: str) -> dict:
        """The cover region's parameters that put the class's window ghosts into a run."""
        g, s = self.window_ghosts, self.state(weather_class)
        film = {"mean_transmission": s.window_transmission} if s.window_transmission < 1 else {}
        return {**film, "near_field_ghost_per_beam": s.window_ghosts_per_beam,
                "near_field_scale_m": g.scale_m, "near_field_amplitude": g.amplitude, "near_field_sigma_ln": g.sigma_ln,
                "near_field_ghost_channel_weights": g.channel_weights}  # fmt: skip

    def state(self, weather_class: str) -> ClassState:
        return self.classes[weather_class]

    @model_validator(mode="after")
    def _every_class(self) -> "RooftopStates":
        missing = [w for w in WEATHER_CLASSES if w not in self.classes]
        if missing:
            raise ValueError(f"classes: no state for {', '.join(missing)} (the rooftop runs all four)")
        return self


def states_path() -> Path:
    from lidar_weather_sim.core.paths import config_dir

    return config_dir() / "rooftop_physical.yaml"


def load_states(path: str | Path | None = None) -> RooftopStates:
    return load_yaml(Path(path) if path else states_path(), RooftopStates)
