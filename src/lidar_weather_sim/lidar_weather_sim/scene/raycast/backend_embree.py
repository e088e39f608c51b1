"""Embree 4 through ``embreex`` (PyPI): single-threaded ``rtcIntersect1`` over the rays."""

from __future__ import annotations

import numpy as np

from .backend import CasterBase


def check() -> None:
    from embreex import mesh_construction, rtcore_scene  # noqa: F401


class Caster(CasterBase):
    """Vertices (V, 3) float32 m, triangles (T, 3) uint32; rays in the same frame."""

    def __init__(self, vertices: np.ndarray, triangles: np.ndarray) -> None:
        from embreex import mesh_construction, rtcore_scene

        self._scene = rtcore_scene.EmbreeScene()
        mesh_construction.TriangleMesh(self._scene, vertices, triangles.astype(np.int32))

    def _cast(self, o, d):
        out = self._scene.run(np.ascontiguousarray(o), np.ascontiguousarray(d), output=1)
        hit = out["geomID"] >= 0
        dist = np.where(hit, out["tfar"], np.float32(np.inf)).astype(np.float32, copy=False)
        tri = np.where(hit, out["primID"], -1).astype(np.int64)
        return dist, tri
