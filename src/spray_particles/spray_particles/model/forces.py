"""Forces on spray particles: gravity, drag towards the local air velocity, wind (eq. 11-23).

The thesis writes the forces of its physics engine as F_D = K_D L^2 v^2 (eq. 11),
F_W = K_W (eq. 12), F_G = M G (eq. 13) with M = 1, and matches them to the physical
drag and wind forces (eq. 14-15, 17, 21) of a drop of diameter d:

- eq. 19: K_D L^2 = 1/2 rho_air C_D A_p / m = 3 rho_air C_D / (4 rho_w d)  (= ``kappa``, 1/m)
- eq. 23: K_Wx = 1/2 rho_air v_w^2 C_D A_p / m = kappa v_w^2                 (m/s^2)

Here the same physics is written as one vector law, per unit mass (m/s^2)::

    a = g - (kappa |v - u| + lambda) (v - u)

with ``u`` the local air velocity (ambient wind + the wake that moves with the
vehicle + the two lateral fields behind it + curl-noise turbulence) and lambda =
18 mu / (rho_w d^2) the Stokes (linear) drag, negligible for the 4 mm particle but
what makes fine drops follow the air. In still air a particle moving at v_p
relative to the car, with the air streaming past the car at v_w, feels
kappa (v_w^2 - v_p^2) along x: exactly eq. 20-21 with K_Wx from eq. 23.
"""

from __future__ import annotations

import numpy as np


def drag_rates(diameter_m, drag_coefficient: float, air_density: float, water_density: float, air_viscosity: float):
    """``(kappa, lambda)`` of drops of ``diameter_m`` (m): quadratic (1/m, eq. 19) and Stokes (1/s) drag rates."""
    d = np.asarray(diameter_m, dtype=np.float64)
    kappa = 0.75 * air_density * drag_coefficient / (water_density * d)
    lam = 18.0 * air_viscosity / (water_density * d * d)
    return kappa, lam


def thesis_drag_constant(kappa_per_m: float, scale_l: float) -> float:
    """Eq. 19: the engine's K_D for a physical quadratic drag rate kappa and the scale L."""
    return kappa_per_m / (scale_l * scale_l)


def thesis_wind_constant(kappa_per_m: float, wind_speed_m_s: float) -> float:
    """Eq. 23: the engine's wind force K_W (m/s^2, M = 1) for a wind of ``wind_speed_m_s``."""
    return kappa_per_m * wind_speed_m_s**2


def acceleration(vel: np.ndarray, air: np.ndarray, kappa: np.ndarray, lam: np.ndarray, gravity: float) -> np.ndarray:
    """a = g - (kappa |v - u| + lambda)(v - u), (n, 3) m/s^2; z up."""
    rel = vel - air
    speed = np.sqrt(np.einsum("nk,nk->n", rel, rel))
    a = -(kappa * speed + lam)[:, None] * rel
    a[:, 2] -= gravity
    return a


def lateral_wind_speed(speed_m_s, slope: float, threshold_speed_m_s: float):
    """Speed (m/s) of the lateral air flow 0-6 m behind a car at ``speed_m_s`` that pulls the two
    wheel tracks together (thesis Fig. 20): slope * max(0, v_c - v0) (config/spray.yaml lateral_wind)."""
    return slope * np.maximum(0.0, np.asarray(speed_m_s, dtype=np.float64) - threshold_speed_m_s)


class CurlNoise:
    """Divergence-free random velocity field: the curl of a seeded smooth vector potential.

    psi(x, t) = sum_m a_m sin(k_m . x - w_m t + phi_m) (random Fourier modes, wave numbers
    around 2 pi / ``length_scale_m``); u = curl psi = sum_m cos(k_m . x - w_m t + phi_m) (k_m x a_m),
    normalised to unit RMS speed. Positions in m, time in s, result (n, 3) dimensionless.
    Same seed, same field.
    """

    def __init__(self, seed: int, length_scale_m: float = 1.0, time_scale_s: float = 0.5, modes: int = 12) -> None:
        rng = np.random.default_rng([int(seed) & 0xFFFFFFFF, 0x5EED])
        direction = rng.normal(size=(modes, 3))
        direction /= np.linalg.norm(direction, axis=1, keepdims=True)
        magnitude = 2.0 * np.pi / length_scale_m * rng.uniform(0.5, 1.5, modes)
        self.k = direction * magnitude[:, None]
        a = rng.normal(size=(modes, 3))
        self.curl = np.cross(self.k, a)  # (M, 3)
        self.omega = rng.uniform(0.5, 1.5, modes) / time_scale_s
        self.phase = rng.uniform(0.0, 2.0 * np.pi, modes)
        self.curl /= np.sqrt(0.5 * np.sum(self.curl**2))  # unit RMS speed

    def velocity(self, pos: np.ndarray, time_s: float) -> np.ndarray:
        arg = pos @ self.k.T - self.omega * time_s + self.phase  # (n, M)
        return np.cos(arg) @ self.curl
