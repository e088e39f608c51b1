"""Obstacles raycast by the simulator with a recording's scan pattern (paper 4's rendering step).

The obstacles of one frame (boxes or the other kinds' meshes) become a scene of their own (one
material per box, a car's paint, glass, tyres and plates: label ``OBSTACLE``; its object id) and
:class:`~lidar_weather_sim.sim.simulator.LidarSimulator` casts the frame's scan pattern at it (the
profile's channels, columns, firing times, sub-rays across the beam divergence, the LIDAR equation
and the echo threshold), so each obstacle point has its channel, azimuth, ``time_stamp`` (ns after
the scan start) and an EPW (m) from the sensor model.

Frame: the boxes are given in the sensor frame (REP-103) and held there during the sweep (paper 4:
a box "remains in the same position" relative to the ego, as its simulation kept the leading
vehicle's tracked ego-relative position), so the sensor is cast from the origin at every column.
Only the boxes' returns are kept (the noise floor's false alarms are dropped).
"""

from __future__ import annotations

import numpy as np

from lidar_weather_sim.core.points import empty_points
from lidar_weather_sim.augment.boxes import Box
from lidar_weather_sim.augment.meshes import obstacle_mesh
from lidar_weather_sim.scene.materials import MaterialTable
from lidar_weather_sim.scene.mesh import TriangleMesh
from lidar_weather_sim.scene.scene import Scene
from lidar_weather_sim.sensor.profile import SensorProfile
from lidar_weather_sim.sensor.scan import ScanPattern
from lidar_weather_sim.sim.simulator import LidarSimulator


class SensorAtOrigin:
    """Pose source of a sensor that stays at the origin of its own frame (no actors)."""

    def sensor_poses(self, times_s: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        n = len(times_s)
        return np.zeros((n, 3)), np.tile([0.0, 0.0, 0.0, 1.0], (n, 1))

    def actor_poses(self, time_s: float) -> dict[int, np.ndarray]:
        return {}


def box_scene(boxes: list[Box]) -> Scene:
    """The obstacles (any kind, :func:`~lidar_weather_sim.augment.meshes.obstacle_mesh`) as one
    static mesh in the sensor frame; their materials one after the other (boxes alone: material i = box i)."""
    materials, meshes = [], []
    for b in boxes:
        mesh, own = obstacle_mesh(b)
        mesh.material += len(materials)
        materials += own
        meshes.append(mesh.transformed(b.pose()))
    return Scene(MaterialTable(materials), TriangleMesh.concatenate(meshes))


class ObstacleCaster:
    """Casts boxes with one profile's scan pattern (built once; ``backend`` None: the default)."""

    def __init__(self, profile: SensorProfile, backend: str | None = None) -> None:
        self.profile = profile
        self.pattern = ScanPattern(profile)
        self.backend = backend

    def cast(self, boxes: list[Box], frame_index: int, seed: int) -> np.ndarray:
        """Points (project layout with ground truth, sensor frame) of ``boxes`` in frame ``frame_index``
        of the scan pattern (decides alternating layers); ``seed`` seeds the receiver noise."""
        if not boxes:
            return empty_points(0)
        scene = box_scene(boxes)
        sim = LidarSimulator(self.profile, scene, backend=self.backend, regions=[], seed=seed)
        sim.pattern = self.pattern  # the direction tables are built once per profile
        points = sim.cast_frame(int(frame_index), 0.0, SensorAtOrigin()).points
        return points[np.isin(points["object_id"], [b.object_id for b in boxes])].copy()
