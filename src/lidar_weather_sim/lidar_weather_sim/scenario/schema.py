"""Scenario files (``config/scenarios/*.yaml``): map, ego, actors, sensor, weather, regions.

The weather block follows OpenSCENARIO's Weather concepts in snake_case with SI
unit suffixes (``fog.visual_range_m``, ``precipitation.intensity_mm_h``,
``sun.irradiance_w_m2`` - the thesis' unit, not OpenSCENARIO's lux,
``wind.speed_m_s``). Positions on roads use OpenDRIVE road ids, lane ids
(negative = right of the reference line) and s (m along the road).

A scenario without a ``map`` (``map: null`` or omitted) has an empty road
network: its scene is only its ``static_meshes`` (for example a mesh built from
a real recording). Such a mesh-only scenario has no roads to drive on, so it has
no ``ego`` and no ``actors``; its sensor poses must come from outside (``gap`` /
``compare`` on a recording, the node's /tf or odometry mode), and
``lidar-weather-sim run`` refuses it.
"""

from __future__ import annotations

from pathlib import Path
from typing import Literal

from pydantic import Field, model_validator

from lidar_weather_sim.core.config import ConfigError, ConfigModel, load_yaml
from lidar_weather_sim.core.points import Label


class LaneChange(ConfigModel):
    at_s: float = Field(ge=0, description="Simulated time the lane change starts (s)")
    to_lane: int = Field(description="Target OpenDRIVE lane id")
    duration_s: float = Field(4.0, gt=0, description="Duration of the lateral move (s)")


class Size(ConfigModel):
    length_m: float = Field(4.7, gt=0)
    width_m: float = Field(1.85, gt=0)
    height_m: float = Field(1.45, gt=0)


class Mover(ConfigModel):
    road: str = Field("1", description="OpenDRIVE road id")
    lane: int = Field(description="OpenDRIVE lane id at the start")
    s_m: float = Field(0.0, ge=0, description="Start position along the road (m)")
    speed_m_s: float = Field(0.0, ge=0, description="Speed along the lane (m/s)")
    lane_changes: list[LaneChange] = Field(default_factory=list)
    size: Size = Field(default_factory=Size)


class Actor(Mover):
    id: int = Field(ge=100, le=2**31, description="Object id of its points (ids below 100 belong to the map)")
    type: Literal["vehicle", "box"] = "vehicle"
    label: Literal["vehicle", "obstacle"] = "vehicle"
    appear_s: float = Field(0.0, ge=0, description="Present from this simulated time on (s)")
    emits_spray: bool = Field(False, description="Wheels throw spray (spray region)")

    @property
    def label_code(self) -> Label:
        return Label.VEHICLE if self.label == "vehicle" else Label.OBSTACLE


class Mount(ConfigModel):
    """Sensor pose in base_link (m, deg; REP-103, base_link on the ground below the rear axle)."""

    x_m: float = 3.7
    y_m: float = 0.0
    z_m: float = 0.5
    roll_deg: float = 0.0
    pitch_deg: float = 0.0
    yaw_deg: float = 0.0


class SensorSetup(ConfigModel):
    profile: str = Field("scala4", description="Name in config/sensors or a path")
    mount: Mount = Field(default_factory=Mount)


class Fog(ConfigModel):
    visual_range_m: float = Field(100000.0, gt=0, description="Meteorological visual range (m)")


class Precipitation(ConfigModel):
    type: Literal["dry", "rain", "snow"] = "dry"
    intensity_mm_h: float = Field(0.0, ge=0, le=300, description="Precipitation rate (mm/h)")

    @model_validator(mode="after")
    def _dry(self) -> "Precipitation":
        if self.type == "dry" and self.intensity_mm_h > 0:
            raise ValueError(f"precipitation type 'dry' with intensity_mm_h {self.intensity_mm_h} > 0")
        return self


class Sun(ConfigModel):
    irradiance_w_m2: float = Field(0.0, ge=0, le=1400, description="Global solar irradiance (W/m^2), 0 at night")
    azimuth_deg: float = Field(180.0, ge=0, le=360, description="Sun azimuth from north, clockwise (deg)")
    elevation_deg: float = Field(30.0, ge=-90, le=90, description="Sun elevation above the horizon (deg)")


class Wind(ConfigModel):
    speed_m_s: float = Field(0.0, ge=0, description="Wind speed (m/s)")
    direction_deg: float = Field(0.0, ge=0, le=360, description="Direction the wind blows from, from north (deg)")


class Weather(ConfigModel):
    fog: Fog = Field(default_factory=Fog)
    precipitation: Precipitation = Field(default_factory=Precipitation)
    sun: Sun = Field(default_factory=Sun)
    wind: Wind = Field(default_factory=Wind)


class Scenario(ConfigModel):
    name: str
    description: str = ""
    map: str | None = Field(None, description="OpenDRIVE file in maps/ (or a path); null: no roads, a mesh-only scene")
    static_meshes: list[str] = Field(
        default_factory=list,
        description="Extra meshes (glTF/OBJ/PLY): names in maps/, paths, or 'cache:<path>' in the workspace's .venv/cache",
    )
    duration_s: float = Field(10.0, gt=0, description="Length of `lidar-weather-sim run` (s)")
    seed: int = 0
    ego: Mover | None = Field(None, description="The sensor's vehicle; required with a map, absent without one")
    sensor: SensorSetup = Field(default_factory=SensorSetup)
    actors: list[Actor] = Field(default_factory=list)
    weather: Weather = Field(default_factory=Weather)
    regions: list[str] = Field(default_factory=list, description="Region plugins, in order")
    region_params: dict[str, dict] = Field(default_factory=dict, description="Parameters per region plugin")

    @model_validator(mode="after")
    def _consistent(self) -> "Scenario":
        if len(set(self.regions)) != len(self.regions):
            raise ValueError(f"'regions' {self.regions}: a region listed twice would apply its effect twice")
        ids = [a.id for a in self.actors]
        if len(ids) != len(set(ids)):
            raise ValueError(f"actor ids must be unique, got {ids}")
        unused = sorted(set(self.region_params) - set(self.regions))
        if unused:
            raise ValueError(f"region_params for regions not in 'regions': {unused}")
        if self.map is not None and self.ego is None:
            raise ValueError("'ego' is required with a 'map' (only a mesh-only scenario, map: null, has no ego)")
        if self.map is None:
            if not self.static_meshes:
                raise ValueError("a scenario without a 'map' needs 'static_meshes' (its scene would be empty)")
            if self.ego is not None or self.actors:
                raise ValueError("a scenario without a 'map' has no roads: it cannot have an 'ego' or 'actors'")
        return self

    @property
    def mesh_only(self) -> bool:
        """No road network and no ego: sensor poses must come from a recording or /tf."""
        return self.map is None


#: Entry-point group of packages that ship scenarios: each entry is a callable returning a directory of
#: ``<name>.yaml`` files (weather_filter's training and evaluation runs live in its own package).
SCENARIO_DIRS_GROUP = "lidar_weather_sim.scenario_dirs"


def scenarios_dir() -> Path:
    """The workspace's ``config/scenarios``."""
    from lidar_weather_sim.core.paths import config_dir

    return config_dir() / "scenarios"


def scenario_dirs() -> list[Path]:
    """Where scenario names are looked up: ``config/scenarios`` first, then each registered package's directory."""
    from importlib.metadata import entry_points

    return [scenarios_dir(), *(ep.load()() for ep in sorted(entry_points(group=SCENARIO_DIRS_GROUP), key=lambda e: e.name))]


def known_scenarios() -> dict[str, Path]:
    """Every scenario name -> its file (a name in ``config/scenarios`` wins over a package's)."""
    known: dict[str, Path] = {}
    for directory in reversed(scenario_dirs()):
        known.update({p.stem: p for p in directory.glob("*.yaml")})
    return dict(sorted(known.items()))


def scenario_path(name_or_path: str | Path) -> Path:
    """The file of a scenario name, or ``name_or_path`` itself when it ends in .yaml/.yml; ConfigError lists
    the known names for an unknown one."""
    path = Path(name_or_path)
    if path.suffix in (".yaml", ".yml"):
        return path
    known = known_scenarios()
    if str(name_or_path) not in known:
        raise ConfigError(f"unknown scenario '{name_or_path}' (known: {', '.join(known)})")
    return known[str(name_or_path)]


def load_scenario(name_or_path: str | Path) -> Scenario:
    """A scenario by name (:func:`scenario_path`) or by path."""
    return load_yaml(scenario_path(name_or_path), Scenario)
