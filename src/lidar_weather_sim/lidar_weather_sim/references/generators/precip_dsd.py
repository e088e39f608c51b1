"""Rain and snow as discrete drops from drop-size laws other than Marshall-Palmer / Gunn-Marshall.

Models: precipitation of rate ``R`` (mm/h, liquid water equivalent) as drops placed one by one in each beam.

- **Rain**: a gamma DSD (Ulbrich 1983) ``N(D) = N0 D^2 exp(-Lambda D)`` (m^-3 mm^-1, ``D`` the drop diameter
  in mm, 0.1-6 mm), shape ``mu = 2``, ``Lambda = (3.67 + mu) / D0`` with the median volume diameter
  ``D0 = 0.9 R^0.21`` mm; ``N0`` is fixed by the rate: ``R = 6 pi 1e-4 int D^3 v(D) N(D) dD`` with the
  terminal velocity ``v(D) = 9.65 - 10.3 exp(-0.6 D)`` m/s (Atlas, Srivastava & Sekhon 1973).
- **Snow**: Sekhon & Srivastava (1970) ``N(D) = 2.5e3 R^-0.94 exp(-2.29 R^-0.45 D)`` (m^-3 mm^-1, ``D`` the
  melted diameter in mm, 0.1-5 mm); a flake's optical diameter is ``2.15 D`` (bulk density 0.1 g/cm^3).
- **Optics** (geometric optics, stated efficiencies): extinction efficiency ``Q = 2``, extinction
  ``alpha = Q int (pi d^2 / 4) N(D) dD`` (1/m, ``d`` the optical diameter; ~1e-3 at 10 mm/h: small);
  backscatter the specular reflection of a sphere at normal incidence, ``sigma_b = F d^2 / 16`` (m^2/sr) with
  the Fresnel reflectance ``F = ((n - 1) / (n + 1))^2``, ``n`` = 1.328 (water) for rain, 1.303 (ice) for snow
  (a flake as an ice sphere of its optical diameter).
- **Drops**: each beam with a return in the clear recording is a cone of diameter ``a + theta r`` (``a`` the
  transmit aperture, ``theta`` the geometric-mean full divergence). Drops lie between the closest reported range
  (or the overlap start, if farther) and the nearer of the beam's nearest clear return and the range where the
  largest drop of the law falls to the threshold. Their number is Poisson with mean ``n V`` (``n = int N dD``
  m^-3, ``V`` the cone's volume there), ranges uniform in that volume, diameters from the law. A drop at range
  ``r`` acts as a surface of reflectance ``pi sigma_b / (pi (a + theta r)^2 / 4)``: its peak is
  ``C rho w(r) exp(-2 alpha r) / r^2`` (``C`` the profile's power constant, ``w`` its overlap, linear); it is an
  echo (label RAIN / SNOW, EPW of an isolated pulse) where that peak reaches the threshold.
- **Loss**: every hard return's power is multiplied by ``exp(-2 alpha R)``; returns left below the threshold are
  removed. The returns each beam reports follow the return mode (:func:`.echoes.merge`).

Parameters: ``kind`` rain or snow; ``rate_mm_h`` in [1, 50] mm/h for rain, [0.2, 8] mm/h for snow; the seed of
the ``numpy.random.Generator`` passed to ``apply``.

Leaves out: drops on beams without a return in the clear recording (sky), drops merging within one pulse, the
beam's intensity profile (top-hat), multiple scattering, splashes, background light.
"""

from __future__ import annotations

import numpy as np

from lidar_weather_sim.core.points import Label
from lidar_weather_sim.references.generators.echoes import (Receiver, attenuate, beam_rows, echoes_at, merge,
                                                           nearest_on_beam)

RATE_MM_H = {"rain": (1.0, 50.0), "snow": (0.2, 8.0)}
DIAMETER_MM = {"rain": (0.1, 6.0), "snow": (0.1, 5.0)}
REFRACTIVE_INDEX = {"rain": 1.328, "snow": 1.303}  # at 850-905 nm
OPTICAL_PER_MELTED = {"rain": 1.0, "snow": 2.15}
EXTINCTION_EFFICIENCY = 2.0
GAMMA_MU = 2.0
GRID_MM = 1e-3  # step of the diameter tables (mm)
REACH_LIMIT_M = 100.0  # drops are sought no farther than this (m)
_LABEL = {"rain": Label.RAIN, "snow": Label.SNOW}


def size_law(kind: str, rate_mm_h: float, diameter_mm: np.ndarray) -> np.ndarray:
    """``N(D)`` (m^-3 mm^-1) of ``kind`` at ``rate_mm_h`` (module doc); ``D`` in mm (melted for snow)."""
    d = np.asarray(diameter_mm, np.float64)
    if kind == "snow":
        return 2.5e3 * rate_mm_h**-0.94 * np.exp(-2.29 * rate_mm_h**-0.45 * d)
    shape = d**GAMMA_MU * np.exp(-(3.67 + GAMMA_MU) / (0.9 * rate_mm_h**0.21) * d)
    lo, hi = DIAMETER_MM["rain"]
    grid = np.arange(lo, hi + GRID_MM / 2, GRID_MM)
    velocity = np.maximum(9.65 - 10.3 * np.exp(-0.6 * grid), 0.0)
    per_n0 = 6e-4 * np.pi * np.trapezoid(grid**3 * velocity * grid**GAMMA_MU
                                         * np.exp(-(3.67 + GAMMA_MU) / (0.9 * rate_mm_h**0.21) * grid), grid)  # fmt: skip
    return rate_mm_h / per_n0 * shape


class PrecipDSD:
    """``kind`` (rain | snow) of rate ``rate_mm_h`` as discrete drops (module doc)."""

    def __init__(self, rx: Receiver, kind: str, rate_mm_h: float) -> None:
        if kind not in RATE_MM_H:
            raise ValueError(f"kind: precipitation must be rain or snow, got {kind!r}")
        lo, hi = RATE_MM_H[kind]
        if not lo <= rate_mm_h <= hi:
            raise ValueError(f"rate_mm_h: {kind} rate must be in [{lo:g}, {hi:g}] mm/h, got {rate_mm_h:g}")
        self.rx, self.kind = rx, kind
        d_lo, d_hi = DIAMETER_MM[kind]
        self._d = np.arange(d_lo, d_hi + GRID_MM / 2, GRID_MM)
        n = size_law(kind, rate_mm_h, self._d)
        cdf = np.concatenate([[0.0], np.cumsum(0.5 * (n[1:] + n[:-1]) * GRID_MM)])
        self.number_m3 = float(cdf[-1])
        self._cdf = cdf / cdf[-1]
        area = np.pi / 4.0 * (OPTICAL_PER_MELTED[kind] * self._d * 1e-3) ** 2
        self.alpha = float(EXTINCTION_EFFICIENCY * np.trapezoid(area * n, self._d))
        self.near_m = max(rx.min_range_m, rx.overlap_start_m, 1e-3)
        r = np.linspace(self.near_m, REACH_LIMIT_M, 20000)
        visible = np.flatnonzero(self.peak(r, np.full_like(r, d_hi)) >= rx.threshold)
        self.reach_m = float(r[visible[-1]]) if len(visible) else self.near_m

    def cdf(self, diameter_mm: np.ndarray) -> np.ndarray:
        """The law's cumulative share of drops below ``diameter_mm`` (mm)."""
        return np.interp(diameter_mm, self._d, self._cdf)

    def backscatter(self, diameter_mm: np.ndarray) -> np.ndarray:
        """``sigma_b`` (m^2/sr) of drops of diameter ``diameter_mm`` (mm, melted for snow)."""
        n = REFRACTIVE_INDEX[self.kind]
        d = OPTICAL_PER_MELTED[self.kind] * np.asarray(diameter_mm) * 1e-3
        return ((n - 1.0) / (n + 1.0)) ** 2 * d**2 / 16.0

    def beam_diameter(self, r: np.ndarray) -> np.ndarray:
        """The beam's diameter (m) at range ``r`` (m)."""
        return self.rx.aperture_m + self.rx.divergence_rad * np.asarray(r)

    def peak(self, r: np.ndarray, diameter_mm: np.ndarray) -> np.ndarray:
        """Peak amplitude (noise units) of a drop of ``diameter_mm`` at range ``r`` (m) on the beam's axis."""
        rho = np.pi * self.backscatter(diameter_mm) / (np.pi / 4.0 * self.beam_diameter(r) ** 2)
        return self.rx.power_constant * rho * self.rx.overlap(r) * np.exp(-2.0 * self.alpha * r) / np.asarray(r) ** 2

    def volume(self, near_m: np.ndarray, far_m: np.ndarray) -> np.ndarray:
        """The beam cone's volume (m^3) between ``near_m`` and ``far_m`` (m); 0 where far <= near."""
        th, a = self.rx.divergence_rad, self.rx.aperture_m
        far = np.maximum(far_m, near_m)
        if th == 0:
            return np.pi / 4.0 * a**2 * (far - near_m)
        return np.pi / (12.0 * th) * ((a + th * far) ** 3 - (a + th * near_m) ** 3)

    def drops(self, far_m: np.ndarray, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(beam index, range m, diameter mm) of the drops in beams reaching ``far_m`` (m) each."""
        far = np.minimum(np.asarray(far_m, np.float64), self.reach_m)
        counts = rng.poisson(self.number_m3 * self.volume(self.near_m, far))
        beam = np.repeat(np.arange(len(far)), counts)
        th, a = self.rx.divergence_rad, self.rx.aperture_m
        u = rng.random(len(beam))
        if th == 0:
            r = self.near_m + u * (far[beam] - self.near_m)
        else:
            lo, hi = (a + th * self.near_m) ** 3, (a + th * far[beam]) ** 3
            r = (np.cbrt(lo + u * (hi - lo)) - a) / th
        diameter = np.interp(rng.random(len(beam)), self._cdf, self._d)
        return beam, r, diameter

    def apply(self, points: np.ndarray, rng: np.random.Generator) -> np.ndarray:
        """``points`` (the project's layout) in the precipitation: attenuated, drop echoes added."""
        hard = attenuate(points, 2.0 * self.alpha * points["distance"].astype(np.float64), self.rx)
        rows = beam_rows(points)
        beam, r, diameter = self.drops(nearest_on_beam(points, points[rows]), rng)
        ratio = np.log(np.maximum(self.peak(r, diameter), 1e-300) / self.rx.threshold)
        seen = ratio >= 0.0
        echoes = echoes_at(points, rows[beam[seen]], r[seen], ratio[seen], _LABEL[self.kind], self.rx)
        return merge(hard, echoes, self.rx)
