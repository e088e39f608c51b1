"""Mesh ray casters: the backend interface and the registry of implementations.

A caster is built once from one triangle mesh and then answers batches of rays
in that mesh's frame. Every backend converts the float64 vertices to float32
the same way (``np.float32`` rounding of the float64 values) and tests rays
with ``tnear = 0`` and no far limit, so the backends return the same hits.

Default order, fastest first (``benchmarks/performance/raycast_backends.py``: 128x2048x3
lidar rays, 2 cores): ``mitsuba`` (Mitsuba 3 LLVM variant, coherent Embree ray
streams on all cores, 50-110 Mrays/s), ``open3d`` (RaycastingScene, Embree on
all cores, 14-21 Mrays/s; the reference, always available), ``embree``
(embreex, one thread, ~14.5 Mrays/s). ``LWS_RAYCAST_BACKEND`` overrides the
default of ``default_backend()``.
"""

from __future__ import annotations

import importlib
import os
from abc import ABC, abstractmethod
from functools import cache
from typing import Protocol, runtime_checkable

import numpy as np

from lidar_weather_sim.core.registry import Registry

#: The backends, fastest first (the order ``default_backend()`` tries them in).
DEFAULT_ORDER: tuple[str, ...] = ("mitsuba", "open3d", "embree")


@runtime_checkable
class MeshCaster(Protocol):
    """Nearest-hit ray caster over one static triangle mesh (metres, the mesh's frame)."""

    def cast(self, origins: np.ndarray, directions: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Rays (N, 3) float32 origins (m) and unit directions, in the mesh's frame.

        Returns distance (N,) float32 m along the ray (``np.inf`` for a miss) and
        triangle_index (N,) int64 into the mesh's triangles (-1 for a miss). Both
        are the caller's to modify.
        """
        ...


class BackendUnavailableError(ValueError):
    """Unknown backend name, or a backend whose library cannot be used here."""


#: Backend name -> its module (``check()`` and ``Caster``), imported on first use.
BACKENDS: Registry[str] = Registry("ray casting backend", error=BackendUnavailableError)
for backend_name in DEFAULT_ORDER:
    BACKENDS.register(backend_name, f"{__package__}.backend_{backend_name}")
del backend_name


class CasterBase(ABC):
    """Shared input handling: subclasses implement ``_cast`` on float32 (N, 3) arrays, N > 0, in
    C or column-major order (the transpose of a C (3, N) array, as the simulator's rays)."""

    def cast(self, origins: np.ndarray, directions: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        o = np.asarray(origins, dtype=np.float32).reshape(-1, 3)
        d = np.asarray(directions, dtype=np.float32).reshape(-1, 3)
        if len(o) != len(d):
            raise ValueError(f"{len(o)} origins but {len(d)} directions")
        if not len(o):
            return np.zeros(0, np.float32), np.zeros(0, np.int64)
        return self._cast(o, d)

    @abstractmethod
    def _cast(self, o: np.ndarray, d: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Distances (N,) float32 (inf = miss) and triangle indices (N,) int64 (-1 = miss)."""


class _EmptyCaster(CasterBase):
    """A mesh without triangles: every ray misses (no backend handles empty scenes uniformly)."""

    def _cast(self, o, d):
        return np.full(len(o), np.inf, np.float32), np.full(len(o), -1, np.int64)


@cache
def _probe(name: str) -> str | None:
    """None if backend ``name`` works here, else the reason it does not."""
    try:
        importlib.import_module(BACKENDS.get(name)).check()
    except Exception as exc:  # noqa: BLE001 - any failure means "not usable", reported verbatim
        return f"{type(exc).__name__}: {exc}"
    return None


def available_backends() -> list[str]:
    """Names of the backends usable here, fastest first (``DEFAULT_ORDER``)."""
    return [n for n in DEFAULT_ORDER if _probe(n) is None]


def unavailable_backends() -> dict[str, str]:
    """Backend name -> why it cannot be used here."""
    return {n: reason for n in DEFAULT_ORDER if (reason := _probe(n)) is not None}


def fastest_available() -> str:
    """The first usable backend of ``DEFAULT_ORDER``."""
    names = available_backends()
    if not names:
        raise BackendUnavailableError(f"no ray casting backend is usable: {unavailable_backends()}")
    return names[0]


def default_backend() -> str:
    """``$LWS_RAYCAST_BACKEND`` if set, else ``fastest_available()``."""
    return os.environ.get("LWS_RAYCAST_BACKEND") or fastest_available()


def make_caster(name: str, vertices: np.ndarray, triangles: np.ndarray) -> MeshCaster:
    """Build backend ``name``'s caster for vertices (V, 3) m and triangles (T, 3) vertex indices."""
    module = BACKENDS.get(name)
    if (reason := _probe(name)) is not None:
        raise BackendUnavailableError(
            f"ray casting backend '{name}' is unavailable ({reason}); available backends: {', '.join(available_backends())}"
        )
    v = np.ascontiguousarray(np.asarray(vertices, dtype=np.float64).reshape(-1, 3).astype(np.float32))
    t = np.ascontiguousarray(np.asarray(triangles).reshape(-1, 3), dtype=np.uint32)
    if len(t) and int(t.max()) >= len(v):
        raise ValueError(f"triangle indices outside 0..{len(v) - 1}")
    if not len(t):
        return _EmptyCaster()
    return importlib.import_module(module).Caster(v, t)
