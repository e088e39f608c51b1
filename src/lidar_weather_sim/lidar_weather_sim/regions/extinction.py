"""Extinction coefficients (1/m) of fog, rain and snow for a near-infrared LiDAR (905 nm).

- Fog: Koschmieder, alpha = 3.912 / V (V meteorological visual range, m; 2 % contrast
  threshold). Wavelength dependence ignored (fog droplets 1-20 um: Mie regime).
- Rain: empirical free-space-optics relation alpha = 1.076 R^0.67 dB/km (R in mm/h),
  Carbonneau (1998), as tabulated in Kaushal & Kaddoum, "Optical communication in
  space: challenges and mitigation techniques", IEEE Commun. Surveys Tuts. 19(1), 2017.
- Snow: alpha = a S^b dB/km (S water-equivalent rate, mm/h) with a = 5.42e-5 lambda_nm
  + 5.4958776, b = 1.38 for dry snow (the same review, after Akiba et al.).

dB/km -> 1/m: x ln(10) / 10 / 1000.
"""

from __future__ import annotations

import numpy as np

KOSCHMIEDER = 3.912
DB_PER_KM_TO_PER_M = np.log(10.0) / 10.0 / 1000.0
WAVELENGTH_NM = 905.0


def fog_alpha(visual_range_m: float) -> float:
    """Koschmieder extinction (1/m) for a visual range (m)."""
    if visual_range_m <= 0:
        raise ValueError(f"fog visual_range_m must be > 0, got {visual_range_m}")
    return KOSCHMIEDER / visual_range_m


def rain_alpha(rate_mm_h: float) -> float:
    """Rain extinction (1/m) for a rain rate (mm/h)."""
    return 1.076 * max(rate_mm_h, 0.0) ** 0.67 * DB_PER_KM_TO_PER_M


def snow_alpha(rate_mm_h: float, wavelength_nm: float = WAVELENGTH_NM) -> float:
    """Dry-snow extinction (1/m) for a water-equivalent snowfall rate (mm/h)."""
    return (5.42e-5 * wavelength_nm + 5.4958776) * max(rate_mm_h, 0.0) ** 1.38 * DB_PER_KM_TO_PER_M


def total_alpha(visual_range_m: float, precipitation: str, intensity_mm_h: float) -> float:
    """Fog plus precipitation extinction (1/m)."""
    alpha = fog_alpha(visual_range_m)
    if precipitation == "rain":
        alpha += rain_alpha(intensity_mm_h)
    elif precipitation == "snow":
        alpha += snow_alpha(intensity_mm_h)
    return alpha
