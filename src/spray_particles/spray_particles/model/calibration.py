"""Fits of the constants in ``config/spray.yaml`` to the thesis' tables (paper 3).

Each function takes the ``spray`` block of ``thesis_tables.yaml`` (and physical constants) and
returns the constant the config file holds; ``test_physics.py`` re-runs them.
"""

from __future__ import annotations

import numpy as np

KMH = 1.0 / 3.6


def fit_drop_constant(spray: dict, surface_tension: float, water_density: float) -> float:
    """k of eq. 3 from the thesis' example (speed, tread height -> mean diameter, line 2252)."""
    ex = spray["drop_size_example"]
    v, b, d = ex["speed_kmh"] * KMH, ex["tread_height_mm"] * 1e-3, ex["d_mean_um"] * 1e-6
    return d * v / np.sqrt(surface_tension / (water_density * b))


def table_kappa(spray: dict) -> float:
    """The quadratic drag rate K_D L^2 (1/m) of Table III (same at both speeds and in Table IV)."""
    p = spray["proving_ground"]["by_speed"][39]
    return p["K_D"] * p["L"] ** 2


def fit_drag_coefficient(spray: dict, air_density: float, water_density: float) -> float:
    """C_D with which eq. 19 gives the Table's K_D L^2 for the 4 mm particle."""
    d = spray["particle_diameter_mm"] * 1e-3
    return table_kappa(spray) * 4.0 / 3.0 * water_density * d / air_density


def fit_emission(spray: dict) -> tuple[float, float]:
    """(gain per mm per m/s, threshold speed m/s) of n = gain h (v - v0) through Table III's two points."""
    pg = spray["proving_ground"]
    h = pg["water_film_mm"][0]
    (v1, n1), (v2, n2) = [(s * KMH, pg["by_speed"][s]["particles_per_wheel_per_frame"]) for s in sorted(pg["by_speed"])]
    slope = (n2 - n1) / (v2 - v1)
    return slope / h, v1 - n1 / slope


def fit_lateral_wind(spray: dict) -> tuple[float, float]:
    """(slope, threshold m/s) of v_y = slope (v_c - v0): v_y from K_Wy = kappa v_y^2 (eq. 23) at the
    speeds of Tables III and IV, least squares."""
    kappa = table_kappa(spray)
    pg = spray["proving_ground"]["by_speed"]
    speeds = [s * KMH for s in sorted(pg)] + [spray["highway"]["speed_kmh"][0] * KMH]
    k_wy = [pg[s]["K_Wy"] for s in sorted(pg)] + [spray["highway"]["params"]["K_Wy"]]
    vy = np.sqrt(np.array(k_wy) / kappa)
    slope, intercept = np.polyfit(speeds, vy, 1)
    return float(slope), float(-intercept / slope)


def fit_film_constant(spray: dict, rain_mm_h: float, drainage_length_m: float, cross_slope: float) -> float:
    """k_s of eq. 1 such that the highway (T_s of Table IV, ``rain_mm_h``) has its measured film."""
    hw = spray["highway"]
    h = hw["water_film_mm"][0]
    t_s = hw["params"]["T_s"]
    return h / (t_s**0.3 * np.sqrt(drainage_length_m * rain_mm_h) * cross_slope**-0.3)
