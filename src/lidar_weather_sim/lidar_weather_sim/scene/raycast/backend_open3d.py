"""Open3D ``RaycastingScene`` caster: the reference backend (Embree inside, on the simulator's ``workers.THREADS``).

The rays go to Open3D as one (N, 6) array shared with its tensor (no copy), written by a
kernel: numpy copies rows of three floats slowly. Another kernel turns the answer into
distances and triangle indices in one pass. Both run in chunks on the simulator's threads
(:mod:`lidar_weather_sim.core.workers`).
"""

from __future__ import annotations

import numba
import numpy as np

from lidar_weather_sim.core import workers

from .backend import CasterBase

_INVALID_ID = np.uint32(0xFFFFFFFF)  # open3d.t.geometry.RaycastingScene.INVALID_ID
CHUNK_RAYS = 65536  # rays per chunk of the copying kernels


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
        rays = np.empty((len(o), 6), np.float32)
        cuts = workers.bounds(len(o), CHUNK_RAYS)
        workers.run_chunks(lambda c: _interleave(o, d, rays, cuts[c], cuts[c + 1]), len(cuts) - 1)
        out = self._scene.cast_rays(self._o3c.Tensor.from_numpy(rays), nthreads=workers.THREADS)
        t_hit, prim = out["t_hit"].numpy(), out["primitive_ids"].numpy()
        dist = np.empty(len(o), np.float32)
        tri = np.empty(len(o), np.int64)
        workers.run_chunks(lambda c: _hits(t_hit, prim, _INVALID_ID, dist, tri, cuts[c], cuts[c + 1]), len(cuts) - 1)
        return dist, tri


@numba.njit(cache=True, nogil=True)
def _interleave(o, d, rays, lo, hi):
    for i in range(lo, hi):
        rays[i, 0], rays[i, 1], rays[i, 2] = o[i, 0], o[i, 1], o[i, 2]
        rays[i, 3], rays[i, 4], rays[i, 5] = d[i, 0], d[i, 1], d[i, 2]


@numba.njit(cache=True, nogil=True)
def _hits(t_hit, prim, invalid, dist, tri, lo, hi):
    """Rays lo..hi: distance (inf for a miss) and triangle index (-1 for a miss) of Open3D's answer."""
    for i in range(lo, hi):
        if prim[i] == invalid:
            dist[i] = np.inf
            tri[i] = -1
        else:
            dist[i] = t_hit[i]
            tri[i] = prim[i]
