"""Airborne drops thrown by a tyre: how much water, which sizes (shared by the particle model's
drop packets and the droplet reference). SI units.

The tread picks up water at the rate of eq. 2; the share ``airborne_fraction`` of it
becomes airborne drops (config/spray.yaml ``drops``). Their number distribution is
lognormal with the median of eq. 3 (D_mean at the wheel speed) and spread
``size_sigma_ln``; samples that carry equal water volumes are drawn from the
volume-weighted distribution, ln d ~ N(ln median + 3 s^2, s).
"""

from __future__ import annotations

import numpy as np

from spray_particles.model.constants import SprayConstants
from spray_particles.model.water import mean_drop_diameter_m, tread_pickup_m3_s


def airborne_water_m3(c: SprayConstants, film_mm: float, speed_m_s: float, dt_s: float) -> float:
    """Water (m^3) one wheel throws into the air as drops in ``dt_s`` at that film (mm) and speed (m/s)."""
    pickup = tread_pickup_m3_s(film_mm, speed_m_s, c.tyre.grooves, c.tyre.groove_width_m, c.tyre.tread_height_m)
    return c.drops.airborne_fraction * float(pickup) * dt_s


def volume_weighted_diameters(c: SprayConstants, rng: np.random.Generator, n: int, speed_m_s: float) -> np.ndarray:
    """``n`` drop diameters (m), each standing for an equal volume of the wheel's drops at that speed."""
    median = float(mean_drop_diameter_m(speed_m_s, c.tyre.tread_height_m, c.water.drop_size_k,
                                        c.physics.water_surface_tension_n_m, c.physics.water_density_kg_m3))  # fmt: skip
    s = c.drops.size_sigma_ln
    d = np.exp(rng.normal(np.log(median) + 3.0 * s * s, s, n))
    return np.clip(d, c.drops.min_diameter_m, c.drops.max_diameter_m)


def drops_per_volume(diameter_m: np.ndarray, volume_m3: np.ndarray | float) -> np.ndarray:
    """Number of drops of ``diameter_m`` (m) that hold ``volume_m3`` (m^3) of water."""
    return volume_m3 / (np.pi / 6.0 * np.asarray(diameter_m) ** 3)
