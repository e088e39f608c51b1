"""Open3D ``RaycastingScene`` caster: the reference backend (Embree inside, multithreaded)."""

from __future__ import annotations

import numpy as np

from .backend import CasterBase

_INVALID_ID = np.uint32(0xFFFFFFFF)  # open3d.t.geometry.RaycastingScene.INVALID_ID


def check() -> None:
    import open3d  # noqa: F401


class Caster(CasterBase):
    """Vertices (V, 3) float32 m, triangles (T, 3) uint32; rays in the same frame."""

    def __init__(self, vertices: np.ndarray, triangles: np.ndarray) -> None:
        import open3d as o3d

        self._o3c = o3d.core
        self._scene = o3d.t.geometry.RaycastingScene()
        self._scene.add_triangles(o3d.core.Tensor(vertices), o3d.core.Tensor(triangles))

    def _cast(self, o, d):
        rays = self._o3c.Tensor(np.hstack([o, d]))
        out = self._scene.cast_rays(rays)
        prim = out["primitive_ids"].numpy()
        tri = np.where(prim == _INVALID_ID, -1, prim.astype(np.int64))
        dist = np.where(tri >= 0, out["t_hit"].numpy(), np.float32(np.inf)).astype(np.float32, copy=False)
        return dist, tri
