"""Triangle meshes with a material and an object id per triangle, and the material table.

Coordinates are metres in the mesh's own frame (the map frame for the static
scene, the actor's body frame for actors: REP-103, x forward, z up).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from lidar_weather_sim.core.points import Label


@dataclass(frozen=True)
class Material:
    """Optical surface properties at 905 nm.

    ``reflectivity`` is the diffuse (Lambertian) albedo, 0-1. ``retro_share`` is
    the fraction of the returned power that is retro-reflected (lane markings,
    signs, number plates: returned towards the source whatever the incidence
    angle), 0-1. ``label`` is the ground-truth label of returns from it.
    """

    name: str
    reflectivity: float
    retro_share: float = 0.0
    label: Label = Label.STATIC

    def __post_init__(self) -> None:
        if not 0.0 <= self.reflectivity <= 1.0:
            raise ValueError(f"material '{self.name}': reflectivity {self.reflectivity} outside [0, 1]")
        if not 0.0 <= self.retro_share <= 1.0:
            raise ValueError(f"material '{self.name}': retro_share {self.retro_share} outside [0, 1]")


@dataclass
class TriangleMesh:
    """Vertices (V, 3) float64 m; triangles (T, 3) int32; per-triangle material index and object id."""

    vertices: np.ndarray
    triangles: np.ndarray
    material: np.ndarray
    object_id: np.ndarray
    _normals: np.ndarray | None = field(default=None, repr=False, compare=False)

    def __post_init__(self) -> None:
        self.vertices = np.ascontiguousarray(self.vertices, dtype=np.float64).reshape(-1, 3)
        self.triangles = np.ascontiguousarray(self.triangles, dtype=np.int32).reshape(-1, 3)
        n = len(self.triangles)
        self.material = np.broadcast_to(np.asarray(self.material, dtype=np.uint16), (n,)).copy()
        self.object_id = np.broadcast_to(np.asarray(self.object_id, dtype=np.uint32), (n,)).copy()
        if n and (self.triangles.min() < 0 or self.triangles.max() >= len(self.vertices)):
            raise ValueError(f"triangle indices outside 0..{len(self.vertices) - 1}")

    @classmethod
    def empty(cls) -> "TriangleMesh":
        return cls(np.zeros((0, 3)), np.zeros((0, 3), np.int32), np.zeros(0), np.zeros(0))

    @classmethod
    def concatenate(cls, meshes: list["TriangleMesh"]) -> "TriangleMesh":
        """One mesh holding all triangles of ``meshes`` (indices shifted)."""
        meshes = [m for m in meshes if len(m.triangles)]
        if not meshes:
            return cls.empty()
        offsets = np.cumsum([0] + [len(m.vertices) for m in meshes[:-1]])
        return cls(
            np.concatenate([m.vertices for m in meshes]),
            np.concatenate([m.triangles + o for m, o in zip(meshes, offsets)]),
            np.concatenate([m.material for m in meshes]),
            np.concatenate([m.object_id for m in meshes]),
        )

    @property
    def face_normals(self) -> np.ndarray:
        """Unit normals (T, 3), right-handed winding (counter-clockwise seen from the front)."""
        if self._normals is None:
            v = self.vertices[self.triangles]
            n = np.cross(v[:, 1] - v[:, 0], v[:, 2] - v[:, 0])
            norm = np.linalg.norm(n, axis=1, keepdims=True)
            self._normals = np.divide(n, norm, out=np.zeros_like(n), where=norm > 0)
        return self._normals

    def transformed(self, matrix: np.ndarray) -> "TriangleMesh":
        """Copy with vertices mapped by a 4x4 homogeneous transform."""
        v = self.vertices @ matrix[:3, :3].T + matrix[:3, 3]
        return TriangleMesh(v, self.triangles, self.material, self.object_id)

    def bounding_sphere(self) -> tuple[np.ndarray, float]:
        """Centre (3,) and radius (m) of a sphere enclosing every vertex (box-centred)."""
        if not len(self.vertices):
            return np.zeros(3), 0.0
        centre = 0.5 * (self.vertices.min(axis=0) + self.vertices.max(axis=0))
        return centre, float(np.linalg.norm(self.vertices - centre, axis=1).max())


def box_mesh(size_xyz: tuple[float, float, float], material: int, object_id: int, z_bottom: float = 0.0) -> TriangleMesh:
    """Axis-aligned box (m) centred on x/y = 0 standing on ``z_bottom``, outward normals."""
    lx, ly, lz = 0.5 * size_xyz[0], 0.5 * size_xyz[1], size_xyz[2]
    corners = np.array(
        [[x, y, z_bottom + z] for z in (0.0, lz) for y in (-ly, ly) for x in (-lx, lx)], dtype=np.float64
    )
    # corner index = 4*z + 2*y + x (bits: x, y, z)
    faces = [
        (0, 2, 3), (0, 3, 1),  # bottom (z-)
        (4, 5, 7), (4, 7, 6),  # top (z+)
        (0, 1, 5), (0, 5, 4),  # y-
        (2, 6, 7), (2, 7, 3),  # y+
        (0, 4, 6), (0, 6, 2),  # x-
        (1, 3, 7), (1, 7, 5),  # x+
    ]  # fmt: skip
    return TriangleMesh(corners, np.array(faces), material, object_id)
