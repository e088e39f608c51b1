"""A second, simplified fog generator, written apart from the fast atmosphere region and from the reference
(:mod:`lidar_weather_sim.references.droplets`): the method of Hahner, Sakaridis, Dai & Van Gool, "Fog Simulation
on Real LiDAR Point Clouds for 3D Object Detection in Adverse Weather", ICCV 2021, on the points of a clear
cloud (it needs no scene, only the points):

- **Hard target**: every return's received power is multiplied by ``exp(-2 alpha R)`` (their eq. 6-7:
  the hard target term keeps its form with the two-way Beer-Lambert loss), ``alpha = 3.912 / V``
  (Koschmieder; wavelength-independent as in the paper). On this project's receiver the power is the
  peak amplitude ``A``, recovered from each point's intensity with its pulse width from its EPW
  (:func:`~lidar_weather_sim.references.droplets.scene_pulses`);
  the attenuated return's intensity and EPW follow from ``A exp(-2 alpha R)`` on the profile's scales,
  so the intensity byte drops by ``255 * 2 alpha R / ln(intensity_dynamic_range)``; returns below the
  threshold are removed.
- **Soft target (fog)**: the fog's response ``S(r) = C pi beta int xi(r') exp(-2 alpha r') / r'^2 g(r - r') dr'``
  (their eq. 9-10; g the pulse, C the profile's power constant, ``beta = 0.046 / V`` 1/(m sr), the
  backscatter Hahner et al. take from Rasshofer et al. 2011), with their crossover function ``xi``
  rising linearly from 0 at R_1 to 1 at R_2 (here the profile's ``overlap_start_m`` and ``overlap_full_m``;
  0.9 m / 1.0 m when the profile has none). Its maximum lies a few metres ahead of the sensor and grows with
  alpha. Where it exceeds the attenuated hard return (and the threshold) and lies before it, the point
  becomes a fog point at the maximum's range plus Gaussian noise of one pulse sigma (the paper jitters
  the soft point), with the soft peak's intensity and EPW (label FOG).

Beams without a return stay empty (the method works on existing points only), as in the paper.

**Return mode.** Hahner et al. worked on a single-return sensor (a Velodyne HDL-64 reporting its strongest
echo), where the soft echo replaces the hard return it beats (the rule above). A sensor reporting every echo
(``detection.return_mode: all``, scala4's) reports both: there the soft echo is added to its beam as the first
echo when it beats the threshold and lies before the beam's nearest return, the hard returns above the
threshold stay as later echoes, and the nearest ``max_echoes`` are kept (echo numbers and return types
renumbered). A beam is a channel's firing: its points share channel and time stamp.
"""

from __future__ import annotations

import numpy as np

from lidar_weather_sim.core.points import Label, ReturnType
from lidar_weather_sim.references.droplets import epw_of, intensity_bytes, scene_pulses
from lidar_weather_sim.sensor.profile import SensorProfile
from lidar_weather_sim.sensor.radiometry import FWHM_TO_SIGMA, Threshold, dark_level

KOSCHMIEDER = 3.912
BETA_PER_INVERSE_V = 0.046  # beta = 0.046 / V (1/(m sr)), Rasshofer et al. 2011 as used by Hahner et al.
HAHNER_R1_M, HAHNER_R2_M = 0.9, 1.0


class HahnerFog:
    """Fog of visual range ``visual_range_m`` (m) on the clouds of ``profile`` (see module doc)."""

    def __init__(self, profile: SensorProfile, visual_range_m: float, *, sun_irradiance_w_m2: float = 0.0) -> None:
        if not visual_range_m > 0:
            raise ValueError(f"visual range must be > 0 m, got {visual_range_m}")
        self.profile = profile
        self.alpha = KOSCHMIEDER / visual_range_m
        self.beta = BETA_PER_INVERSE_V / visual_range_m
        self.threshold = Threshold.under_sun(profile.detection, sun_irradiance_w_m2).level
        self.dark = dark_level(profile.detection)
        self.log_span = float(np.log(profile.detection.intensity_dynamic_range))
        self.sigma = profile.pulse.fwhm_m * FWHM_TO_SIGMA
        o = profile.optics
        r1, r2 = (o.overlap_start_m, o.overlap_full_m) if o.overlap_full_m > o.overlap_start_m else (HAHNER_R1_M,
                                                                                                    HAHNER_R2_M)
        self.soft_range_m, self.soft_peak = self._soft_echo(r1, r2)

    def _soft_echo(self, r1: float, r2: float) -> tuple[float, float]:
        """(range m, peak amplitude) of the maximum of the fog's response S(r) (quadrature on a s/10 grid)."""
        dx = self.sigma / 10.0
        r = np.arange(1, int(60.0 / dx)) * dx  # the maximum lies within a few m (xi, 1/r^2)
        xi = np.clip((r - r1) / (r2 - r1), 0.0, 1.0)
        integrand = self.profile.detection.power_constant * np.pi * self.beta * xi * np.exp(-2 * self.alpha * r) / r**2
        k = np.arange(-50, 51) * dx
        g = np.exp(-0.5 * (k / self.sigma) ** 2)
        s = np.convolve(integrand * dx, g, mode="same")
        i = int(np.argmax(s))
        return float(r[i]), float(s[i])

    def apply(self, points: np.ndarray, rng: np.random.Generator) -> np.ndarray:
        """``points`` (the project's layout) in this fog: hard returns attenuated, soft echoes replacing them
        (single return) or added before them (return mode ``all``; module doc)."""
        d = points["distance"].astype(np.float64)
        hard, width = scene_pulses(points, self.threshold, self.sigma, self.dark, self.log_span)
        hard = hard * np.exp(-2.0 * self.alpha * d)
        if self.profile.detection.return_mode == "all":
            return self._every_echo(points, d, hard, width, rng)
        soft = (self.soft_peak > hard) & (self.soft_peak > self.threshold) & (self.soft_range_m < d)
        return self._write(points, hard, width, soft, soft | (hard > self.threshold), rng)

    def _every_echo(self, points, d, hard, width, rng) -> np.ndarray:
        """Return mode ``all``: each beam's soft echo before its returns, the hard returns above the threshold behind."""
        beam = points["channel"].astype(np.int64) << 32 | points["time_stamp"].astype(np.int64)
        keys, first, inverse = np.unique(beam, return_index=True, return_inverse=True)
        nearest = np.full(len(keys), np.inf)
        np.minimum.at(nearest, inverse, d)
        foggy = (self.soft_peak > self.threshold) & (self.soft_range_m < nearest)
        # the soft echo of a beam: a copy of one of its points (direction, channel, time), moved by _write
        rows = np.concatenate([np.flatnonzero(hard > self.threshold), first[foggy]])
        soft = np.zeros(len(rows), bool)
        soft[len(rows) - int(foggy.sum()):] = True
        out = self._write(points[rows], hard[rows], width[rows], soft, np.ones(len(rows), bool), rng)
        order = np.lexsort((out["distance"], beam[rows]))
        out, beam = out[order], beam[rows][order]
        start = np.searchsorted(beam, beam, side="left")
        rank = np.arange(len(out)) - start
        kept = rank < self.profile.detection.max_echoes
        out, beam, rank = out[kept], beam[kept], rank[kept]
        last = np.searchsorted(beam, beam, side="right") - 1 - np.searchsorted(beam, beam, side="left")
        if "echo" in (out.dtype.names or ()):
            out["echo"] = rank + 1
        if "return_type" in (out.dtype.names or ()):
            out["return_type"] = np.where(last == 0, ReturnType.IDENTICAL, np.where(
                rank == 0, ReturnType.FIRST, np.where(rank == last, ReturnType.LAST, ReturnType.SECOND)))  # fmt: skip
        return out

    def _write(self, points, hard, width, soft, keep, rng) -> np.ndarray:
        """The ``keep`` points of ``points``, ``soft`` ones as fog points at the soft echo, the rest with their
        attenuated peaks ``hard``."""
        out = points[keep].copy()
        hard, soft, width = hard[keep], soft[keep], width[keep]
        amp = np.where(soft, self.soft_peak, hard)
        out["intensity"] = intensity_bytes(amp, self.dark, self.log_span)
        if "epw" in (out.dtype.names or ()):
            out["epw"] = epw_of(amp, self.threshold, np.where(soft, self.sigma, width))
        if soft.any():
            old = np.maximum(out["distance"][soft].astype(np.float64), 1e-9)
            new = np.maximum(self.soft_range_m + rng.normal(0.0, self.sigma, int(soft.sum())), 1e-3)
            for axis in ("x", "y", "z"):
                out[axis][soft] = out[axis][soft] * (new / old)
            out["distance"][soft] = new
            if "label" in (out.dtype.names or ()):
                out["label"][soft] = Label.FOG
                out["object_id"][soft] = 0
        return out
