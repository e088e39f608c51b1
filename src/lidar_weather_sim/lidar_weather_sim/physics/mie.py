"""Mie efficiencies of water drops and ice spheres at the LiDAR's wavelength.

``Q_ext`` (extinction) and ``Q_back`` (backscatter, radar convention: the backscatter cross-section
is ``Q_back pi a^2`` and the differential one, per sr, ``Q_back a^2 / 4``; Rayleigh limit
``4 x^4 |(m^2-1)/(m^2+2)|^2``) of a sphere of size parameter ``x = pi D / lambda``.

- Fog droplets (x < 700 at 550-905 nm): ``miepython`` 3.3.0 (Prahl, https://github.com/scottprahl/miepython),
  vectorised over x (``regime="mie"``).
- Precipitation (``regime="geometric"``; rain drops at 905 nm have x ~ 350-21 000, snow flakes up to ~40 000; miepython needs
  ~0.1 s per size at x = 10 000): ``Q_ext = 2`` (the extinction paradox, van de Hulst 1957, "Light
  scattering by small particles", ch. 8) and the geometric-optics backscatter of a sphere
  (:func:`geometric_backscatter`): the specular reflection at the front plus the axial ray reflected once
  at the back, ``Q_back = R0 + (1 - R0)^2 R0 (m / (2 - m))^2`` with ``R0 = ((m - 1)/(m + 1))^2``
  (van de Hulst 1957, sec. 12.3; water at 905 nm: 0.095). It leaves out the glory of perfect spheres:
  Mie gives Q_back ~ 2-10 for water at x = 600-10 000 (miepython, averaged over +-8 % of x), but rain
  drops above ~1 mm are oblate and flakes are aggregates, and small departures from sphericity suppress
  the glory (Mishchenko, Travis & Lacis 2002, "Scattering, absorption and emission of light by small
  particles", sec. 10.7). This is the documented choice: geometric optics, no shipped table.

Refractive indices (``m = n + i k``; miepython wants ``n - i k``):
- water: Hale & Querry (1973), "Optical constants of water in the 200-nm to 200-um wavelength region",
  Appl. Opt. 12, 555, Table 1: 550 nm 1.333 + 1.96e-9 i, 850 nm 1.329 + 2.93e-7 i, 900 nm
  1.328 + 4.86e-7 i, linearly interpolated (905 nm taken at the 900 nm value; ~1.328 + 1e-6 i is often
  quoted, the difference does not change Q_ext or Q_back of drops below a cm: the absorption length
  lambda / (4 pi k) is > 0.1 m).
- ice: Warren & Brandt (2008), "Optical constants of ice from the ultraviolet to the microwave: a revised
  compilation", J. Geophys. Res. 113, D14220: n 1.311 at 550 nm, 1.303 at 865-905 nm; k < 1e-6 in
  this band (taken 2.5e-7, an approximate value read from their compilation). Snow flakes are treated
  as ice spheres of the flake diameter (an assumption: aggregates are porous and not spheres).
"""

from __future__ import annotations

import numpy as np

_WATER = ((550.0, 1.333, 1.96e-9), (850.0, 1.329, 2.93e-7), (900.0, 1.328, 4.86e-7))
_ICE = ((550.0, 1.311, 3.1e-9), (865.0, 1.303, 2.5e-7), (905.0, 1.303, 2.5e-7))
MATERIALS = ("water", "ice")


def refractive_index(material: str, wavelength_nm: float) -> complex:
    """Complex refractive index n + i k of ``material`` (water or ice) at ``wavelength_nm`` (nm, 550-950),
    linearly interpolated in the tables above (held at the ends)."""
    table = {"water": _WATER, "ice": _ICE}.get(material)
    if table is None:
        raise ValueError(f"material {material!r}: one of {', '.join(MATERIALS)}")
    if not 400.0 <= wavelength_nm <= 1000.0:
        raise ValueError(f"wavelength {wavelength_nm} nm is outside the 400-1000 nm these indices cover")
    wl, n, k = (np.array(c) for c in zip(*table))
    return complex(np.interp(wavelength_nm, wl, n), np.interp(wavelength_nm, wl, k))


def mie_direct(m: complex, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(Q_ext, Q_back) from miepython at size parameters ``x`` (index ``m`` = n + i k)."""
    import miepython

    x = np.atleast_1d(np.asarray(x, dtype=np.float64))
    qext, _, qback, _ = miepython.efficiencies_mx(complex(m.real, -abs(m.imag)), x)
    return np.asarray(qext, dtype=np.float64), np.asarray(qback, dtype=np.float64)


def geometric_backscatter(m: complex) -> float:
    """Geometric-optics backscatter efficiency (radar convention) of a large sphere of index ``m``: front
    reflection plus the axial ray reflected once inside, ``R0 + (1 - R0)^2 R0 (m / (2 - m))^2``, with the
    Fresnel reflectance at normal incidence ``R0 = |(m - 1)/(m + 1)|^2`` (absorption inside neglected)."""
    n = complex(m).real
    r0 = abs((complex(m) - 1.0) / (complex(m) + 1.0)) ** 2
    return float(r0 + (1.0 - r0) ** 2 * r0 * (n / (2.0 - n)) ** 2)


def efficiencies(material: str, wavelength_nm: float, diameter_m: np.ndarray,
                 regime: str = "mie") -> tuple[np.ndarray, np.ndarray]:  # fmt: skip
    """(Q_ext, Q_back) of spheres of ``material`` with diameters ``diameter_m`` (m) at ``wavelength_nm``:
    ``regime`` "mie" (miepython; fog) or "geometric" (Q_ext 2 and :func:`geometric_backscatter`; rain, snow)."""
    d = np.atleast_1d(np.asarray(diameter_m, dtype=np.float64))
    m = refractive_index(material, wavelength_nm)
    if regime == "mie":
        return mie_direct(m, np.pi * d / (wavelength_nm * 1e-9))
    if regime == "geometric":
        return np.full_like(d, 2.0), np.full_like(d, geometric_backscatter(m))
    raise ValueError(f"regime {regime!r}: mie or geometric")
