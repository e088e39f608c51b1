"""Small scenes, profiles and pose sources for tests and examples (no ROS).

A one-beam profile with closed-form behaviour, vertical walls, a sensor moving
along +x: the building blocks of the simulator's physics tests, reusable by
region plugins and downstream packages.
"""

from __future__ import annotations

import numpy as np

from lidar_weather_sim.regions.base import RayBatch
from lidar_weather_sim.scene.materials import MaterialTable
from lidar_weather_sim.scene.mesh import TriangleMesh
from lidar_weather_sim.scene.scene import Scene
from lidar_weather_sim.sensor.profile import SensorProfile, load_profile

MATERIALS = MaterialTable.default()


def simple_profile(**changes) -> SensorProfile:
    """One horizontal beam, 81 columns over +-10 deg, no divergence, no noise, 10 Hz."""
    base = {
        "name": "test",
        "beams": [{"elevation_deg": 0.0}],
        "scan": {"frame_rate_hz": 10.0, "azimuth_min_deg": -10.0, "azimuth_max_deg": 10.0, "columns": 81,
                 "direction": "cw", "sweep_fraction": 0.5},
        "range": {"min_m": 0.0, "max_m": 200.0, "resolution_m": 0.1, "noise_sigma_m": 0.0},
        "optics": {"divergence_h_mrad": 0.0, "divergence_v_mrad": 0.0},
        "pulse": {"fwhm_m": 0.6},
        "detection": {"max_echoes": 3, "power_constant": 1.0e5, "noise_mean": 1.0, "noise_sigma": 1.0,
                      "threshold_sigma": 3.0},
    }  # fmt: skip
    for key, value in changes.items():
        section, _, field = key.partition("__")
        if field:
            base[section] = {**base[section], field: value}
        else:
            base[section] = value
    return SensorProfile.model_validate(base)


def wall(x_m: float, material: str, object_id: int, half_width: float = 50.0, tilt_deg: float = 0.0) -> TriangleMesh:
    """Vertical wall through (x_m, 0), facing -x, rotated by ``tilt_deg`` about z; 20 m tall."""
    c, s = np.cos(np.deg2rad(tilt_deg)), np.sin(np.deg2rad(tilt_deg))
    ys = np.array([-half_width, half_width])
    corners = [(x_m - s * y, c * y, z) for z in (-10.0, 10.0) for y in ys]
    return TriangleMesh(np.array(corners), np.array([[0, 2, 1], [1, 2, 3]]), MATERIALS.index(material), object_id)


def scene_of(*meshes: TriangleMesh) -> Scene:
    return Scene(MATERIALS, TriangleMesh.concatenate(list(meshes)))


class LinearPose:
    """Sensor at (x0 + v t, 0, 0), facing +x: a pose source for tests."""

    def __init__(self, speed_m_s: float = 0.0, x0: float = 0.0) -> None:
        self.speed, self.x0 = speed_m_s, x0

    def sensor_poses(self, times):
        times = np.asarray(times, dtype=np.float64)
        t = np.zeros((len(times), 3))
        t[:, 0] = self.x0 + self.speed * times
        q = np.tile([0.0, 0.0, 0.0, 1.0], (len(times), 1))
        return t, q

    def actor_poses(self, time_s):
        return {}


def one_frame(sim, pose=None, start_s: float = 0.0):
    """The one frame a simulator completes over one period from ``start_s``."""
    pose = pose or LinearPose()
    frames = sim.advance(start_s, pose) + sim.advance(start_s + sim.profile.period_s, pose)
    if len(frames) != 1:
        raise AssertionError(f"expected one frame, got {len(frames)}")
    return frames[0]


def beams_along_x(hits_m: np.ndarray, subrays: int = 3) -> RayBatch:
    """A region's ray batch: one beam per entry of ``hits_m`` along +x from the origin, ``subrays`` equal sub-rays
    each hitting at that range (m; inf: nothing)."""
    hits_m = np.asarray(hits_m, dtype=np.float64)
    n = len(hits_m)
    d = np.zeros((n, subrays, 3))
    d[..., 0] = 1.0
    return RayBatch(frame_index=0, origins=np.zeros((n, 3)), directions=d, sensor_directions=d.copy(),
                    channel=np.zeros(n, np.int64), time_s=np.zeros(n), weights=np.full(subrays, 1.0 / subrays),
                    distance=np.repeat(hits_m[:, None], subrays, axis=1), normal=np.zeros((n, subrays, 3)),
                    material=np.zeros((n, subrays), np.int64), object_id=np.zeros((n, subrays), np.uint32),
                    label=np.zeros((n, subrays), np.uint8))  # fmt: skip


def receiver_variant(name: str, overlap_model: str | None = None, ac_coupling_tau_m: float | None = None) -> SensorProfile:
    """Profile ``name`` with another overlap model (``cone`` | ``defocus``) and / or AC-coupling time constant (m;
    0: DC-coupled), named after them: e.g. scala4's optics before its receiver, ``receiver_variant("scala4", "cone", 0)``."""
    data = load_profile(name).model_dump(mode="json")
    if overlap_model is not None:
        data["optics"]["overlap_model"] = overlap_model
        data["name"] += f"_{overlap_model}"
    if ac_coupling_tau_m is not None:
        data["detection"]["ac_coupling_tau_m"] = float(ac_coupling_tau_m)
        data["name"] += f"_{ac_coupling_tau_m:g}"
    return SensorProfile.model_validate(data)
