"""The thesis' static rooftop set-up (paper 2, section 3): the sensor on a roof looking down at an
asphalt parking lot, 46 deg incidence at the street region 33-37 m away (x distance).

Used to calibrate the background-light model and to reproduce the paper's per-frame statistics.
The geometry is read from ``config/rooftop.yaml`` (:class:`RooftopGeometry`, documented there):
the street layer's central beam meets the lot at ``incidence_deg`` at horizontal distance
``street_layer_x_m``, so the sensor height is h = x / tan(incidence) and its x axis is pitched
down by 90 deg - incidence - elevation(street layer).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from functools import lru_cache

import numpy as np
from pydantic import Field

from lidar_weather_sim.core.config import ConfigModel, load_yaml
from lidar_weather_sim.core.geometry import matrix_quaternion, rpy_matrix
from lidar_weather_sim.scene.materials import MaterialTable
from lidar_weather_sim.scene.mesh import TriangleMesh
from lidar_weather_sim.scene.scene import Scene

STREET_REGION_X_M = (33.0, 37.0)
ATMOSPHERE_REGION_M = (0.0, 5.0)
LOT_OBJECT_ID = 1


class LotExtent(ConfigModel):
    x_near_m: float = Field(description="Near edge of the asphalt along the axis (horizontal, m)")
    x_far_m: float = Field(description="Far edge of the asphalt along the axis (horizontal, m)")
    half_width_m: float = Field(gt=0, description="Half width of the asphalt across the axis (m)")


class RooftopGeometry(ConfigModel):
    incidence_deg: float = Field(gt=0, lt=90, description="Beam to surface normal at the street layer (deg)")
    street_layer: int = Field(ge=0, description="Channel of the sensor profile whose central beam defines the incidence")
    street_layer_x_m: float = Field(gt=0, description="Horizontal distance where that beam meets the lot (m)")
    lot: LotExtent
    street_gain: float = Field(gt=0, description="The lot's backscatter at the incidence over a Lambertian "
                               "surface of its albedo (fixed, fitted on the clear-night street)")  # fmt: skip

    def height_m(self) -> float:
        return self.street_layer_x_m / np.tan(np.deg2rad(self.incidence_deg))

    def pitch_deg(self, layer_elevation_deg: float) -> float:
        return 90.0 - self.incidence_deg + layer_elevation_deg  # depression of the layer = pitch - elevation


@lru_cache(maxsize=1)
def geometry() -> RooftopGeometry:
    from lidar_weather_sim.core.paths import config_dir

    return load_yaml(config_dir() / "rooftop.yaml", RooftopGeometry)


def _street_layer_elevation_deg(profile=None) -> float:
    """Elevation (deg) of the street layer of ``profile`` (a SensorProfile; None: scala4)."""
    from lidar_weather_sim.sensor.profile import load_profile

    profile = profile or load_profile("scala4")
    layer = geometry().street_layer
    if layer >= len(profile.beams):
        raise ValueError(f"config/rooftop.yaml street_layer {layer}: sensor profile '{profile.name}' has "
                         f"{len(profile.beams)} channels")
    return float(profile.beams[int(profile.channel_order[layer])].elevation_deg)


def sensor_height_m() -> float:
    return geometry().height_m()


def rooftop_scene(surface: str = "asphalt_dry", materials: MaterialTable | None = None, size_m: float = 400.0) -> Scene:
    """A flat, unbounded lot of ``surface`` (a material name) at z = 0, ``size_m`` wide, centred below the sensor."""
    materials = materials or MaterialTable.default()
    h = 0.5 * size_m
    vertices = np.array([[-h, -h, 0.0], [h, -h, 0.0], [h, h, 0.0], [-h, h, 0.0]])
    lot = TriangleMesh(vertices, np.array([[0, 1, 2], [0, 2, 3]]), materials.index(surface), LOT_OBJECT_ID)
    return Scene(materials, lot, object_names={LOT_OBJECT_ID: f"parking lot ({surface})"})


def bounded_lot_scene(surface: str = "asphalt_dry", materials: MaterialTable | None = None,
                      lot: LotExtent | None = None) -> Scene:  # fmt: skip
    """The asphalt the sensor sees in the paper's set-up (``config/rooftop.yaml`` ``lot``), at z = 0."""
    materials = materials or MaterialTable.default()
    lot = lot or geometry().lot
    x0, x1, w = lot.x_near_m, lot.x_far_m, lot.half_width_m
    vertices = np.array([[x0, -w, 0.0], [x1, -w, 0.0], [x1, w, 0.0], [x0, w, 0.0]])
    mesh = TriangleMesh(vertices, np.array([[0, 1, 2], [0, 2, 3]]), materials.index(surface), LOT_OBJECT_ID)
    return Scene(materials, mesh, object_names={LOT_OBJECT_ID: f"parking lot ({surface})"})


@dataclass(frozen=True)
class RooftopPose:
    """Static pose source: the sensor at (0, 0, h) pitched down so the street layer meets the lot at the incidence."""

    height_m: float = field(default_factory=sensor_height_m)
    pitch_deg: float = field(default_factory=lambda: geometry().pitch_deg(_street_layer_elevation_deg()))

    @classmethod
    def for_profile(cls, profile) -> "RooftopPose":
        """The pose that puts ``profile``'s street layer (a SensorProfile) on the lot at the incidence."""
        return cls(pitch_deg=geometry().pitch_deg(_street_layer_elevation_deg(profile)))

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
