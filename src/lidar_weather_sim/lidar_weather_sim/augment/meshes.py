"""Procedural meshes of the obstacle kinds (:mod:`~lidar_weather_sim.augment.kinds`), no files.

Body frame (REP-103, m): x along the obstacle's length (a car's or a pedestrian's front), y to its
left, z up; origin at the centre of the footprint on the ground (z = 0 is the road), as the scene's
actor meshes (:mod:`lidar_weather_sim.scene.scene`). Every mesh's bounding box is length x width x
height (a tread strip's by its thickness' slant, under 1 cm more in length):

- ``box``: the paper's closed box (:func:`~lidar_weather_sim.scene.mesh.box_mesh`);
- ``vehicle``: the simulator's own passenger car (:class:`~lidar_weather_sim.scene.scene.VehicleShape`:
  body, cabin with glass, wheels, number plates), its paint the drawn reflectivity, glass, tyres and
  plates from ``config/materials.yaml``;
- ``pedestrian``: legs, torso, arms and head as boxes, facing +x;
- ``debris``: a strip of tyre tread (:data:`TREAD_THICKNESS_M` thick) bent into a parabolic arch
  whose top is ``height`` above the road, lying along x.

Every material of an obstacle carries label ``OBSTACLE``.
"""

from __future__ import annotations

import math

import numpy as np

from lidar_weather_sim.core.points import Label
from lidar_weather_sim.augment.boxes import Box
from lidar_weather_sim.scene.materials import MaterialTable
from lidar_weather_sim.scene.mesh import Material, TriangleMesh, box_mesh
from lidar_weather_sim.scene.scene import VehicleShape

#: Thickness (m) of a tyre-tread strip (truck retread: 15-25 mm of rubber); thinner for a flatter strip.
TREAD_THICKNESS_M = 0.02
_TREAD_SEGMENTS = 8
# pedestrian parts as fractions of (depth, width, height): size, centre y, bottom z
_PEDESTRIAN = (
    ((0.6, 0.30, 0.47), (-0.17, 0.0)),  # right leg
    ((0.6, 0.30, 0.47), (0.17, 0.0)),  # left leg
    ((1.0, 0.64, 0.34), (0.0, 0.47)),  # torso
    ((0.6, 0.18, 0.36), (-0.41, 0.45)),  # right arm
    ((0.6, 0.18, 0.36), (0.41, 0.45)),  # left arm
    ((0.7, 0.36, 0.19), (0.0, 0.81)),  # head and neck
)


def _moved(mesh: TriangleMesh, x: float, y: float, z: float, pitch: float = 0.0) -> TriangleMesh:
    """``mesh`` turned by ``pitch`` (rad, about y: +x towards -z) then moved by (x, y, z) m."""
    c, s = math.cos(pitch), math.sin(pitch)
    m = np.array([[c, 0.0, s, x], [0.0, 1.0, 0.0, y], [-s, 0.0, c, z], [0.0, 0.0, 0.0, 1.0]])
    return mesh.transformed(m)


def pedestrian_mesh(depth: float, width: float, height: float, material: int, object_id: int) -> TriangleMesh:
    """Standing pedestrian facing +x (m): bounding box depth (x) x width (y, arms included) x height."""
    parts = []
    for (fx, fy, fz), (cy, bz) in _PEDESTRIAN:
        part = box_mesh((fx * depth, fy * width, fz * height), material, object_id)
        parts.append(_moved(part, 0.0, cy * width, bz * height))
    return TriangleMesh.concatenate(parts)


def debris_mesh(length: float, width: float, height: float, material: int, object_id: int) -> TriangleMesh:
    """Tyre-tread strip (m) lying along x: ``_TREAD_SEGMENTS`` flat pieces on the parabola
    z = (height - t)(1 - (2x / length)^2), t = min(:data:`TREAD_THICKNESS_M`, height / 2) thick."""
    t = min(TREAD_THICKNESS_M, 0.5 * height)
    xs = np.linspace(-0.5 * length, 0.5 * length, _TREAD_SEGMENTS + 1)
    zs = (height - t) * (1.0 - (2.0 * xs / length) ** 2)
    parts = []
    for xa, xb, za, zb in zip(xs[:-1], xs[1:], zs[:-1], zs[1:]):
        piece = box_mesh((math.hypot(xb - xa, zb - za), width, t), material, object_id)
        parts.append(_moved(piece, 0.5 * (xa + xb), 0.0, 0.5 * (za + zb), -math.atan2(zb - za, xb - xa)))
    return TriangleMesh.concatenate(parts)


def vehicle_parts(reflectivity: float) -> MaterialTable:
    """A car's materials (car_paint, glass, tyre, license_plate) with the paint's albedo
    ``reflectivity``, the others' from ``config/materials.yaml``; every one labelled ``OBSTACLE``."""
    default = MaterialTable.default()
    out = []
    for name in ("car_paint", "glass", "tyre", "license_plate"):
        m = default.materials[default.index(name)]
        refl = reflectivity if name == "car_paint" else m.reflectivity
        out.append(Material(name, refl, m.retro_share, Label.OBSTACLE))
    return MaterialTable(out)


def obstacle_mesh(box: Box) -> tuple[TriangleMesh, list[Material]]:
    """``box``'s mesh in its body frame (materials indexing the returned list, named
    ``obstacle_<id>[_<part>]``, all labelled ``OBSTACLE``) and that list."""
    name = f"obstacle_{box.object_id}"
    if box.kind == "vehicle":
        parts = vehicle_parts(box.reflectivity)
        mesh = VehicleShape(box.length, box.width, box.height).mesh(box.object_id, parts)
        return mesh, [Material(f"{name}_{m.name}", m.reflectivity, m.retro_share, m.label) for m in parts.materials]
    material = [Material(name, box.reflectivity, 0.0, Label.OBSTACLE)]
    if box.kind == "box":
        return box_mesh((box.length, box.width, box.height), 0, box.object_id), material
    if box.kind == "pedestrian":
        return pedestrian_mesh(box.length, box.width, box.height, 0, box.object_id), material
    if box.kind == "debris":
        return debris_mesh(box.length, box.width, box.height, 0, box.object_id), material
    raise ValueError(f"unknown obstacle kind '{box.kind}'")
