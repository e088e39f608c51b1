"""Ray casting against triangle meshes, without ROS.

``backend`` defines the per-mesh ``MeshCaster`` interface and the registry of
implementations (``open3d``, ``embree``, ``mitsuba``); ``scene_caster`` casts
against a static map mesh plus rigidly moving actors without rebuilding.
"""

from .backend import (
    DEFAULT_ORDER,
    BackendUnavailableError,
    MeshCaster,
    available_backends,
    default_backend,
    fastest_available,
    make_caster,
    unavailable_backends,
)
from .scene_caster import Hits, SceneCaster, TriangleTables

__all__ = [
    "DEFAULT_ORDER",
    "BackendUnavailableError",
    "Hits",
    "MeshCaster",
    "SceneCaster",
    "TriangleTables",
    "available_backends",
    "default_backend",
    "fastest_available",
    "make_caster",
    "unavailable_backends",
]
