"""The atmosphere as physics per beam: the drops and the volume return of region ``atmosphere``.

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
  ``DETECTABLE_FRACTION`` of the threshold on their own (in full overlap, before extinction of the pulse's own
  path beyond r); diameters from the distribution above that size. The smaller drops join the volume. A drop
  of differential backscatter cross-section sigma (m^2/sr) on a sub-ray of weight w is a surface of reflectance
  ``pi sigma / (S(r) w)`` (its peak ``C pi sigma / (S(r) r^2)`` before extinction and overlap), blocking its
  geometric cross-section's share of that sub-ray;
- **the volume**: fog and the drops too small to be placed, as the echo stage's volume tables
  (:mod:`lidar_weather_sim.regions.air_volume`: the density ``C pi beta(r) O(r) exp(-2 alpha r) / r^2`` of
  :class:`lidar_weather_sim.regions.volume_return.VolumeReturn`, AC-coupled, convolved with the pulse), built
  once per weather state and read per beam up to its hit (the central sub-ray's scene hit); where its waveform
  stays below ``VOLUME_FLOOR`` of the threshold it is left out. In the near field (out to ``NEAR_M``) the fog
  fluctuates from beam to beam: a slab of one pulse sigma holds a Poisson number of droplets, so its summed
  cross-section is compound Poisson, mean ``lam E[sigma]``, variance ``lam E[sigma^2]`` (``lam`` the droplets
  in the slab's beam volume), drawn in its normal limit and clipped at 0, as the reference does for its cells;
  a bank of such near fields is drawn once per weather state and each beam reads one of them. A fog echo is
  flat-topped (metres wide): without this every beam of a channel put its peak on the same spot, where the
  droplets' own fluctuation moves it by tens of centimetres. Drops do not dim the volume behind them (each
  blocks ~1e-4 of the beam).

How much of the fog's backscatter a unit turns into detections is its own: ``fog_backscatter_gain`` (0-1)
scales the fog's backscatter (the volume's density and its near-field fluctuation alike) at every range, its
extinction untouched: 1 is the profile's optics alone (bit for bit), 0 a fog that is loss only (a unit whose
pulse discrimination, near-range gain or blanking keeps the fog's soft echoes out; no datum sizes it beyond
scala's; the gap search fits it with the fog). A DC-coupled receiver's fog echo is metres long (OS1 in fog 100 m:
12-16 m), so a gain limited to the first metres left most of it. The drops of rain and snow are not scaled.

The overlap O(r) is the profile's biaxial geometry (lens separation, receiver field of view, apertures) in its
``optics.overlap_model`` (:data:`lidar_weather_sim.physics.overlap.OVERLAP_MODELS`) where its optics give it,
else the echo stage's smoothstep; it is part of the volume's density. A drop is seen with probability
O(r) at full strength (``cone``: in the receiver's view or not), or, ``defocus``, always with the share of its
light the field stop takes at its place on the beam's disc (``bypass_overlap``: the echo stage does not apply
its own). The threshold is the dark one (no sun). This is the
model :mod:`lidar_weather_sim.references.droplets` computes slowly, drop by drop, with a geometric overlap and
fog droplet statistics: the fast model is checked against it (``benchmarks/validation/atmosphere_reference.py``). Not modelled: multiple scattering, the fog's fluctuation beyond the near field
(the reference's quadrature there is smooth too).
"""

from __future__ import annotations

from functools import cache, cached_property, partial


import numba
import numpy as np

from lidar_weather_sim.core.points import Label
from lidar_weather_sim.physics.coefficients import Medium, medium
from lidar_weather_sim.physics.overlap import OVERLAP_MODELS, point_share
from lidar_weather_sim.regions.air_volume import AirVolume, air_volume, optics_overlap
from lidar_weather_sim.regions.base import RayBatch, Scatterers, VolumeTerm
from lidar_weather_sim.regions.volume_return import VolumeReturn
from lidar_weather_sim.sensor.radiometry import FWHM_TO_SIGMA, MIN_RANGE_M, dark_level

NEAR_M = 5.0  # the near field (m), as the reference's: there the fog's droplets fluctuate from beam to beam
DETECTABLE_FRACTION = 0.5  # drops reaching this share of the threshold alone are placed; the smaller join the volume
VOLUME_FLOOR = 0.02  # the volume's waveform below this share of the threshold is left out
DEFAULT_WAVELENGTH_NM = 905.0
GRID_M = 0.02  # the range grid of the per-beam drop volumes (m)
BOUND_POINTS = 17  # values of the overlap per grid cell that bound it there (drops in the receiver's view or not)
MIN_EXIT_RADIUS_M = 1e-3  # a beam's exit radius at least (m): a profile of no aperture and no divergence has no
# volume to hold drops (the shipped profiles' exits are 2-5 mm)
#: the seed of the near field's realisations, the same for every weather state (common random numbers): a fog's
#: near field then changes smoothly with its visual range. Seeded by the weather's values, the realisations changed
#: with every change of the visual range, and the gap search's fit gap with them (seeded draw case 14, fog 278.6 m
#: with a sun: -0.0298 at 278.6 m, -0.0123 at 278.6000001 m)
VOLUME_SEED = 0x766F6C
LABELS = {"fog": Label.FOG, "rain": Label.RAIN, "snow": Label.SNOW}


class PhysicalAir:
    """Fog (visual range m, or None) and precipitation ((``rain`` | ``snow``, mm/h), or None) seen by ``profile``."""

    def __init__(self, profile, fog_visual_range_m: float | None, precipitation: tuple[str, float] | None,
                 fog_backscatter_gain: float = 1.0) -> None:
        """``fog_backscatter_gain`` (0-1): the share of the fog's backscatter the receiver turns into signal, at
        every range (module doc); 1 is the profile's optics alone."""
        if not 0.0 <= fog_backscatter_gain <= 1.0:
            raise ValueError(f"fog_backscatter_gain: must be within [0, 1], got {fog_backscatter_gain:g}")
        self.fog_gain = float(fog_backscatter_gain)
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
        self.exit_radius = max(float(o.tx_aperture_radius_m), MIN_EXIT_RADIUS_M)
        overlap, self._optics = None, None  # (lens separation m, receiver FOV rad, aperture radius m)
        self.overlap_model = o.overlap_model
        if o.lens_separation_m is not None and o.receiver_fov_mrad is not None:
            overlap = partial(OVERLAP_MODELS[o.overlap_model], separation_m=o.lens_separation_m,
                              divergence_rad=self.divergence, fov_rad=1e-3 * o.receiver_fov_mrad,
                              tx_radius_m=o.tx_aperture_radius_m, rx_radius_m=o.rx_aperture_radius_m)  # fmt: skip
            self._optics = (o.lens_separation_m, 1e-3 * o.receiver_fov_mrad, o.rx_aperture_radius_m)
        start = 0.0 if overlap is not None else o.overlap_start_m
        sigma = profile.pulse.fwhm_m * FWHM_TO_SIGMA
        self.volume = VolumeReturn(self.power, self.alpha, 1.0, sigma, start, o.overlap_full_m, overlap)
        self._grid = np.arange(max(start, MIN_RANGE_M), self.r_max + GRID_M, GRID_M)
        widening = overlap is not None and 1e-3 * o.receiver_fov_mrad >= self.divergence  # the view holds the beam
        self._full_overlap_m = (_full_overlap_range(o.overlap_model, float(self._grid[0]), self.r_max,
                                                    **overlap.keywords) if widening else np.inf)  # fmt: skip
        if self.precip is not None:
            self._cum, self._d_min = self._drop_tables(self.precip)
            self._cum_index = bucket_index(self._cum)
        sampled = None if overlap is None else optics_overlap(o.overlap_model, self.r_max, **overlap.keywords)
        self._sampled = VolumeReturn(self.power, self.alpha, 1.0, sigma, start, o.overlap_full_m, sampled)
        self.air_volume = self._air_volume(float(self._grid[0]))

    # -- tables, built once --------------------------------------------------------------------------
    def area(self, r: np.ndarray) -> np.ndarray:
        """The beam's cross-section S(r) (m^2) at range ``r`` (m)."""
        return np.pi * (self.exit_radius + np.asarray(r) * np.tan(0.5 * self.divergence)) ** 2

    def _drop_tables(self, m: Medium) -> tuple[np.ndarray, np.ndarray]:
        """On the range grid: the expected drops per beam from the start that are placed one by one (those that
        reach DETECTABLE_FRACTION of the threshold alone, in full overlap), and that size limit (distribution
        diameter, m)."""
        r = self._grid
        s = self.area(r)
        per_sigma = self.power * np.pi / (s * np.maximum(r, MIN_RANGE_M) ** 2) * np.exp(-2.0 * self.alpha * r)
        per_d2 = float(np.median(m.sigma_back / np.maximum(m.diameters, 1e-12) ** 2))  # geometric optics: constant
        d_min = np.sqrt(DETECTABLE_FRACTION * self.threshold / np.maximum(per_sigma, 1e-300) / per_d2)
        f = m.number_above(d_min) * s
        return np.concatenate([[0.0], np.cumsum(0.5 * (f[1:] + f[:-1]) * np.diff(r))]), d_min

    @cached_property
    def _overlap_bounds(self) -> tuple[np.ndarray, np.ndarray]:
        """Per cell [r_k, r_k + GRID_M) of the range grid: bounds (lower, upper) on O(r) over it and its two
        neighbours, from :data:`BOUND_POINTS` values per cell, widened by the largest step between two of them
        (a drop's cell is found by a division that may put it one off), so that a uniform draw below the lower
        or at the upper decides u < O(r) as O(r) itself does."""
        sub = self._grid[:, None] + GRID_M * np.linspace(0.0, 1.0, BOUND_POINTS)[None, :]
        o = self._overlap(sub.ravel()).reshape(sub.shape)
        step = np.abs(np.diff(o, axis=1)).max(axis=1)
        lo, hi = o.min(axis=1) - step, o.max(axis=1) + step
        lo = np.minimum(np.minimum(lo, np.roll(lo, 1)), np.roll(lo, -1))
        hi = np.maximum(np.maximum(hi, np.roll(hi, 1)), np.roll(hi, -1))
        lo[[0, -1]], hi[[0, -1]] = -1.0, 2.0  # the grid's ends: left open
        return lo, hi

    def beta(self, range_m: np.ndarray) -> np.ndarray:
        """The volume's backscatter (1/(m sr)) at ``range_m`` (m) that the receiver sees: the fog's (times
        ``fog_gain``) and the drops' too small to be placed."""
        beta = np.zeros(np.shape(range_m))
        if self.precip is not None:
            beta += self.precip.beta_below(np.interp(range_m, self._grid, self._d_min))
        if self.fog is not None:
            beta += self.fog_gain * self.fog.beta
        return beta

    def _air_volume(self, start_m: float) -> AirVolume:
        """The volume's tables: its mean ``C pi beta(r) O(r) exp(-2 alpha r) / r^2`` and, with fog, the near field's
        slabs of one pulse sigma, each fluctuating with the droplets in it (module doc), seeded by :data:`VOLUME_SEED`."""
        edges, rel_sd = np.zeros(0), np.zeros(0)
        if self.fog is not None and self.fog_gain > 0.0:
            f = self.fog
            mean_s2 = float(np.sum(0.5 * (f.density[1:] * f.sigma_back[1:] ** 2 + f.density[:-1] * f.sigma_back[:-1] ** 2)
                                   * np.diff(f.diameters)))  # number x E[sigma^2], per m^3  # fmt: skip
            centres, width = self.volume.slabs(np.inf, spacing_m=self.volume.sigma_m, r_max_m=self.r_max)
            near = centres <= NEAR_M
            centres, width = centres[near], width[near]
            edges = np.append(centres - 0.5 * width, centres[-1] + 0.5 * width[-1]) if len(centres) else edges
            # summed sigma over a slab's beam volume S h: mean beta S h, variance lam E[sigma^2] = mean_s2 S h (the
            # fog's share scaled by its gain)
            rel_sd = self.fog_gain * np.sqrt(mean_s2 / (self.area(centres) * width)) / self.beta(centres)
        kind = "fog" if self.fog is not None or self.precip is None else self.precip.kind
        return air_volume(lambda r: self._sampled.density(r) * self.beta(r), sigma_m=self.volume.sigma_m,
                          r_max_m=self.r_max, start_m=start_m, tau_m=self.tau, floor=VOLUME_FLOOR * self.threshold,
                          label=LABELS[kind], slab_edges=edges, rel_sd=rel_sd,
                          seed=[VOLUME_SEED])  # fmt: skip

    # -- per batch -----------------------------------------------------------------------------------
    def scatterers(self, batch: RayBatch, rng: np.random.Generator) -> tuple[Scatterers | None, list[VolumeTerm]]:
        """The drops placed one by one in front of each beam's hit, and the volume's layers on the batch's beams."""
        terms = self.air_volume.terms(batch.shape[0], rng)
        if self.precip is None:
            return None, terms
        w = np.asarray(batch.weights, dtype=np.float64)
        core = int(np.argmax(w))
        hit = np.where(np.isfinite(batch.distance[:, core]), batch.distance[:, core], self.r_max)
        return self._drops(hit, w, rng), terms

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

    def _drops(self, hit: np.ndarray, w: np.ndarray, rng: np.random.Generator) -> Scatterers | None:
        m, r = self.precip, self._grid
        expected = self._on_grid(hit, self._cum)  # drops per beam in front of its hit
        beam = np.repeat(np.arange(len(hit)), rng.poisson(expected))
        if not len(beam):
            return None
        # ranges by the inverse of the cumulative count, each in front of its beam's hit
        x = rng.random(len(beam)) * expected[beam]
        rng_m = _interp_sorted(x, self._cum, r, *self._cum_index, np.empty(len(beam)))
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
            u = rng.random(len(range_m))
            lo, hi = self._overlap_bounds
            seen = np.empty(len(range_m))
            if _seen_by_bounds(u, range_m, float(self._grid[0]), GRID_M, lo, hi, seen):
                left = np.flatnonzero(seen < 0.0)
                seen[left] = u[left] < self._overlap(range_m[left])
            return seen
        separation, fov, rx_radius = self._optics
        rho = (self.exit_radius + range_m * np.tan(0.5 * self.divergence)) * np.sqrt(rng.random(len(range_m)))
        phi = 2.0 * np.pi * rng.random(len(range_m))
        lateral = np.hypot(rho * np.cos(phi) - separation, rho * np.sin(phi))
        return point_share("defocus", lateral, range_m, fov, rx_radius)


@cache
def _full_overlap_range(model: str, start_m: float, r_max_m: float, **optics: float) -> float:
    """The range (m) from which the biaxial overlap ``OVERLAP_MODELS[model]`` with ``optics`` (its keyword arguments)
    of a receiver whose field of view widens at least as fast as the beam is exactly 1: once its disc holds the
    beam's it keeps holding it (checked on the range grid's points from ``start_m`` to ``r_max_m``, m, beyond);
    inf if it never does on the grid. Computed once per optics."""
    grid = np.arange(start_m, r_max_m + GRID_M, GRID_M)
    o = OVERLAP_MODELS[model](grid, **optics)
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
        out[i] = _numpy_interp_at(v, j, xp, fp)
    return out


def bucket_index(xp: np.ndarray) -> tuple[np.ndarray, float]:
    """For :func:`_interp_sorted` on the non-decreasing ``xp`` (>= 0): per bucket [b h, (b + 1) h) of len(xp)
    equal buckets of [0, xp[-1]], the last index j with xp[j] <= b h (-1: none), and 1 / h."""
    m = len(xp)
    h = float(xp[-1]) / m if m and xp[-1] > 0 else 1.0
    return np.searchsorted(xp, h * np.arange(m + 1), side="right").astype(np.int64) - 1, 1.0 / h


@numba.njit(cache=True, nogil=True)
def _interp_sorted(x, xp, fp, index, inv_h, out):
    """``np.interp(x, xp, fp)`` into ``out`` for a non-decreasing ``xp``: the last j with xp[j] <= x by bisection
    between the bounds of x's bucket (``index``, ``inv_h``: :func:`bucket_index`), then numpy's own arithmetic, so
    the values are its values bit for bit."""
    n, m = len(xp), len(index) - 1
    for i in range(len(x)):
        v = x[i]
        if np.isnan(v):
            out[i] = v
        elif v < xp[0]:
            out[i] = fp[0]
        elif v > xp[n - 1]:
            out[i] = fp[n - 1]
        else:
            b = min(max(int(v * inv_h), 0), m - 1)
            lo, hi = max(index[b], 0), min(index[b + 1] + 1, n - 1)
            if xp[lo] > v or (hi < n - 1 and xp[hi + 1] <= v):
                lo, hi = 0, n - 1  # the bucket's bounds miss v (its division rounded the other way): all of xp
            while lo < hi:  # the last index in [lo, hi] with xp <= v
                mid = (lo + hi + 1) >> 1
                if xp[mid] <= v:
                    lo = mid
                else:
                    hi = mid - 1
            out[i] = _numpy_interp_at(v, lo, xp, fp)
    return out


@numba.njit(cache=True, inline="always")
def _numpy_interp_at(v, j, xp, fp):
    """``np.interp``'s value at ``v`` in [xp[j], xp[j + 1]) (numpy/_core/src/multiarray/compiled_base.c,
    arr_interp): fp[j] at the last point or on a point, else the line through j and j + 1, from the other end
    where that is not a number."""
    if j == len(xp) - 1 or xp[j] == v:
        return fp[j]
    slope = (fp[j + 1] - fp[j]) / (xp[j + 1] - xp[j])
    y = slope * (v - xp[j]) + fp[j]
    if np.isnan(y):
        y = slope * (v - xp[j + 1]) + fp[j + 1]
        if np.isnan(y) and fp[j] == fp[j + 1]:
            y = fp[j]
    return y


@numba.njit(cache=True, nogil=True)
def _seen_by_bounds(u, range_m, x0, h, lo, hi, out):
    """Where the bounds decide it, whether each drop (uniform draw ``u``, range ``range_m`` m) is seen (1.0) or not
    (0.0), u < O(r), into ``out``; -1.0 where they do not. ``lo``, ``hi``: bounds on O over the cells
    [x0 + k h, x0 + (k + 1) h) and their neighbours. Returns how many are left open."""
    n = len(lo)
    open_ = 0
    for i in range(len(u)):
        k = int(np.floor((range_m[i] - x0) / h))
        if 0 <= k < n and u[i] < lo[k]:
            out[i] = 1.0
        elif 0 <= k < n and u[i] >= hi[k]:
            out[i] = 0.0
        else:
            out[i] = -1.0
            open_ += 1
    return open_
