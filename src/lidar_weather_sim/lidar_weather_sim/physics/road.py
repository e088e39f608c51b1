"""Water on the road (thesis paper 3, eq. 1): the film a rain leaves on a drained road. Units in the names."""

from __future__ import annotations

import numpy as np

#: k_s of eq. 1. The thesis does not give it; fitted (``spray_particles.model.calibration.fit_film_constant``) so
#: that the thesis' highway (T_s 1.5 mm, Table IV; 2 mm/h) on 3 lanes of 3.75 m with 2.5 % cross slope has its
#: measured 0.7 mm film (Fig. 13).
FILM_CONSTANT_K_S = 0.0432


def water_film_mm(rain_mm_h, texture_depth_mm, drainage_length_m, cross_slope, k_s=FILM_CONSTANT_K_S):
    """Eq. 1: water film thickness h (mm) = k_s T_s^0.3 (L_s I_R)^0.5 S_s^-0.3.

    ``rain_mm_h`` rainfall intensity I_R (mm/h), ``texture_depth_mm`` T_s (0.208 mm smooth
    concrete ... 1.644 mm porous asphalt), ``drainage_length_m`` L_s (m), ``cross_slope`` S_s
    (m/m), ``k_s`` the constant (:data:`FILM_CONSTANT_K_S`).
    """
    rain = np.asarray(rain_mm_h, dtype=np.float64)
    if np.any(rain < 0) or np.any(np.asarray(cross_slope) <= 0):
        raise ValueError(f"water film: need rain >= 0 and slope > 0, got rain {rain_mm_h}, slope {cross_slope}")
    return k_s * np.power(texture_depth_mm, 0.3) * np.sqrt(drainage_length_m * rain) * np.power(cross_slope, -0.3)
