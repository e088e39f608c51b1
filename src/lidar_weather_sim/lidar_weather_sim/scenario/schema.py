"""Scenario files (``config/scenarios/*.yaml``): map, ego, actors, sensor, weather, regions.

The weather block (:mod:`lidar_weather_sim.regions.weather`, the regions' input) follows
OpenSCENARIO's Weather concepts in snake_case with SI unit suffixes. Positions on roads use OpenDRIVE road ids, lane ids
(negative = right of the reference line) and s (m along the road).

A scenario without a ``map`` (``map: null`` or omitted) has an empty road
network: its scene is only its ``static_meshes`` (for example a mesh built from
a real recording). Such a mesh-only scenario has no roads to drive on, so it has
no ``ego``, and its actors drive their own ``trajectory``; its sensor poses come from outside (``gap`` /
``compare`` on a recording, the node's /tf or odometry mode), or from its
``trajectory`` (timed base_link poses in the map frame, e.g. the recorded poses
that ``lidar-weather-sim twin`` writes): only with a trajectory does
``lidar-weather-sim run`` accept it.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any, Literal

from pydantic import Field, model_validator

from lidar_weather_sim.core.config import ConfigError, ConfigModel, load_yaml
from lidar_weather_sim.core.points import Label
from lidar_weather_sim.regions.weather import Weather
from lidar_weather_sim.sensor.profile import ReturnMode
from lidar_weather_sim.sensor.response import SensorResponse

#: Physical bounds of scenario values: a value outside is refused naming its key.
MAX_SPEED_M_S = 150.0  # 540 km/h
MAX_TIME_S = 86_400.0  # a day of simulated time
MAX_S_M = 1.0e6  # along a road (m)
MAX_MOUNT_M = 20.0  # sensor from base_link (m)


class LaneChange(ConfigModel):
    at_s: float = Field(ge=0, le=MAX_TIME_S, description="Simulated time the lane change starts (s)")
    to_lane: int = Field(description="Target OpenDRIVE lane id")
    duration_s: float = Field(4.0, gt=0, le=60, description="Duration of the lateral move (s)")


class Size(ConfigModel):
    length_m: float = Field(4.7, gt=0, le=50, description="m (<= 50: a road train)")
    width_m: float = Field(1.85, gt=0, le=10, description="m")
    height_m: float = Field(1.45, gt=0, le=10, description="m")


class Mover(ConfigModel):
    road: str = Field("1", description="OpenDRIVE road id")
    lane: int = Field(description="OpenDRIVE lane id at the start")
    s_m: float = Field(0.0, ge=0, le=MAX_S_M, description="Start position along the road (m)")
    speed_m_s: float = Field(0.0, ge=0, le=MAX_SPEED_M_S, description="Speed along the lane (m/s; <= 150)")
    lane_changes: list[LaneChange] = Field(default_factory=list)
    size: Size = Field(default_factory=Size)


class TrajectoryPose(ConfigModel):
    """base_link in the map frame at simulated time ``t_s``: translation (m), unit quaternion x, y, z, w."""

    t_s: float = Field(ge=-MAX_TIME_S, le=MAX_TIME_S, description="Simulated time (s; before 0: e.g. an actor "
                       "driving before a recording starts, for a spray region's warm-up)")
    x_m: float = Field(ge=-MAX_S_M, le=MAX_S_M, description="m")
    y_m: float = Field(ge=-MAX_S_M, le=MAX_S_M, description="m")
    z_m: float = Field(ge=-MAX_S_M, le=MAX_S_M, description="m")
    qx: float = Field(0.0, ge=-1, le=1)
    qy: float = Field(0.0, ge=-1, le=1)
    qz: float = Field(0.0, ge=-1, le=1)
    qw: float = Field(1.0, ge=-1, le=1)


class Actor(Mover):
    """A vehicle or box on the roads: at ``lane`` / ``s_m`` (its footprint centre), or placed by the
    thesis' measure, ``lead_gap_m`` / ``lead_offset_y_m`` from the ego's sensor to the middle of its
    rear (:func:`lidar_weather_sim.scenario.player.place_lead`)."""

    id: int = Field(ge=100, le=2**31, description="Object id of its points (ids below 100 belong to the map)")
    lane: int | None = Field(None, description="OpenDRIVE lane id at the start (not with lead_gap_m)")
    s_m: float | None = Field(None, ge=0, le=MAX_S_M, description="Start position of its footprint centre along the road (m; "
                              "default 0; not with lead_gap_m)")
    type: Literal["vehicle", "box"] = "vehicle"
    label: Literal["vehicle", "obstacle"] = "vehicle"
    appear_s: float = Field(0.0, ge=0, le=MAX_TIME_S, description="Present from this simulated time on (s; an actor "
                            "with a trajectory that does not set it: from the trajectory's first time)")
    emits_spray: bool = Field(False, description="Wheels throw spray (spray region)")
    lead_gap_m: float | None = Field(
        None, gt=0, le=1000, description="Gap from the ego's sensor to the middle of this actor's rear, along the ego's "
        "x axis at time 0 (m; thesis paper 3: 17.5, Fig. 13: 15.5-32.6); sets lane and s_m")
    lead_offset_y_m: float | None = Field(
        None, ge=-100, le=100, description="With lead_gap_m: that point's offset to the left of the sensor (m; default the "
        "thesis' 3.7); the actor drives the lane whose centre is nearest")
    trajectory: list[TrajectoryPose] = Field(
        default_factory=list, description="Timed poses of the body (footprint centre on the ground, x forward) in the "
        "map frame, instead of a lane: how actors move in a mesh-only scenario (interpolated like the sensor's)")

    @model_validator(mode="before")
    @classmethod
    def _one_placement(cls, data: Any) -> Any:
        if not isinstance(data, dict):
            return data
        who = f"actor {data.get('id')}"
        if data.get("trajectory"):
            given = [k for k in ("lane", "s_m", "lead_gap_m", "lead_offset_y_m", "speed_m_s", "lane_changes")
                     if data.get(k) not in (None, [], 0.0, 0)]  # fmt: skip
            if given:
                raise ValueError(f"{who}: 'trajectory' moves the actor; remove {given}")
            return data
        if data.get("lead_gap_m") is None:
            if data.get("lead_offset_y_m") is not None:
                raise ValueError(f"{who}: 'lead_offset_y_m' needs 'lead_gap_m'")
            if data.get("lane") is None:
                raise ValueError(f"{who}: give 'lane' and 's_m', or 'lead_gap_m'")
            return {**data, "s_m": 0.0} if data.get("s_m") is None else data
        both = [k for k in ("lane", "s_m") if data.get(k) is not None]
        if both:
            raise ValueError(f"{who}: 'lead_gap_m' places the actor; remove {both}")
        return data

    @property
    def label_code(self) -> Label:
        return Label.VEHICLE if self.label == "vehicle" else Label.OBSTACLE


class Mount(ConfigModel):
    """Sensor pose in base_link (m, deg; REP-103, base_link on the ground below the rear axle)."""

    x_m: float = Field(3.7, ge=-MAX_MOUNT_M, le=MAX_MOUNT_M, description="m")
    y_m: float = Field(0.0, ge=-MAX_MOUNT_M, le=MAX_MOUNT_M, description="m")
    z_m: float = Field(0.5, ge=-MAX_MOUNT_M, le=MAX_MOUNT_M, description="m")
    roll_deg: float = Field(0.0, ge=-360, le=360, description="deg")
    pitch_deg: float = Field(0.0, ge=-360, le=360, description="deg")
    yaw_deg: float = Field(0.0, ge=-360, le=360, description="deg")


MAX_PART_M = 5.0  # a fixed part of the sensor lies within this of it (m)


class PartBox(ConfigModel):
    """An axis-aligned box in the sensor frame: centre (m) and size (m)."""

    x_m: float = Field(ge=-MAX_PART_M, le=MAX_PART_M, description="centre, m")
    y_m: float = Field(ge=-MAX_PART_M, le=MAX_PART_M, description="centre, m")
    z_m: float = Field(ge=-MAX_PART_M, le=MAX_PART_M, description="centre, m")
    length_m: float = Field(gt=0, le=2 * MAX_PART_M, description="along x, m")
    width_m: float = Field(gt=0, le=2 * MAX_PART_M, description="along y, m")
    height_m: float = Field(gt=0, le=2 * MAX_PART_M, description="along z, m")


class FixedPart(ConfigModel):
    """Structure fixed to the sensor (its housing's surroundings, a roof rack, the car's roof edge): cast in the
    sensor frame at every column, wherever the sensor is. Either ``mesh`` (a mesh file in the sensor frame, m;
    a surveyed PLY keeps its reflectivity per face, :mod:`lidar_weather_sim.scene.surveyed`) or ``box``."""

    mesh: str | None = Field(None, description="Mesh file (glTF/OBJ/PLY) in the sensor frame: a path, a name in "
                                               "maps/ or 'cache:<path>'")  # fmt: skip
    box: PartBox | None = Field(None, description="An axis-aligned box in the sensor frame")
    material: str = Field("car_paint", description="Material of the box, or of a mesh without reflectivity per face")

    @model_validator(mode="after")
    def _one_shape(self) -> "FixedPart":
        if (self.mesh is None) == (self.box is None):
            raise ValueError("a fixed part needs exactly one of 'mesh' (a file) and 'box'")
        return self


class SensorSetup(ConfigModel):
    profile: str = Field("scala4", description="Name in config/sensors or a path")
    return_mode: ReturnMode | None = Field(
        None, description="Return mode overriding the profile's detection.return_mode (null: the profile's)"
    )
    mount: Mount = Field(default_factory=Mount)
    response: SensorResponse = Field(
        default_factory=SensorResponse, description="How this unit's output departs from the sensor model after "
                                                     "detection (intensity response, range bias and noise, ray drop)")  # fmt: skip
    beam_origin_radial_m: float = Field(
        0.0, ge=0, le=1, description="Distance of the beams' origin from the spin axis, along the firing azimuth, "
                                     "in the frame the points are reported in (m; Ouster: lidar_origin_to_beam_"
                                     "origin_mm)")  # fmt: skip
    beam_origin_z_m: float = Field(
        0.0, ge=-1, le=1, description="Height of the beams' origin above the origin of the frame the points are "
                                      "reported in (m; e.g. Ouster's os_lidar above os_sensor, ~0.036)")  # fmt: skip
    elevation_offsets_deg: dict[int, float] = Field(
        default_factory=dict, description="Channel (0 = lowest) -> degrees its beam points, and is reported, above "
                                          "the profile's elevation table (a unit off its nominal calibration)")  # fmt: skip
    fixed_parts: list[FixedPart] = Field(
        default_factory=list, description="Structure fixed to the sensor, in the sensor frame (e.g. the ego part "
                                          "`lidar-weather-sim twin` finds): cast at every column, labelled static")  # fmt: skip


class Scenario(ConfigModel):
    name: str
    description: str = ""
    map: str | None = Field(None, description="OpenDRIVE file in maps/ (or a path); null: no roads, a mesh-only scene")
    static_meshes: list[str] = Field(
        default_factory=list,
        description="Extra meshes (glTF/OBJ/PLY): names in maps/, paths, or 'cache:<path>' in the workspace's .venv/cache",
    )
    duration_s: float = Field(10.0, gt=0, le=MAX_TIME_S, description="Length of `lidar-weather-sim run` (s)")
    seed: int = Field(0, ge=0, le=2**31 - 1, description="Seed of every random process (as --seed)")
    ego: Mover | None = Field(None, description="The sensor's vehicle; required with a map, absent without one")
    sensor: SensorSetup = Field(default_factory=SensorSetup)
    actors: list[Actor] = Field(default_factory=list)
    trajectory: list[TrajectoryPose] = Field(
        default_factory=list, description="Mesh-only scenarios: base_link poses in the map frame over time "
        "(interpolated: translation linear, rotation slerp; held before the first and after the last); makes "
        "`lidar-weather-sim run` possible without roads")
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
            if self.ego is not None:
                raise ValueError("a scenario without a 'map' has no roads: it cannot have an 'ego'")
            on_roads = [a.id for a in self.actors if not a.trajectory]
            if on_roads:
                raise ValueError(f"a scenario without a 'map' has no roads: actors {on_roads} need a 'trajectory'")
        elif self.trajectory:
            raise ValueError("'trajectory' is for scenarios without a 'map' (with a map the ego drives its lane)")
        for who, poses in [("'trajectory'", self.trajectory)] + [(f"actor {a.id}: 'trajectory'", a.trajectory)
                                                                    for a in self.actors]:  # fmt: skip
            times = [p.t_s for p in poses]
            if any(b <= a for a, b in zip(times, times[1:])):
                raise ValueError(f"{who} times t_s must increase strictly")
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
