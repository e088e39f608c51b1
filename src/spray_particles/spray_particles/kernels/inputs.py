"""Named groups of the tick kernels' inputs (:mod:`.stages`, :mod:`.fused`): NamedTuples of arrays and
scalars, which numba passes as one argument in nopython mode (module level, so ``cache=True`` can
pickle their types). World frame, vehicle body frame (x forward, y left, z up, origin on the ground
at the footprint centre); m, s, rad."""

from __future__ import annotations

from typing import NamedTuple

import numpy as np


class ParticleArrays(NamedTuple):
    """One row per particle, the fields of ``model.system.Particles`` in its order."""

    pos: np.ndarray  # (n, 3) m, world
    vel: np.ndarray  # (n, 3) m/s, world
    age: np.ndarray  # (n,) s
    lifetime: np.ndarray  # (n,) s
    kappa: np.ndarray  # (n,) 1/m, quadratic drag rate
    lam: np.ndarray  # (n,) 1/s, Stokes drag rate
    vehicle: np.ndarray  # (n,) int64, index of the emitting vehicle
    side: np.ndarray  # (n,) +1 left wheel, -1 right wheel
    population: np.ndarray  # (n,) uint8, 0 inertial particle, 1 drop packet
    wheel: np.ndarray  # (n,) int64, index into the vehicle's wheels
    diameter: np.ndarray  # (n,) m, drag diameter
    weight: np.ndarray  # (n,) real drops per particle
    diffusivity: np.ndarray  # (n,) m^2/s, a packet's turbulent spreading
    airborne: np.ndarray  # (n,) share of a packet's drops not deposited


class VehicleState(NamedTuple):
    """The vehicles at one tick."""

    rot: np.ndarray  # (V, 3, 3) body-to-world rotation
    org: np.ndarray  # (V, 3) m, body origin in the world
    vel: np.ndarray  # (V, 3) m/s, world velocity


class VehicleBodies(NamedTuple):
    """Per vehicle, its body box and wheel arches (body frame, m)."""

    length: np.ndarray  # (V,)
    width: np.ndarray  # (V,)
    height: np.ndarray  # (V,)
    clearance: np.ndarray  # (V,) ground clearance: the box starts there
    wheel_xz: np.ndarray  # (V, W, 2) wheel centres' x and z
    wheel_y: np.ndarray  # (V, W) wheel centres' y
    n_wheels: np.ndarray  # (V,) int64, wheels used of the W columns
    arch_r: np.ndarray  # (V,) wheel-arch radius
    arch_half_w: np.ndarray  # (V,) wheel-arch half width


class AirModel(NamedTuple):
    """The air around the vehicles: ambient wind, their wakes and lateral fields, the turbulence's scale."""

    v_lat: np.ndarray  # (V,) m/s, lateral wind speed of each vehicle's field
    ambient: np.ndarray  # (3,) m/s, world
    wind_over_speed: float  # share of the vehicle's speed the wake does not carry
    wake_length: float  # m, e-folding length of the wake behind the rear bumper
    lateral_lo: float  # m behind the rear bumper where the lateral field starts
    lateral_hi: float  # m behind the rear bumper where it ends
    turbulence: float  # turbulence intensity, RMS over the vehicle's speed in the wake


class CurlModes(NamedTuple):
    """The curl noise's random Fourier modes (``model.forces.CurlNoise``), body frame."""

    k: np.ndarray  # (M, 3) 1/m, wave vectors
    omega: np.ndarray  # (M,) rad/s, angular frequencies
    phase: np.ndarray  # (M,) rad
    curl: np.ndarray  # (M, 3) curl directions


class TickConstants(NamedTuple):
    """The constants of one integration tick."""

    gravity: float  # m/s^2
    dt: float  # s, tick length
    stiff_limit: float  # r dt above which a particle takes exponential sub-steps instead of RK4
    r0: float  # m, initial radius of a drop packet
