"""The atmosphere as physics per beam: the scatterers of region ``atmosphere`` with
``model: physical``.

The media are fog (its visual range) and one precipitation (rain or snow, mm/h) from
:mod:`lidar_weather_sim.physics` at the profile's wavelength (``optics.wavelength_nm``; 905 nm for a
profile that gives none): drop-size
distribution, Mie or geometric cross-sections, extinction ``alpha`` and backscatter ``beta``. Nothing
is fitted to a sensor: what changes from one profile to another is its wavelength, beam, pulse, overlap
and threshold. Per batch of beams (world-frame rays, ranges in m along the ray):

- **extinction**: the media's ``alpha`` (1/m), summed; the echo stage applies exp(-2 alpha R);
- **drops one by one** (rain drops, snow flakes): Poisson in the beam's volume ``S(r) dr`` in front of
  each beam's hit (the central sub-ray's), ``S(r) = pi (a + r tan(theta / 2))^2`` the beam's cross-section
  (exit radius ``a``, divergence theta the geometric mean of the profile's two): the drops that reach
  ``NEAR_FRACTION`` of the threshold on their own (in full overlap, before extinction of the pulse's own
  path beyond r) out to ``NEAR_M``, ``INDIVIDUAL_FRACTION`` beyond it; diameters from the distribution above
  that size. The smaller drops join the volume: a beam holds a few drops in its first metres, so drops too
  weak to be seen alone rarely meet in one pulse. A drop of differential backscatter cross-section sigma (m^2/sr) on a
  sub-ray of weight w is a surface of reflectance ``pi sigma / (S(r) w)`` (its peak
  ``C pi sigma / (S(r) r^2)`` before extinction and overlap), blocking its geometric cross-section's share
  of that sub-ray;
- **the volume**: fog and the drops too small to be seen one by one, as the echo stage's own pulses
  (:class:`lidar_weather_sim.regions.volume_return.VolumeReturn`: one per slab of one pulse sigma, the slab
  a surface of reflectance ``pi beta h``; at that spacing the pulses' sum is smooth to 1e-8) on the central
  sub-ray in front of its hit; where the volume's waveform stays below ``VOLUME_FLOOR`` of the threshold
  it is left out. In the near field (out to ``NEAR_M``) the fog's pulses fluctuate from beam to beam: a slab
  holds a Poisson number of droplets, so its summed cross-section is compound Poisson, mean ``lam E[sigma]``,
  variance ``lam E[sigma^2]`` (``lam`` the droplets in the slab's beam volume), drawn in its normal limit and
  clipped at 0, as the reference does for its cells. A fog echo is flat-topped (metres wide): without this
  every beam of a channel put its peak on the same spot, where the droplets' own fluctuation moves it by tens of
  centimetres.

The overlap O(r) is the profile's biaxial geometry (lens separation, receiver field of view, apertures) in its
``optics.overlap_model`` (:data:`lidar_weather_sim.physics.overlap.OVERLAP_MODELS`) where its optics give it,
else the echo stage's smoothstep; it is part of each volume pulse's reflectance. A drop is seen with probability
O(r) at full strength (``cone``: in the receiver's view or not), or, ``defocus``, always with the share of its
light the field stop takes at its place on the beam's disc (``bypass_overlap``: the echo stage does not apply
its own). The threshold is the dark one (no sun). This is the
model :mod:`lidar_weather_sim.references.droplets` computes slowly, drop by drop, with a geometric overlap and
fog droplet statistics: the fast model is checked against it (``benchmarks/validation/atmosphere_reference.py
--fast-model physical``). Not modelled: multiple scattering, the fog's fluctuation beyond the near field
(the reference's quadrature there is smooth too).
"""

from __future__ import annotations

from functools import partial

import numba
import numpy as np

from lidar_weather_sim.core.points import Label
from lidar_weather_sim.physics.coefficients import Medium, medium
from lidar_weather_sim.physics.overlap import OVERLAP_MODELS, point_share
from lidar_weather_sim.regions.base import RayBatch, Scatterers
from lidar_weather_sim.regions.volume_return import VolumeReturn
from lidar_weather_sim.sensor.ac_coupling import highpass_slabs
from lidar_weather_sim.sensor.radiometry import FWHM_TO_SIGMA, MIN_RANGE_M, dark_level

NEAR_M = 5.0  # the near field (m), as the reference's
NEAR_FRACTION = 0.01  # in the near field: drops reaching this share of the threshold alone are placed
INDIVIDUAL_FRACTION = 0.05  # beyond NEAR_M: the same, as the reference
VOLUME_FLOOR = 0.02  # the volume's waveform below this share of the threshold is left out
DEFAULT_WAVELENGTH_NM = 905.0
GRID_M = 0.02  # the range grid of the per-beam drop volumes (m)
LABELS = {"fog": Label.FOG, "rain": Label.RAIN, "snow": Label.SNOW}


class PhysicalAir:
    """Fog (visual range m, or None) and precipitation ((``rain`` | ``snow``, mm/h), or None) seen by ``profile``."""

    def __init__(self, profile, fog_visual_range_m: float | None, precipitation: tuple[str, float] | None) -> None:
        o, det = profile.optics, profile.detection
        wavelength = float(o.wavelength_nm or DEFAULT_WAVELENGTH_NM)
        self.fog = medium("fog", float(fog_visual_range_m), wavelength) if fog_visual_range_m else None
        self.precip = medium(precipitation[0], float(precipitation[1]), wavelength) if precipitation else None
        self.alpha = sum(m.alpha for m in (self.fog, self.precip) if m is not None)
        self.power = float(det.power_constant)
        self.threshold = dark_level(det)
        self.tau = float(det.ac_coupling_tau_m)
        self.r_max = float(profile.range.max_m)
        self.divergence = 1e-3 * float(np.sqrt(o.divergence_h_mrad * o.divergence_v_mrad))
        self.exit_radius = float(o.tx_aperture_radius_m)
        overlap, self._optics = None, None  # (lens separation m, receiver FOV rad, aperture radius m)
        self.overlap_model = o.overlap_model
        if o.lens_separation_m is not None and o.receiver_fov_mrad is not None:
            overlap = partial(OVERLAP_MODELS[o.overlap_model], separation_m=o.lens_separation_m,
                              divergence_rad=self.divergence, fov_rad=1e-3 * o.receiver_fov_mrad,
                              tx_radius_m=o.tx_aperture_radius_m, rx_radius_m=o.rx_aperture_radius_m)  # fmt: skip
            self._optics = (o.lens_separation_m, 1e-3 * o.receiver_fov_mrad, o.rx_aperture_radius_m)
        start = 0.0 if overlap is not None else o.overlap_start_m
        self.volume = VolumeReturn(self.power, self.alpha, 1.0, profile.pulse.fwhm_m * FWHM_TO_SIGMA, start,
                                   o.overlap_full_m, overlap)  # fmt: skip
        self._grid = np.arange(max(start, MIN_RANGE_M), self.r_max + GRID_M, GRID_M)
        widening = overlap is not None and 1e-3 * o.receiver_fov_mrad >= self.divergence  # the view holds the beam
        self._full_overlap_m = _full_overlap_range(overlap, self._grid) if widening else np.inf
        if self.precip is not None:
            self._cum, self._d_min = self._drop_tables(self.precip)
        self._volume_pulses = self._volume_table()

    # -- tables, built once --------------------------------------------------------------------------
    def area(self, r: np.ndarray) -> np.ndarray:
        """The beam's cross-section S(r) (m^2) at range ``r`` (m)."""
        return np.pi * (self.exit_radius + np.asarray(r) * np.tan(0.5 * self.divergence)) ** 2

    def _drop_tables(self, m: Medium) -> tuple[np.ndarray, np.ndarray]:
        """On the range grid: the expected drops per beam from the start that are placed one by one (those that
        reach their range's share of the threshold alone), and that size limit (distribution diameter, m)."""
        r = self._grid
        s = self.area(r)
        per_sigma = self.power * np.pi / (s * np.maximum(r, MIN_RANGE_M) ** 2) * np.exp(-2.0 * self.alpha * r)
        per_d2 = float(np.median(m.sigma_back / np.maximum(m.diameters, 1e-12) ** 2))  # geometric optics: constant
        fraction = np.where(r <= NEAR_M, NEAR_FRACTION, INDIVIDUAL_FRACTION)
        d_min = np.sqrt(fraction * self.threshold / np.maximum(per_sigma, 1e-300) / per_d2)
        f = m.number_above(d_min) * s
        return np.concatenate([[0.0], np.cumsum(0.5 * (f[1:] + f[:-1]) * np.diff(r))]), d_min

    def _volume_table(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """(centres m, reflectance per unit sub-ray weight, its standard deviation from beam to beam, label) of
        the volume pulses of a beam without a hit, those that reach VOLUME_FLOOR of the threshold."""
        centres, width = self.volume.slabs(np.inf, spacing_m=self.volume.sigma_m, r_max_m=self.r_max)
        beta = np.zeros(len(centres))
        labels = np.zeros(len(centres), np.uint8)
        if self.precip is not None:  # the drops too small to be placed one by one
            beta += self.precip.beta_below(np.interp(centres, self._grid, self._d_min))
            labels[:] = LABELS[self.precip.kind]
        if self.fog is not None:
            beta += self.fog.beta
            labels[:] = LABELS["fog"]
        level = self.volume.density(centres) * beta * np.sqrt(2.0 * np.pi) * self.volume.sigma_m  # waveform (smooth)
        keep = level > VOLUME_FLOOR * self.threshold
        overlap = self.volume.overlap(centres)
        sd = np.zeros(len(centres))
        if self.fog is not None:  # the near field's droplets: compound Poisson (module doc)
            f = self.fog
            mean_s2 = float(np.sum(0.5 * (f.density[1:] * f.sigma_back[1:] ** 2 + f.density[:-1] * f.sigma_back[:-1] ** 2)
                                   * np.diff(f.diameters)))  # number x E[sigma^2], per m^3  # fmt: skip
            near = centres <= NEAR_M
            area = self.area(centres[near])
            # reflectance pi (summed sigma) / S: its sd pi sqrt(lam E[sigma^2]) / S, lam = number S h
            sd[near] = np.pi * np.sqrt(mean_s2 * area * width[near]) / area * overlap[near]
        # the slabs' extents, and the share of a reflectance the echo stage makes a peak of (the LIDAR equation
        # without C, overlap and weight): the AC coupling filters the peaks' density, not the reflectance
        r = np.maximum(centres, MIN_RANGE_M)
        self._slab_edges = (centres - 0.5 * width)[keep], (centres + 0.5 * width)[keep]
        self._slab_gain = (np.exp(-2.0 * self.alpha * r) / (r * r))[keep]
        return centres[keep], (np.pi * beta * width * overlap)[keep], sd[keep], labels[keep]

    # -- per batch -----------------------------------------------------------------------------------
    def scatterers(self, batch: RayBatch, rng: np.random.Generator) -> Scatterers | None:
        """Drops and volume pulses of the batch's beams in front of each beam's hit."""
        w = np.asarray(batch.weights, dtype=np.float64)
        core = int(np.argmax(w))
        hit = np.where(np.isfinite(batch.distance[:, core]), batch.distance[:, core], self.r_max)
        parts = [self._volume(hit, core, w[core], rng)]
        if self.precip is not None:
            parts.append(self._drops(hit, w, rng))
        return Scatterers.concatenate(parts)

    def _on_grid(self, x: np.ndarray, table: np.ndarray) -> np.ndarray:
        """``np.interp(x, self._grid, table)``, bit for bit, without its binary search (the grid is uniform)."""
        x = np.ascontiguousarray(x, dtype=np.float64)
        return _interp_uniform(x, float(self._grid[0]), GRID_M, self._grid, table, np.empty(len(x)))

    def _overlap(self, range_m: np.ndarray) -> np.ndarray:
        """O(r) at each of ``range_m`` (m): 1 from ``_full_overlap_m`` on, where the receiver's field of view holds
        the whole beam (there the overlap function gives exactly 1), the function itself nearer."""
        near = range_m < self._full_overlap_m
        if near.all():
            return self.volume.overlap(range_m)
        out = np.ones(len(range_m))
        out[near] = self.volume.overlap(range_m[near])
        return out

    def _volume(self, hit: np.ndarray, core: int, weight: float, rng: np.random.Generator) -> Scatterers | None:
        centres, refl, sd, labels = self._volume_pulses
        if not len(centres):
            return None
        beam, k = np.nonzero(centres[None, :] < hit[:, None])
        n = len(beam)
        reflectance = refl[k]
        varies = np.flatnonzero(sd[k] > 0)
        if len(varies):
            reflectance = reflectance.copy()
            reflectance[varies] = np.maximum(refl[k[varies]] + sd[k[varies]] * rng.standard_normal(len(varies)), 0.0)
        if self.tau > 0:
            (lower, upper), gain = self._slab_edges, self._slab_gain[k]
            reflectance = highpass_slabs(reflectance * gain, lower[k], upper[k], beam, self.tau) / gain
            kept = reflectance > 0
            beam, k, reflectance, n = beam[kept], k[kept], reflectance[kept], int(kept.sum())
        return Scatterers(beam=beam, subray=np.full(n, core), range_m=centres[k], reflectance=reflectance / weight,
                          occlusion=np.zeros(n), label=labels[k], object_id=np.zeros(n, np.uint32),
                          bypass_overlap=np.ones(n, bool))  # fmt: skip

    def _drops(self, hit: np.ndarray, w: np.ndarray, rng: np.random.Generator) -> Scatterers | None:
        m, r = self.precip, self._grid
        expected = self._on_grid(hit, self._cum)  # drops per beam in front of its hit
        beam = np.repeat(np.arange(len(hit)), rng.poisson(expected))
        if not len(beam):
            return None
        # ranges by the inverse of the cumulative count, each in front of its beam's hit
        rng_m = np.interp(rng.random(len(beam)) * expected[beam], self._cum, r)
        share = self._seen_share(rng_m, rng)
        seen = share > 0
        beam, rng_m, share = beam[seen], rng_m[seen], share[seen]
        diameter, sigma = m.sample(len(beam), rng, self._on_grid(rng_m, self._d_min))
        subray = rng.choice(len(w), size=len(beam), p=w / w.sum())
        patch = self.area(rng_m) * w[subray]
        optical = m.dsd.optical(diameter)
        n = len(beam)
        return Scatterers(beam=beam, subray=subray, range_m=rng_m, reflectance=np.pi * sigma * share / patch,
                          occlusion=np.clip(np.pi * optical**2 / 4.0 / patch, 0.0, 1.0),
                          label=np.full(n, LABELS[m.kind], np.uint8), object_id=np.zeros(n, np.uint32),
                          bypass_overlap=np.ones(n, bool))  # fmt: skip

    def _seen_share(self, range_m: np.ndarray, rng: np.random.Generator) -> np.ndarray:
        """The share of each drop's light (at ``range_m``, m) that reaches the detector. Cone overlap: a drop is in
        the receiver's view or not, so the share O(r) of them is seen, at full strength (1 or 0). Defocused
        overlap: each drop at a uniform place on the beam's disc gives the share of its blur disc on the field stop
        (:func:`lidar_weather_sim.physics.overlap.point_share`); its mean over the disc is O(r)."""
        if self.overlap_model == "cone" or self._optics is None:
            return (rng.random(len(range_m)) < self._overlap(range_m)).astype(np.float64)
        separation, fov, rx_radius = self._optics
        rho = (self.exit_radius + range_m * np.tan(0.5 * self.divergence)) * np.sqrt(rng.random(len(range_m)))
        phi = 2.0 * np.pi * rng.random(len(range_m))
        lateral = np.hypot(rho * np.cos(phi) - separation, rho * np.sin(phi))
        return point_share("defocus", lateral, range_m, fov, rx_radius)


def _full_overlap_range(overlap, grid: np.ndarray) -> float:
    """The range (m) from which the biaxial ``overlap`` of a receiver whose field of view widens at least as fast as
    the beam is exactly 1: once its disc holds the beam's it keeps holding it (checked on ``grid``'s points beyond);
    inf if it never does on the grid."""
    o = overlap(grid)
    below = np.flatnonzero(o < 1.0)
    if len(below) == len(grid):
        return np.inf
    start = grid[below[-1] + 1] if len(below) else grid[0]
    return float(start) if np.all(o[grid >= start] == 1.0) else np.inf


@numba.njit(cache=True, nogil=True)
def _interp_uniform(x, x0, h, xp, fp, out):
    """``np.interp(x, xp, fp)`` into ``out`` for ``xp`` = x0 + k h (k = 0, 1, ...): the interval from the step count,
    then numpy's own arithmetic (numpy/_core/src/multiarray/compiled_base.c, arr_interp), so the values are
    its values bit for bit."""
    n = len(xp)
    for i in range(len(x)):
        v = x[i]
        if np.isnan(v):
            out[i] = v
            continue
        if v < xp[0]:
            out[i] = fp[0]
            continue
        if v > xp[n - 1]:
            out[i] = fp[n - 1]
            continue
        j = min(max(int((v - x0) / h), 0), n - 1)
        while j > 0 and xp[j] > v:
            j -= 1
        while j < n - 1 and xp[j + 1] <= v:
            j += 1
        if j == n - 1 or xp[j] == v:
            out[i] = fp[j]
            continue
        slope = (fp[j + 1] - fp[j]) / (xp[j + 1] - xp[j])
        y = slope * (v - xp[j]) + fp[j]
        if np.isnan(y):
            y = slope * (v - xp[j + 1]) + fp[j + 1]
            if np.isnan(y) and fp[j] == fp[j + 1]:
                y = fp[j]
        out[i] = y
    return out
