"""Drop-size distributions (DSD) of fog, rain and snow.

Every distribution gives ``n(D)``, the number of particles per m^3 of air and per m of diameter
(m^-4), over a finite diameter range [d_min, d_max] (m). Diameters are full diameters in m.

Sources
-------
- Fog: the modified gamma distribution of Shettle & Fenn (1979), "Models for the aerosols of the
  lower atmosphere and the effects of humidity variations on their optical properties",
  AFGL-TR-79-0214, as tabulated for lidar work by Rasshofer, Spies & Spies (2011), "Influences of
  weather phenomena on automotive laser radar systems", Adv. Radio Sci. 9, 49-60, Table 2:
  ``n(r) = a r^alpha exp(-b r^gamma)`` (r radius in um, n in cm^-3 um^-1).
  Advection fog: a 0.027, alpha 3, b 0.3, gamma 1 (20 droplets per cm^3, mode radius 10 um);
  radiation fog: a 607.5, alpha 6, b 3, gamma 1 (200 per cm^3, mode radius 2 um).
  The thesis gives fog droplets of 3-18 um (``typical_sizes.fog_um`` in thesis_tables.yaml),
  which the advection fog spans. The shape is kept and ``a`` is scaled so that the visual range
  (Koschmieder, 2 % contrast) ``V = 3.912 / alpha(550 nm)`` (:func:`fog_for_visual_range`).
- Rain: Marshall & Palmer (1948), "The distribution of raindrops with size", J. Meteor. 5, 165:
  ``n(D) = N0 exp(-Lambda D)``, N0 = 8000 m^-3 mm^-1, Lambda = 4.1 R^-0.21 mm^-1 (R in mm/h),
  diameters 0.1-6 mm (below 0.1 mm Marshall-Palmer over-counts drizzle; above ~6 mm drops break up).
- Snow: Gunn & Marshall (1958), "The distribution with size of aggregate snowflakes", J. Meteor.
  15, 452: ``n(D_m) = N0 exp(-Lambda D_m)``, N0 = 3800 R^-0.87 m^-3 mm^-1, Lambda = 2.55 R^-0.48
  mm^-1, with D_m the diameter of the melted flake and R the water-equivalent rate (mm/h). A flake of
  density rho_s has the diameter ``D = D_m (rho_w / rho_s)^(1/3)``; with rho_s = 100 kg/m^3 (an assumed
  typical dry-snow aggregate density) the mean flake at 1 mm/h is 0.84 mm, close to the thesis'
  typical snowflake of 1 mm (``typical_sizes.snowflake_mm``). Melted diameters 0.1-5 mm.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.special import gamma as gamma_fn
from scipy.special import gammaincc

#: Density of the snow aggregates (kg/m^3), assumed (dry snow aggregates: 50-200 kg/m^3).
SNOW_DENSITY_KG_M3 = 100.0
WATER_DENSITY_KG_M3 = 1000.0
#: Flake diameter over melted diameter.
SNOW_SIZE_FACTOR = (WATER_DENSITY_KG_M3 / SNOW_DENSITY_KG_M3) ** (1.0 / 3.0)

#: Shettle & Fenn (1979) fog parameters (a [cm^-3 um^-(alpha+1)], alpha, b [um^-gamma], gamma).
SHETTLE_FENN = {
    "advection": (0.027, 3.0, 0.3, 1.0),
    "radiation": (607.5, 6.0, 3.0, 1.0),
}


@dataclass(frozen=True)
class ExponentialDSD:
    """``n(D) = n0 exp(-lam D)`` (m^-4) for d_min <= D <= d_max (m); ``size_factor`` turns the
    distribution's diameter (melted for snow) into the optical one."""

    n0: float  # m^-4
    lam: float  # m^-1
    d_min: float  # m
    d_max: float  # m
    size_factor: float = 1.0

    def density(self, d: np.ndarray) -> np.ndarray:
        """n(D) (m^-4) at the distribution's diameters ``d`` (m), 0 outside [d_min, d_max]."""
        d = np.asarray(d, dtype=np.float64)
        return np.where((d >= self.d_min) & (d <= self.d_max), self.n0 * np.exp(-self.lam * d), 0.0)

    def number(self, d_lo: float | np.ndarray | None = None) -> np.ndarray:
        """Particles per m^3 with a distribution diameter above ``d_lo`` (default d_min) (m^-3)."""
        lo = self.d_min if d_lo is None else np.maximum(d_lo, self.d_min)
        return np.maximum(self.n0 / self.lam * (np.exp(-self.lam * lo) - np.exp(-self.lam * self.d_max)), 0.0)

    def sample(self, count: int, rng: np.random.Generator, d_lo: float | np.ndarray | None = None) -> np.ndarray:
        """``count`` distribution diameters (m) drawn from n(D) above ``d_lo`` (inverse CDF of the truncated
        exponential; ``d_lo`` may be one value per draw)."""
        lo = np.broadcast_to(self.d_min if d_lo is None else np.maximum(d_lo, self.d_min), (count,))
        u = rng.random(count)
        a, b = np.exp(-self.lam * lo), np.exp(-self.lam * self.d_max)
        return -np.log(a - u * (a - b)) / self.lam

    def optical(self, d: np.ndarray) -> np.ndarray:
        """Optical diameter (m) of particles of distribution diameter ``d`` (m)."""
        return np.asarray(d) * self.size_factor


def marshall_palmer(rate_mm_h: float) -> ExponentialDSD:
    """Rain of ``rate_mm_h`` (mm/h): Marshall & Palmer (1948), N0 8000 m^-3 mm^-1, Lambda 4.1 R^-0.21 mm^-1."""
    if rate_mm_h <= 0:
        raise ValueError(f"rain rate must be > 0 mm/h, got {rate_mm_h}")
    return ExponentialDSD(n0=8000.0 * 1e3, lam=4.1 * rate_mm_h**-0.21 * 1e3, d_min=0.1e-3, d_max=6.0e-3)


def gunn_marshall(rate_mm_h: float) -> ExponentialDSD:
    """Snow of water-equivalent ``rate_mm_h`` (mm/h): Gunn & Marshall (1958), N0 3800 R^-0.87 m^-3 mm^-1,
    Lambda 2.55 R^-0.48 mm^-1 in melted diameter; flakes are SNOW_SIZE_FACTOR times larger."""
    if rate_mm_h <= 0:
        raise ValueError(f"snow rate must be > 0 mm/h, got {rate_mm_h}")
    return ExponentialDSD(n0=3800.0 * rate_mm_h**-0.87 * 1e3, lam=2.55 * rate_mm_h**-0.48 * 1e3, d_min=0.1e-3,
                          d_max=5.0e-3, size_factor=SNOW_SIZE_FACTOR)  # fmt: skip


@dataclass(frozen=True)
class ModifiedGammaDSD:
    """Shettle & Fenn fog: ``n(r) = scale a r^alpha exp(-b r^gamma)`` with r in um and n in cm^-3 um^-1,
    expressed per diameter in SI (m^-4) by :meth:`density`."""

    a: float
    alpha: float
    b: float
    gamma: float
    scale: float = 1.0
    r_min_um: float = 0.1
    r_max_um: float = 60.0

    @property
    def d_min(self) -> float:
        return 2e-6 * self.r_min_um

    @property
    def d_max(self) -> float:
        return 2e-6 * self.r_max_um

    def density(self, d: np.ndarray) -> np.ndarray:
        """n(D) (m^-4) at diameters ``d`` (m)."""
        r_um = np.asarray(d, dtype=np.float64) * 0.5e6
        n_cm3_um = self.scale * self.a * r_um**self.alpha * np.exp(-self.b * r_um**self.gamma)
        inside = (r_um >= self.r_min_um) & (r_um <= self.r_max_um)
        # per cm^3 per um of radius -> per m^3 per m of diameter: x 1e6 (cm^-3 -> m^-3) x 1e6 / 2 (um r -> m D)
        return np.where(inside, n_cm3_um * 1e6 * 0.5e6, 0.0)

    def number(self) -> float:
        """Droplets per m^3 over [r_min, r_max] (closed form with the incomplete gamma function)."""
        k = (self.alpha + 1.0) / self.gamma

        def upper(r):
            return gamma_fn(k) * gammaincc(k, self.b * r**self.gamma)

        per_cm3 = self.scale * self.a / (self.gamma * self.b**k) * (upper(self.r_min_um) - upper(self.r_max_um))
        return float(per_cm3 * 1e6)

    def scaled(self, factor: float) -> "ModifiedGammaDSD":
        return ModifiedGammaDSD(self.a, self.alpha, self.b, self.gamma, self.scale * factor, self.r_min_um,
                                self.r_max_um)  # fmt: skip


def shettle_fenn(kind: str = "advection") -> ModifiedGammaDSD:
    """The unscaled Shettle & Fenn (1979) fog of ``kind`` (advection or radiation)."""
    if kind not in SHETTLE_FENN:
        raise ValueError(f"fog kind {kind!r}: one of {', '.join(SHETTLE_FENN)}")
    return ModifiedGammaDSD(*SHETTLE_FENN[kind])
