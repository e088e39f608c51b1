"""Extinction alpha (1/m) and backscatter beta (1/(m sr)) of fog, rain and snow at a wavelength, from a
drop-size distribution (:mod:`.dsd`) and Mie or geometric-optics efficiencies (:mod:`.mie`)::

    alpha = int n(D) Q_ext(D) pi D^2 / 4 dD          (1/m)
    beta  = int n(D) Q_back(D) D^2 / 16 dD            (1/(m sr)), Q_back in the radar convention

with D the optical diameter (flake diameter for snow). Fog is scaled to its visual range by
Koschmieder's relation at 550 nm, ``V = 3.912 / alpha_550`` (2 % contrast; CIE / WMO visibility),
so that ``alpha_550 = 3.912 / V`` holds by construction and alpha at the LiDAR's wavelength follows from
the droplets' Mie efficiencies there.

Published checks (test/test_atmosphere_physics.py): rain at 905 nm gives ``alpha ~ 0.365 R^0.63``
(1/km, R in mm/h; Kim, McArthur & Korevaar 2001 / Al Naboulsi et al. 2004 for near-IR free-space optics)
within 20 % over 1-50 mm/h; for Marshall-Palmer with Q_ext = 2 alpha = pi N0 / Lambda^3 (closed form).
"""

from __future__ import annotations

import functools
from dataclasses import dataclass

import numpy as np

from lidar_weather_sim.physics import dsd as dsd_mod
from lidar_weather_sim.physics.mie import efficiencies

KOSCHMIEDER = 3.912  # -ln(0.02): visual range at 2 % contrast
VISIBLE_NM = 550.0
KINDS = ("fog", "rain", "snow")
_GRID = 600  # diameters of the quadrature


@dataclass(frozen=True)
class Medium:
    """One weather at one wavelength: its DSD, per-particle cross-sections and bulk coefficients.

    ``diameters`` (m, distribution diameters), ``density`` n(D) (m^-4), ``sigma_ext`` (m^2) and
    ``sigma_back`` (m^2/sr, differential backscatter at 180 deg) per particle on that grid."""

    kind: str
    value: float  # visual range (m) for fog, rate (mm/h) for rain and snow
    wavelength_nm: float
    diameters: np.ndarray
    density: np.ndarray
    sigma_ext: np.ndarray
    sigma_back: np.ndarray
    alpha: float  # 1/m
    beta: float  # 1/(m sr)
    number: float  # particles per m^3
    dsd: object

    @property
    def lidar_ratio_sr(self) -> float:
        """alpha / beta (sr)."""
        return self.alpha / self.beta

    @property
    def visual_range_m(self) -> float:
        """3.912 / alpha at this wavelength (m)."""
        return KOSCHMIEDER / self.alpha

    def sample(self, count: int, rng: np.random.Generator, d_lo: float | np.ndarray | None = None):
        """``count`` particles drawn from n(D) (above ``d_lo`` where given): (diameter m, sigma_back m^2/sr)."""
        if isinstance(self.dsd, dsd_mod.ExponentialDSD):
            d = self.dsd.sample(count, rng, d_lo)
        else:
            cdf = np.concatenate([[0.0], np.cumsum(0.5 * (self.density[1:] + self.density[:-1]) * np.diff(self.diameters))])
            d = np.interp(rng.random(count) * cdf[-1], cdf, self.diameters)
        return d, np.interp(d, self.diameters, self.sigma_back)

    def number_above(self, d_lo: np.ndarray) -> np.ndarray:
        """Particles per m^3 with a distribution diameter above ``d_lo`` (m)."""
        if isinstance(self.dsd, dsd_mod.ExponentialDSD):
            return self.dsd.number(d_lo)
        cdf = np.concatenate([[0.0], np.cumsum(0.5 * (self.density[1:] + self.density[:-1]) * np.diff(self.diameters))])
        return cdf[-1] - np.interp(d_lo, self.diameters, cdf)

    def beta_below(self, d_hi: np.ndarray) -> np.ndarray:
        """The part of beta (1/(m sr)) from particles with a distribution diameter below ``d_hi`` (m)."""
        f = self.density * self.sigma_back
        cum = np.concatenate([[0.0], np.cumsum(0.5 * (f[1:] + f[:-1]) * np.diff(self.diameters))])
        return np.interp(d_hi, self.diameters, cum)


def _integrate(d: np.ndarray, n: np.ndarray, sigma: np.ndarray) -> float:
    f = n * sigma
    return float(np.sum(0.5 * (f[1:] + f[:-1]) * np.diff(d)))


def _cross_sections(kind: str, wavelength_nm: float, d_optical: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    material = "ice" if kind == "snow" else "water"
    regime = "mie" if kind == "fog" else "geometric"
    qext, qback = efficiencies(material, wavelength_nm, d_optical, regime)
    area = np.pi * d_optical**2 / 4.0
    return qext * area, qback * area / (4.0 * np.pi)


@functools.lru_cache(maxsize=16)
def _fog_cross_sections(fog_kind: str, wavelength_nm: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(diameter grid m, sigma_ext m^2, sigma_back m^2/sr) of the fog droplets (Mie once per wavelength)."""
    unit = dsd_mod.shettle_fenn(fog_kind)
    d = np.geomspace(unit.d_min, unit.d_max, _GRID)
    return (d, *_cross_sections("fog", wavelength_nm, d))


@functools.lru_cache(maxsize=256)
def medium(kind: str, value: float, wavelength_nm: float, fog_kind: str = "advection") -> Medium:
    """The :class:`Medium` of ``kind`` (fog: visual range ``value`` m; rain, snow: ``value`` mm/h) at
    ``wavelength_nm`` (nm)."""
    if kind not in KINDS:
        raise ValueError(f"weather {kind!r}: one of {', '.join(KINDS)}")
    if not value > 0:
        raise ValueError(f"{kind}: parameter must be > 0, got {value}")
    if kind == "fog":
        unit = dsd_mod.shettle_fenn(fog_kind)
        d, ext550, _ = _fog_cross_sections(fog_kind, VISIBLE_NM)
        alpha550_unit = _integrate(d, unit.density(d), ext550)
        dist = unit.scaled(KOSCHMIEDER / value / alpha550_unit)
        _, sigma_ext, sigma_back = _fog_cross_sections(fog_kind, float(wavelength_nm))
    else:
        dist = dsd_mod.marshall_palmer(value) if kind == "rain" else dsd_mod.gunn_marshall(value)
        d = np.linspace(dist.d_min, dist.d_max, _GRID)
        sigma_ext, sigma_back = _cross_sections(kind, wavelength_nm, dist.optical(d))
    n = dist.density(d)
    number = float(dist.number())
    return Medium(kind, float(value), float(wavelength_nm), d, n, sigma_ext, sigma_back,
                  _integrate(d, n, sigma_ext), _integrate(d, n, sigma_back), number, dist)  # fmt: skip


def alpha_beta(kind: str, value: float, wavelength_nm: float) -> tuple[float, float]:
    """(alpha 1/m, beta 1/(m sr)) of ``kind`` at ``value`` (fog V m; rain, snow mm/h) and ``wavelength_nm``."""
    m = medium(kind, float(value), float(wavelength_nm))
    return m.alpha, m.beta
