"""Water in the tread (thesis paper 3, eq. 2-3; eq. 1, the road's film, is in
:mod:`lidar_weather_sim.physics.road`). SI units unless a name says otherwise."""

from __future__ import annotations

import re

import numpy as np


def tread_pickup_m3_s(film_mm, speed_m_s, grooves, groove_width_m, tread_height_m):
    """Eq. 2: water picked up by the tread per second (m^3/s) = h/3 v_c n_t a b.

    ``h/3`` is the filled share of the grooves (the model holds for films up to 3 mm,
    so h is in mm and capped there), ``v_c`` the wheel (vehicle) speed (m/s).
    """
    fill = np.clip(np.asarray(film_mm, dtype=np.float64), 0.0, 3.0) / 3.0
    return fill * np.asarray(speed_m_s, dtype=np.float64) * grooves * groove_width_m * tread_height_m


def mean_drop_diameter_m(speed_m_s, tread_height_m, k, surface_tension_n_m=0.0728, water_density_kg_m3=1000.0):
    """Eq. 3: mean tread pick-up drop diameter (m) = k / v_c sqrt(sigma / (rho b)).

    Diverges at standstill: the speed is floored at 0.5 m/s.
    """
    v = np.maximum(np.asarray(speed_m_s, dtype=np.float64), 0.5)
    return k / v * np.sqrt(surface_tension_n_m / (water_density_kg_m3 * tread_height_m))


def drop_mass_kg(diameter_m, water_density_kg_m3=1000.0):
    """Mass (kg) of a spherical drop of ``diameter_m`` (m)."""
    return water_density_kg_m3 * np.pi / 6.0 * np.asarray(diameter_m, dtype=np.float64) ** 3


def tyre_dimensions(size: str) -> tuple[float, float]:
    """Outer radius and width (m) of an ISO metric tyre size ``'255/40R19'``."""
    m = re.fullmatch(r"\s*(\d{3})/(\d{2})\s*Z?R\s*(\d{2})\s*", size)
    if not m:
        raise ValueError(f"tyre size {size!r}: expected e.g. '255/40R19'")
    width_mm, aspect, rim_in = (int(g) for g in m.groups())
    diameter = rim_in * 0.0254 + 2 * width_mm * aspect / 100.0 / 1000.0
    return 0.5 * diameter, width_mm / 1000.0
