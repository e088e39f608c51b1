"""The thesis' static rooftop set-up (paper 2, section 3): the sensor on a roof looking down at an
asphalt parking lot, 46 deg incidence at the street region 33-37 m away (x distance).

Used to calibrate the background-light model and to reproduce the paper's per-frame statistics.
The sensor height follows from the geometry: h = 35 m / tan(46 deg) = 33.8 m; its x axis is
pitched down by 90 - 46 = 44 deg so the beams meet the lot at the paper's incidence angle.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from lidar_weather_sim.materials import MaterialTable
from lidar_weather_sim.mesh import TriangleMesh
from lidar_weather_sim.player import matrix_quaternion, rpy_matrix
from lidar_weather_sim.scene import Scene

INCIDENCE_DEG = 46.0
STREET_CENTRE_X_M = 35.0
STREET_REGION_X_M = (33.0, 37.0)
ATMOSPHERE_REGION_M = (0.0, 5.0)
LOT_OBJECT_ID = 1


def sensor_height_m() -> float:
    return STREET_CENTRE_X_M / np.tan(np.deg2rad(INCIDENCE_DEG))


def rooftop_scene(surface: str = "asphalt_dry", materials: MaterialTable | None = None, size_m: float = 400.0) -> Scene:
    """A flat lot of ``surface`` (a material name) at z = 0, ``size_m`` wide, centred below the sensor."""
    materials = materials or MaterialTable.default()
    h = 0.5 * size_m
    vertices = np.array([[-h, -h, 0.0], [h, -h, 0.0], [h, h, 0.0], [-h, h, 0.0]])
    lot = TriangleMesh(vertices, np.array([[0, 1, 2], [0, 2, 3]]), materials.index(surface), LOT_OBJECT_ID)
    return Scene(materials, lot, object_names={LOT_OBJECT_ID: f"parking lot ({surface})"})


@dataclass(frozen=True)
class RooftopPose:
    """Static pose source: the sensor at (0, 0, h) pitched down by 90 deg - incidence."""

    height_m: float = sensor_height_m()
    pitch_deg: float = 90.0 - INCIDENCE_DEG

    def sensor_poses(self, times_s: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        n = len(np.atleast_1d(times_s))
        q = matrix_quaternion(rpy_matrix(0.0, np.deg2rad(self.pitch_deg), 0.0))
        return np.tile([0.0, 0.0, self.height_m], (n, 1)), np.tile(q, (n, 1))

    def actor_poses(self, time_s: float) -> dict:
        return {}

    def x_distance(self, points: np.ndarray) -> np.ndarray:
        """Horizontal distance (m) of sensor-frame points along the sensor's axis of symmetry."""
        pitch = np.deg2rad(self.pitch_deg)
        return points["x"] * np.cos(pitch) + points["z"] * np.sin(pitch)
