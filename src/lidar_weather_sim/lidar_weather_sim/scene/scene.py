"""The scene the virtual LiDAR sees: static triangles, the material table and actor meshes.

Frames (m, rad): static geometry is in the map frame (the OpenDRIVE inertial
frame: x east / along the first road, z up). Actor meshes are in their body frame
(REP-103: x forward, y left, z up) with the origin at the **centre of the
vehicle's footprint on the ground** (bounding-box centre in x/y, z = 0 at the
tyre contact plane); a 4x4 pose map<-body places them.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from lidar_weather_sim.core.points import Label
from lidar_weather_sim.scene.materials import MaterialTable
from lidar_weather_sim.scene.mesh import TriangleMesh, box_mesh
from lidar_weather_sim.scene.opendrive import RoadNetwork
from lidar_weather_sim.scene.surveyed import read_surveyed_faces, surveyed_materials

MESH_SUFFIXES = (".glb", ".gltf", ".obj", ".ply", ".stl", ".off")
# glTF is y-up with the asset's front along +z and +x to its left: (x, y, z)_ros = (z, x, y)_gltf.
GLTF_TO_ROS = np.array([[0.0, 0.0, 1.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])


class MeshLoadError(ValueError):
    """A mesh file that cannot be read; the message names the file."""


def load_static_mesh(path: str | Path, material: int, object_id: int, *, y_up: bool | None = None,
                     transform: np.ndarray | None = None) -> TriangleMesh:  # fmt: skip
    """Read a glTF/GLB/OBJ/PLY/STL/OFF file (trimesh) into one :class:`TriangleMesh`.

    Every triangle gets ``material`` (index into the scene's table) and
    ``object_id``. Scene-graph node transforms are applied. ``y_up`` (default:
    true for glTF/GLB as the glTF spec says, false otherwise) rotates y-up data
    into z-up (:data:`GLTF_TO_ROS`). ``transform`` (4x4, m) is applied last.
    """
    path = Path(path)
    suffix = path.suffix.lower()
    if suffix not in MESH_SUFFIXES:
        raise MeshLoadError(f"{path}: cannot read mesh: unsupported format '{suffix}' (use {', '.join(MESH_SUFFIXES)})")
    if not path.is_file():
        raise MeshLoadError(f"{path}: cannot read mesh: no such file")
    import trimesh  # lazy: only needed for mesh files

    try:
        loaded = trimesh.load(str(path), force="mesh", process=False)
    except Exception as exc:  # trimesh raises many types for corrupt files
        raise MeshLoadError(f"{path}: cannot read mesh: {type(exc).__name__}: {exc}") from None
    vertices = np.asarray(getattr(loaded, "vertices", np.zeros((0, 3))), dtype=np.float64)
    faces = np.asarray(getattr(loaded, "faces", np.zeros((0, 3))), dtype=np.int64)
    if not len(faces):
        raise MeshLoadError(f"{path}: cannot read mesh: no triangles")
    if suffix in (".glb", ".gltf") if y_up is None else y_up:
        vertices = vertices @ GLTF_TO_ROS.T
    mesh = TriangleMesh(vertices, faces, material, object_id)
    return mesh if transform is None else mesh.transformed(np.asarray(transform, dtype=np.float64))


@dataclass(frozen=True)
class VehicleShape:
    """Box-model passenger car (m). Origin: footprint centre on the ground, x forward, z up.

    Lower body (car paint) from ``ground_clearance`` to ``belt_height``; cabin
    (glass sides, front and rear; car-paint roof) from there to ``height``, set
    back by 5 % of the length; four wheel boxes (tyre) with their outer faces at
    +-width/2; EU number plates (520 x 110 mm, retro-reflective) front and rear
    at +-length/2. The overall bounding box is exactly length x width x height.
    """

    length: float = 4.6
    width: float = 1.85
    height: float = 1.45
    wheel_diameter: float = 0.66
    wheel_width: float = 0.24
    wheelbase: float | None = None  # default 0.6 * length
    ground_clearance: float = 0.15
    belt_height: float | None = None  # default 0.55 * height
    plate_size: tuple[float, float, float] = (0.01, 0.52, 0.11)  # thickness (x), width (y), height (z)
    plate_centre_z: tuple[float, float] = (0.40, 0.55)  # front, rear

    def __post_init__(self) -> None:
        belt = self.belt
        if not 0 < self.ground_clearance < belt < self.height:
            raise ValueError(f"vehicle: need 0 < ground_clearance < belt height < height, got "
                             f"{self.ground_clearance}, {belt}, {self.height}")  # fmt: skip
        if self.wheel_diameter > self.height or 2 * self.wheel_width >= self.width:
            raise ValueError("vehicle: wheels larger than the body")

    @property
    def belt(self) -> float:
        return 0.55 * self.height if self.belt_height is None else self.belt_height

    @property
    def wheel_centres(self) -> np.ndarray:
        """(4, 3) wheel centres in the body frame: front-left, front-right, rear-left, rear-right."""
        wb = 0.6 * self.length if self.wheelbase is None else self.wheelbase
        y = 0.5 * self.width - 0.5 * self.wheel_width
        r = 0.5 * self.wheel_diameter
        return np.array([[0.5 * wb, y, r], [0.5 * wb, -y, r], [-0.5 * wb, y, r], [-0.5 * wb, -y, r]])

    def mesh(self, object_id: int, materials: MaterialTable | None = None) -> TriangleMesh:
        """Closed boxes with per-triangle materials (car_paint, glass, tyre, license_plate)."""
        materials = MaterialTable.default() if materials is None else materials
        paint, glass, tyre, plate = (materials.index(n) for n in ("car_paint", "glass", "tyre", "license_plate"))
        inset, plate_t = 0.02, self.plate_size[0]
        parts = [box_mesh((self.length - 2 * plate_t, self.width - 2 * inset, self.belt - self.ground_clearance),
                          paint, object_id, z_bottom=self.ground_clearance)]  # fmt: skip
        cabin = box_mesh((0.5 * self.length, self.width - 2 * inset - 0.16, self.height - self.belt), glass, object_id,
                         z_bottom=self.belt)  # fmt: skip
        cabin.material[2:4] = paint  # roof (box_mesh faces: bottom, top, y-, y+, x-, x+)
        parts.append(cabin.transformed(_translation(-0.05 * self.length, 0.0, 0.0)))
        for centre in self.wheel_centres:
            wheel = box_mesh((self.wheel_diameter, self.wheel_width, self.wheel_diameter), tyre, object_id)
            parts.append(wheel.transformed(_translation(centre[0], centre[1], 0.0)))
        for sign, zc in ((1.0, self.plate_centre_z[0]), (-1.0, self.plate_centre_z[1])):
            half = 0.5 * self.plate_size[2]
            zc = float(np.clip(zc, self.ground_clearance + half, self.belt - half))
            box = box_mesh(self.plate_size, plate, object_id, z_bottom=zc - 0.5 * self.plate_size[2])
            parts.append(box.transformed(_translation(sign * 0.5 * (self.length - plate_t), 0.0, 0.0)))
        return TriangleMesh.concatenate(parts)


def vehicle_mesh(length: float, width: float, height: float, object_id: int,
                 materials: MaterialTable | None = None, **shape) -> TriangleMesh:  # fmt: skip
    """A car body as closed boxes (see :class:`VehicleShape`; ``shape`` sets its other fields)."""
    return VehicleShape(length, width, height, **shape).mesh(object_id, materials)


def _translation(x: float, y: float, z: float) -> np.ndarray:
    m = np.eye(4)
    m[:3, 3] = (x, y, z)
    return m


@dataclass
class Scene:
    """Static map-frame mesh + material table + actor meshes (body frame) keyed by object id."""

    materials: MaterialTable
    static: TriangleMesh = field(default_factory=TriangleMesh.empty)
    actors: dict[int, TriangleMesh] = field(default_factory=dict)
    object_names: dict[int, str] = field(default_factory=dict)
    roads: RoadNetwork | None = None
    actor_labels: dict[int, Label] = field(default_factory=dict)  # ground-truth label per actor id
    #: structure fixed to the sensor (sensor frame, m): cast at every column wherever the sensor is
    sensor_parts: TriangleMesh = field(default_factory=TriangleMesh.empty)
    #: per static triangle, the mean range (m) its surveyed reflectivity was measured from (NaN: not surveyed);
    #: None when no mesh carries one. A twin's reflectivity holds the recording's air: the simulator can undo it
    #: (:attr:`~lidar_weather_sim.sim.simulator.LidarSimulator.reflectivity_through_air`).
    recorded_range_m: np.ndarray | None = None

    @classmethod
    def from_xodr(cls, path: str | Path, materials: MaterialTable | None = None, *,
                  surface: str = "asphalt_dry") -> "Scene":  # fmt: skip
        """Scene whose static mesh is the road network of ``path`` (object ids from 1)."""
        materials = MaterialTable.default() if materials is None else materials
        roads = RoadNetwork.from_xodr(path)
        names: dict[int, str] = {}
        static = roads.to_mesh(materials, surface=surface, first_object_id=1, names=names)
        return cls(materials, static, {}, names, roads)

    def next_object_id(self) -> int:
        """Smallest object id above every id in use."""
        return max(self.object_names, default=0) + 1

    def _claim(self, mesh: TriangleMesh, name: str) -> None:
        ids = set(np.unique(mesh.object_id).tolist())
        taken = ids & set(self.object_names)
        if taken:
            users = [self.object_names[i] for i in sorted(taken)]
            raise ValueError(f"{name}: object ids {sorted(taken)} already used by {users}")
        if len(mesh.material) and int(mesh.material.max()) >= len(self.materials):
            raise ValueError(f"{name}: material index {int(mesh.material.max())} not in {self.materials}")
        self.object_names.update({i: name for i in ids})

    def add_static(self, mesh: TriangleMesh, name: str = "static mesh", recorded_range_m: np.ndarray | None = None) -> None:
        """Append map-frame triangles (their object ids must be new), with the range (T,) m their surveyed
        reflectivity was measured from if known (:attr:`recorded_range_m`)."""
        self._claim(mesh, name)
        if recorded_range_m is not None or self.recorded_range_m is not None:
            before = np.full(len(self.static.triangles), np.nan) if self.recorded_range_m is None else self.recorded_range_m
            added = np.full(len(mesh.triangles), np.nan) if recorded_range_m is None else recorded_range_m
            self.recorded_range_m = np.concatenate([before, np.asarray(added, dtype=np.float64)])
        self.static = TriangleMesh.concatenate([self.static, mesh])

    def add_mesh_file(self, path: str | Path, name: str) -> None:
        """Append the map-frame mesh file ``path`` (:func:`load_static_mesh`) as concrete under the next free object
        id; a digital twin's mesh (:mod:`~lidar_weather_sim.scene.surveyed`) keeps its surveyed reflectivity per
        triangle instead."""
        mesh = load_static_mesh(path, self.materials.index("concrete"), self.next_object_id())
        faces = read_surveyed_faces(path)
        recorded_range = None
        if faces is not None and len(faces[0]) == len(mesh.triangles):
            self.materials, mesh.material = surveyed_materials(self.materials, faces[0])
            recorded_range = faces[1]
        self.add_static(mesh, name, recorded_range)

    def add_mesh_file_to_sensor(self, path: str | Path, name: str, material: str = "car_paint") -> None:
        """Append the sensor-frame mesh file ``path`` as a fixed part of the sensor (:meth:`add_sensor_part`), of
        ``material`` unless it is a surveyed PLY with its reflectivity per triangle."""
        mesh = load_static_mesh(path, self.materials.index(material), self.next_object_id())
        faces = read_surveyed_faces(path)
        if faces is not None and len(faces[0]) == len(mesh.triangles):
            self.materials, mesh.material = surveyed_materials(self.materials, faces[0])
        self.add_sensor_part(mesh, name)

    def add_sensor_part(self, mesh: TriangleMesh, name: str = "fixed part", label: Label = Label.STATIC) -> None:
        """Append sensor-frame triangles fixed to the sensor (their object ids must be new); their returns get
        ``label``. The simulator casts them in the sensor frame at every column (the scene's caster does not hold
        them)."""
        self._claim(mesh, name)
        self.sensor_parts = TriangleMesh.concatenate([self.sensor_parts, mesh])
        for object_id in np.unique(mesh.object_id).tolist():
            self.actor_labels[int(object_id)] = Label(label)

    def add_body(self, object_id: int, length: float, width: float, height: float, *, vehicle: bool, name: str,
                 label: Label = Label.VEHICLE) -> None:  # fmt: skip
        """Register an actor body of that bounding box (m) under ``object_id``: a car (:func:`vehicle_mesh`) if
        ``vehicle``, else a car-paint box."""
        if vehicle:
            mesh = vehicle_mesh(length, width, height, object_id, self.materials)
        else:
            mesh = box_mesh((length, width, height), self.materials.index("car_paint"), object_id)
        self.add_actor(object_id, mesh, name, label)

    def add_actor(self, object_id: int, mesh: TriangleMesh, name: str = "actor", label: Label = Label.VEHICLE) -> None:
        """Register a body-frame actor mesh under ``object_id`` (its triangles get that id)."""
        mesh = TriangleMesh(mesh.vertices, mesh.triangles, mesh.material, object_id)
        self._claim(mesh, name)
        self.actors[object_id] = mesh
        self.actor_labels[object_id] = Label(label)

    def swap_material(self, old: str, new: str) -> None:
        """Replace material ``old`` by ``new`` on the static mesh (e.g. asphalt_dry -> asphalt_wet)."""
        m = self.static.material.copy()
        m[m == self.materials.index(old)] = self.materials.index(new)
        self.static = TriangleMesh(self.static.vertices, self.static.triangles, m, self.static.object_id)

    def caster(self, backend: str | None = None):
        """A ray caster over the scene as it is now: the static mesh and the actor meshes, instanced
        (:class:`~lidar_weather_sim.scene.raycast.scene_caster.SceneCaster`; ``backend`` None: the fastest)."""
        from lidar_weather_sim.scene.raycast.scene_caster import SceneCaster

        return SceneCaster(self.static, self.actors, backend=backend)

    def world_mesh(self, poses: dict[int, np.ndarray] | None = None) -> TriangleMesh:
        """Static mesh plus each actor in ``poses`` (object id -> 4x4 map<-body) in the map frame."""
        posed = [self.actors[i].transformed(np.asarray(p, dtype=np.float64)) for i, p in (poses or {}).items()]
        return TriangleMesh.concatenate([self.static, *posed])
