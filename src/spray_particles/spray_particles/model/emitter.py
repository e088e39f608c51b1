"""Wheel emitters: tread-ring vertices with the initial positions and velocities of eq. 7-10.

Frames
------
The thesis writes eq. 7-10 in Blender's frame of a wheel rolling towards -x (the
wheel turns counter-clockwise seen with x right, z up; vertex 0 is the ground
contact point and emits with zero velocity, the speed grows as v_c i / N counter-
clockwise). :func:`ring_emission` returns exactly that. :class:`WheelEmitter`
maps it to the vehicle body frame (x forward, y left, z up, origin at the
footprint centre on the ground, as :class:`lidar_weather_sim.scene.scene.VehicleShape`)
by x -> -x: vertex 0 at the contact point, vertices behind it thrown backwards and
up. Velocities are relative to the vehicle body (m/s); positions in m.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property

import numpy as np

from spray_particles.kernels.fused import ring_body


def ring_emission(i, n_vertices: int, speed_m_s: float, radius_m: float, dt_s: float):
    """Eq. 7-10 (thesis frame, m and m/s): ``(p_x, p_z, v_x, v_z)`` of vertex ``i`` of ``n_vertices``.

    ``speed_m_s`` v_c wheel (vehicle) speed, ``radius_m`` r ring radius, ``dt_s`` the time
    between two emission steps (phase advance v_c dt i / (N r)). p_z is measured from the
    ground (the ring centre is at z = r).
    """
    i = np.asarray(i, dtype=np.float64)
    n = float(n_vertices)
    angle = 2.0 * np.pi * i / n - 0.5 * np.pi + speed_m_s * dt_s * i / (n * radius_m)
    mag = speed_m_s * i / n
    return radius_m * np.cos(angle), radius_m * np.sin(angle) + radius_m, -mag * np.sin(angle), mag * np.cos(angle)


@dataclass(frozen=True)
class WheelEmitter:
    """Tread rings of the wheels of one vehicle, in its body frame.

    ``wheel_xy`` (W, 2) wheel centres (m, body frame: x forward, y left); ``radius_m`` and
    ``width_m`` of the tyre; ``treads`` rings spread evenly across the tyre width (the
    thesis' three loop cuts); ``n_vertices`` N of eq. 7-10.
    """

    wheel_xy: np.ndarray
    radius_m: float
    width_m: float
    treads: int = 3
    n_vertices: int = 36

    @cached_property
    def _wheel_xy(self) -> np.ndarray:
        return np.ascontiguousarray(self.wheel_xy, dtype=np.float64)

    @property
    def n_wheels(self) -> int:
        return len(self.wheel_xy)

    @cached_property
    def tread_offsets_m(self) -> np.ndarray:
        """Lateral offsets (m) of the tread rings from the wheel's mid-plane."""
        k = np.arange(self.treads) - 0.5 * (self.treads - 1)
        return k * self.width_m / self.treads

    def emit(self, rng: np.random.Generator, counts: np.ndarray, speed_m_s: float, dt_s: float):
        """``counts[w]`` particles from wheel w at random ring vertices and treads.

        Returns body-frame positions (n, 3) m, velocities relative to the body (n, 3) m/s,
        the side of each particle's wheel (n,) (+1 left, -1 right) and the wheel index (n,).
        """
        counts = np.asarray(counts, dtype=np.int64)
        # draws laid out particle-major (particle i of wheel w at [i, w]): the first particles of a wheel
        # are the same whatever the counts
        draws = rng.random((int(counts.max(initial=0)), self.n_wheels, 2))
        return ring_body(draws, counts, self._wheel_xy, self.tread_offsets_m,
                         self.n_vertices, self.treads, float(speed_m_s), float(self.radius_m), float(dt_s))  # fmt: skip


def vehicle_emitter(length_m: float, width_m: float, height_m: float, tyre_radius_m: float, tyre_width_m: float,
                    treads: int = 3, n_vertices: int = 36) -> WheelEmitter:  # fmt: skip
    """Emitter on the four wheels of the box car :class:`~lidar_weather_sim.scene.scene.VehicleShape`
    of that size (wheel positions from ``VehicleShape.wheel_centres``)."""
    from lidar_weather_sim.scene.scene import VehicleShape

    centres = VehicleShape(length_m, width_m, height_m).wheel_centres
    return WheelEmitter(centres[:, :2].copy(), tyre_radius_m, tyre_width_m, treads, n_vertices)
