"""Meshes with a measured reflectivity per triangle (a digital twin's, ``lidar-weather-sim twin``).

File: a binary little-endian PLY whose ``face`` element has, after ``vertex_indices`` (triangles only),
a ``float reflectivity`` property: the diffuse (Lambertian) NIR albedo of the triangle, 0-1, and optionally a
``float recorded_range``: the mean range (m) of the returns the reflectivity was measured from (a twin's: the air
between held whatever weather the recording had, see :attr:`~lidar_weather_sim.scene.scene.Scene.recorded_range_m`).
Vertices are ``double x, y, z`` in m (the map frame of the scenario). :func:`write_surveyed_ply` writes it,
:func:`read_surveyed_faces` reads the properties back (None for any other mesh file), and
:func:`surveyed_materials` turns the values into material indices: the table gets
:data:`REFLECTIVITY_BINS` extra materials ``surveyed_NNN``, log-spaced between
:data:`REFLECTIVITY_RANGE` (about 4.6 % apart, +-0.6 intensity bytes on a 1e4 dynamic range; a real sensor's reflectivity read as this profile's intensity can map far below the shipped materials'), appended once
so the shipped materials keep their indices.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from lidar_weather_sim.core.points import Label
from lidar_weather_sim.scene.materials import MaterialTable
from lidar_weather_sim.scene.mesh import Material

REFLECTIVITY_BINS = 256
REFLECTIVITY_RANGE = (1.0e-5, 1.0)
PREFIX = "surveyed_"


def bin_values() -> np.ndarray:
    """Reflectivity of each bin (0-1), log-spaced over :data:`REFLECTIVITY_RANGE`."""
    return np.geomspace(*REFLECTIVITY_RANGE, REFLECTIVITY_BINS)


def surveyed_materials(table: MaterialTable, reflectivity: np.ndarray) -> tuple[MaterialTable, np.ndarray]:
    """``table`` with the surveyed bins (added if missing) and the material index (T,) of each triangle's
    ``reflectivity`` (T,) (nearest bin in log; NaN or <= 0 values take the lowest bin)."""
    values = bin_values()
    names = [f"{PREFIX}{k:03d}" for k in range(REFLECTIVITY_BINS)]
    if names[0] not in table:
        table = MaterialTable([*table.materials, *(Material(n, float(v), 0.0, Label.STATIC) for n, v in zip(names, values))])
    r = np.nan_to_num(np.asarray(reflectivity, dtype=np.float64), nan=values[0])
    r = np.clip(r, *REFLECTIVITY_RANGE)
    step = np.log(values[1] / values[0])
    k = np.clip(np.rint(np.log(r / values[0]) / step), 0, REFLECTIVITY_BINS - 1).astype(np.int64)
    return table, (table.index(names[0]) + k).astype(np.uint16)


def _face_dtype(ranges: bool) -> np.dtype:
    return np.dtype([("n", "u1"), ("v", "<i4", (3,)), ("r", "<f4")] + ([("range", "<f4")] if ranges else []))


def write_surveyed_ply(path: str | Path, vertices: np.ndarray, triangles: np.ndarray, reflectivity: np.ndarray,
                       recorded_range: np.ndarray | None = None) -> Path:  # fmt: skip
    """Write vertices (V, 3) m, triangles (T, 3), reflectivity (T,) 0-1 and, if given, the recorded range (T,) m
    as the PLY of the module doc."""
    path = Path(path)
    vertices = np.ascontiguousarray(vertices, dtype="<f8").reshape(-1, 3)
    faces = np.zeros(len(triangles), dtype=_face_dtype(recorded_range is not None))
    faces["n"], faces["v"], faces["r"] = 3, triangles, reflectivity
    if recorded_range is not None:
        faces["range"] = recorded_range
    header = ("ply\nformat binary_little_endian 1.0\ncomment lidar_weather_sim surveyed mesh: reflectivity per face\n"
              f"element vertex {len(vertices)}\nproperty double x\nproperty double y\nproperty double z\n"
              f"element face {len(faces)}\nproperty list uchar int vertex_indices\nproperty float reflectivity\n"
              + ("property float recorded_range\n" if recorded_range is not None else "") + "end_header\n")  # fmt: skip
    path.parent.mkdir(parents=True, exist_ok=True)
    with open(path, "wb") as f:
        f.write(header.encode("ascii"))
        f.write(vertices.tobytes())
        f.write(faces.tobytes())
    return path


def read_surveyed_faces(path: str | Path) -> tuple[np.ndarray, np.ndarray | None] | None:
    """The ``reflectivity`` (T,) and ``recorded_range`` (T,) m (None when the file has none) of a PLY written by
    :func:`write_surveyed_ply`; None for other files."""
    path = Path(path)
    if path.suffix.lower() != ".ply" or not path.is_file():
        return None
    with open(path, "rb") as f:
        head = f.read(4096)
    end = head.find(b"end_header\n")
    if end < 0 or b"property float reflectivity" not in head[:end]:
        return None
    lines = head[:end].decode("ascii", "replace").splitlines()
    expected = ["property double x", "property double y", "property double z",
                "property list uchar int vertex_indices", "property float reflectivity"]  # fmt: skip
    properties = [ln for ln in lines if ln.startswith("property")]
    ranges = properties == [*expected, "property float recorded_range"]
    if "format binary_little_endian 1.0" not in lines or not (ranges or properties == expected):
        return None
    counts = {ln.split()[1]: int(ln.split()[2]) for ln in lines if ln.startswith("element")}
    faces = np.fromfile(path, dtype=_face_dtype(ranges), count=counts["face"],
                        offset=end + len(b"end_header\n") + 24 * counts["vertex"])  # fmt: skip
    if len(faces) != counts["face"] or np.any(faces["n"] != 3):
        return None
    return faces["r"].astype(np.float64), faces["range"].astype(np.float64) if ranges else None
