"""A scenario made runnable: its scene (roads, meshes, actor bodies), player and sensor profile."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

from lidar_weather_sim.core.config import ConfigError
from lidar_weather_sim.core.paths import maps_dir, resolve_data_path
from lidar_weather_sim.regions.base import REGISTRY, Region, RegionContext
from lidar_weather_sim.regions.topic_inputs import TopicInputs
from lidar_weather_sim.scenario.player import ScenarioPlayer
from lidar_weather_sim.scenario.schema import Scenario
from lidar_weather_sim.scene.materials import MaterialTable
from lidar_weather_sim.scene.mesh import box_mesh
from lidar_weather_sim.scene.opendrive import RoadNetwork
from lidar_weather_sim.scene.scene import Scene
from lidar_weather_sim.sensor.profile import SensorProfile, load_profile


def _map_path(name: str) -> Path:
    """A map or mesh of a scenario: ``cache:<path>``, a path, or a name in maps/."""
    return resolve_data_path(name, maps_dir())


@dataclass
class World:
    scenario: Scenario
    profile: SensorProfile
    scene: Scene
    player: ScenarioPlayer  # without an ego (mesh-only): actor_poses is {}, ego poses raise NoEgoError
    _casters: dict = field(default_factory=dict, repr=False, compare=False)  # backend -> the scene's caster

    def caster(self, backend: str | None = None):
        """The scene's ray caster on ``backend`` (None: the fastest available), built once and shared by
        every simulator of this world (re-simulations, restarts)."""
        if backend not in self._casters:
            self._casters[backend] = self.scene.caster(backend)
        return self._casters[backend]

    @classmethod
    def build(cls, scenario: Scenario, profile: str | SensorProfile | None = None,
              return_mode: str | None = None) -> "World":  # fmt: skip
        """Scene, player and profile of ``scenario`` (``profile`` overrides the scenario's sensor; ``return_mode``,
        else the scenario's ``sensor.return_mode``, the profile's ``detection.return_mode``)."""
        if not isinstance(profile, SensorProfile):
            profile = load_profile(profile or scenario.sensor.profile)
        return_mode = return_mode or scenario.sensor.return_mode
        if return_mode:
            profile = profile.with_return_mode(return_mode)
        if scenario.map is None:  # mesh-only: an empty road network, the scene is the static meshes
            scene = Scene(MaterialTable.default(), roads=RoadNetwork({}, "<no map>"))
        else:
            scene = Scene.from_xodr(_map_path(scenario.map))
        for mesh_name in scenario.static_meshes:
            scene.add_mesh_file(_map_path(mesh_name), mesh_name)
        for k, part in enumerate(scenario.sensor.fixed_parts):  # sensor frame, cast by the simulator
            name = f"sensor.fixed_parts[{k}]"
            try:
                if part.mesh is not None:
                    scene.add_mesh_file_to_sensor(_map_path(part.mesh), name, part.material)
                else:
                    b = part.box
                    box = box_mesh((b.length_m, b.width_m, b.height_m), scene.materials.index(part.material),
                                   scene.next_object_id(), z_bottom=b.z_m - 0.5 * b.height_m)  # fmt: skip
                    box.vertices[:, :2] += (b.x_m, b.y_m)
                    scene.add_sensor_part(box, name)
            except KeyError as exc:  # an unknown material
                raise ConfigError(f"{name}: {exc.args[0]}") from None
        for actor in scenario.actors:
            size = actor.size
            scene.add_body(actor.id, size.length_m, size.width_m, size.height_m, vehicle=actor.type == "vehicle",
                           name=f"actor {actor.id}", label=actor.label_code)  # fmt: skip
        return cls(scenario, profile, scene, ScenarioPlayer(scenario, scene.roads))

    def regions(self, names: list[str] | None = None, params: dict[str, dict] | None = None,
                pose_source=None, inputs=None, memo: dict | None = None) -> list[tuple[str, Region]]:  # fmt: skip
        """The scenario's region plugins (or ``names``), built from its region_params overlaid by ``params``;
        actor poses come from ``pose_source`` (default: the scenario player), topic points from ``inputs``
        (a :class:`~lidar_weather_sim.regions.topic_inputs.TopicInputs`, default a new one); ``memo``: what
        they share with earlier builds of the same actors and pose source (:class:`RegionContext`)."""
        context = RegionContext(self.profile, self.scenario.weather, self.scene.materials,
                                actors=self.scenario.actors, pose_source=pose_source or self.player,
                                inputs=TopicInputs() if inputs is None else inputs, memo=memo)  # fmt: skip
        names = self.scenario.regions if names is None else names
        repeated = sorted({n for n in names if list(names).count(n) > 1})
        if repeated:  # a region listed twice would apply its effect twice (twice the spray)
            raise ConfigError(f"regions {list(names)}: {', '.join(repeated)} listed more than once")
        merged = {**self.scenario.region_params}
        for name, values in (params or {}).items():
            merged[name] = {**merged.get(name, {}), **values}
        return [(name, REGISTRY.create(name, merged.get(name), context)) for name in names]
