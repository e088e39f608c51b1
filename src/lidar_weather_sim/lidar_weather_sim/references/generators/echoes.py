"""Reading and writing returns in the project's point layout, for the fixed generators (no weather physics).

Received power is handled as the log ratio ``L = ln(A / T)`` of a return's peak amplitude ``A`` over the
detection threshold ``T`` (no background light). The profile's intensity byte is logarithmic in that ratio:
``I = 255 L / ln(DR)`` (``DR`` the profile's ``detection.intensity_dynamic_range``), so byte 0 is the threshold
and a return is detected while ``L >= 0``. A saturated byte (255) is a lower bound: where the cloud has EPW the
larger ``L`` of an isolated Gaussian pulse of the profile's width, ``(EPW / 2s)^2 / 2``, is taken. A pulse of
Gaussian sigma ``s`` (m) over the threshold has ``EPW = 2 s sqrt(2 L)``.

A beam is one channel's firing: its returns share ``channel`` and ``time_stamp``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from lidar_weather_sim.core.points import ReturnType

FWHM_PER_SIGMA = 2.0 * np.sqrt(2.0 * np.log(2.0))


@dataclass(frozen=True)
class Receiver:
    """What the generators need of a sensor: ``threshold`` (noise units, ``mu + x sigma`` without background
    light), ``log_span`` (ln of the intensity dynamic range), ``pulse_sigma_m`` (m), ``power_constant`` (noise
    units m^2: a Lambertian surface of reflectance rho at R m gives ``C rho / R^2``), ``divergence_rad`` (full
    beam divergence, geometric mean of the two axes), ``aperture_m`` (beam diameter at the sensor),
    ``overlap_start_m`` / ``overlap_full_m`` (receiver overlap, linear between), ``min_range_m`` (closest
    reported range), ``return_mode`` and ``max_echoes``."""

    threshold: float
    log_span: float
    pulse_sigma_m: float
    power_constant: float
    divergence_rad: float
    aperture_m: float
    overlap_start_m: float
    overlap_full_m: float
    min_range_m: float
    return_mode: str
    max_echoes: int

    @classmethod
    def of(cls, profile) -> "Receiver":
        """The receiver of a sensor profile (:class:`lidar_weather_sim.sensor.profile.SensorProfile`)."""
        d, o = profile.detection, profile.optics
        return cls(d.noise_mean + d.threshold_sigma * d.noise_sigma, float(np.log(d.intensity_dynamic_range)),
                   profile.pulse.fwhm_m / FWHM_PER_SIGMA, d.power_constant,
                   float(np.sqrt(o.divergence_h_mrad * o.divergence_v_mrad)) * 1e-3, 2.0 * o.tx_aperture_radius_m,
                   o.overlap_start_m, o.overlap_full_m, profile.range.min_m, d.return_mode, d.max_echoes)  # fmt: skip

    def overlap(self, r: np.ndarray) -> np.ndarray:
        """Receiver overlap 0-1 at range ``r`` (m): 0 before the start, linear to 1 at full overlap."""
        if self.overlap_full_m <= self.overlap_start_m:
            return (np.asarray(r) >= self.overlap_start_m).astype(np.float64)
        return np.clip((np.asarray(r) - self.overlap_start_m) / (self.overlap_full_m - self.overlap_start_m), 0, 1)


def log_ratio(points: np.ndarray, rx: Receiver) -> np.ndarray:
    """``ln(A / T)`` of every point (module doc)."""
    ratio = points["intensity"].astype(np.float64) / 255.0 * rx.log_span
    if "epw" in (points.dtype.names or ()):
        from_width = 0.5 * (points["epw"].astype(np.float64) / (2.0 * rx.pulse_sigma_m)) ** 2
        ratio = np.where(points["intensity"] >= 255, np.maximum(ratio, from_width), ratio)
    return ratio


def attenuate(points: np.ndarray, loss: np.ndarray | float, rx: Receiver) -> np.ndarray:
    """``points`` with each received power multiplied by ``exp(-loss)``: those left at ``L >= 0`` kept, their
    intensity and EPW lowered (the EPW keeps the width its point implies: ``EPW sqrt(L / L0)``)."""
    before = log_ratio(points, rx)
    after = before - np.broadcast_to(np.asarray(loss, np.float64), before.shape)
    keep = after >= 0.0
    out = points[keep].copy()
    before, after = before[keep], after[keep]
    out["intensity"] = intensity_of(after, rx)
    if "epw" in (out.dtype.names or ()):
        scale = np.sqrt(np.divide(after, before, out=np.zeros_like(after), where=before > 0))
        out["epw"] = out["epw"] * scale
    return out


def intensity_of(ratio: np.ndarray, rx: Receiver) -> np.ndarray:
    """Intensity byte of log ratios ``ratio`` (rounded, clipped to 0-255)."""
    return np.clip(np.rint(255.0 * ratio / rx.log_span), 0, 255).astype(np.uint8)


def beam_keys(points: np.ndarray) -> np.ndarray:
    """One int64 key per beam (channel, time stamp) for every point."""
    return points["channel"].astype(np.int64) << 32 | points["time_stamp"].astype(np.int64)


def beam_rows(points: np.ndarray) -> np.ndarray:
    """The row of one point of each beam of ``points``, beams in key order."""
    return np.unique(beam_keys(points), return_index=True)[1]


def nearest_on_beam(cloud: np.ndarray, probe: np.ndarray) -> np.ndarray:
    """(m) the nearest range of ``cloud`` on each ``probe`` point's beam, inf where ``cloud`` has none there."""
    keys, inverse = np.unique(beam_keys(cloud), return_inverse=True)
    nearest = np.full(len(keys) + 1, np.inf)
    np.minimum.at(nearest, inverse, cloud["distance"].astype(np.float64))
    wanted = beam_keys(probe)
    at = np.minimum(np.searchsorted(keys, wanted), len(keys))
    found = np.zeros(len(probe), bool)
    found[at < len(keys)] = keys[at[at < len(keys)]] == wanted[at < len(keys)]
    return np.where(found, nearest[at], np.inf)


def echoes_at(points: np.ndarray, rows: np.ndarray, ranges_m: np.ndarray, ratio: np.ndarray, label: int,
              rx: Receiver) -> np.ndarray:  # fmt: skip
    """New returns along the beams of ``points[rows]`` at ``ranges_m`` (m) with log ratios ``ratio``: isolated
    pulses of the profile's width, labelled ``label`` where the layout has labels."""
    out = points[rows].copy()
    old = np.maximum(out["distance"].astype(np.float64), 1e-9)
    for axis in ("x", "y", "z"):
        out[axis] = out[axis] * (ranges_m / old)
    out["distance"] = ranges_m
    out["intensity"] = intensity_of(ratio, rx)
    if "epw" in (out.dtype.names or ()):
        out["epw"] = 2.0 * rx.pulse_sigma_m * np.sqrt(2.0 * np.maximum(ratio, 0.0))
    if "label" in (out.dtype.names or ()):
        out["label"] = label
        out["object_id"] = 0
    return out


def merge(hard: np.ndarray, added: np.ndarray, rx: Receiver) -> np.ndarray:
    """The returns each beam reports of ``hard`` and ``added`` together under the receiver's return mode:
    ``all`` the nearest ``max_echoes``, ``first`` / ``last`` / ``strongest`` one each; echo numbers and
    return types renumbered by range."""
    if rx.return_mode not in ("all", "first", "last", "strongest"):
        raise ValueError(f"return mode {rx.return_mode!r}: the fixed generators report all, first, last or strongest")
    cloud = np.concatenate([hard, added])
    beam = beam_keys(cloud)
    order = np.lexsort((cloud["distance"], beam))
    cloud, beam = cloud[order], beam[order]
    start = np.searchsorted(beam, beam, side="left")
    end = np.searchsorted(beam, beam, side="right")
    rank, count = np.arange(len(cloud)) - start, end - start
    if "echo" in (cloud.dtype.names or ()):
        cloud["echo"] = rank + 1
    if rx.return_mode == "all":
        kept = rank < rx.max_echoes
        cloud, rank, last = cloud[kept], rank[kept], np.minimum(count[kept], rx.max_echoes) - 1
        if "return_type" in (cloud.dtype.names or ()):
            cloud["return_type"] = np.where(last == 0, ReturnType.IDENTICAL, np.where(
                rank == 0, ReturnType.FIRST, np.where(rank == last, ReturnType.LAST, ReturnType.SECOND)))  # fmt: skip
        return cloud
    if rx.return_mode == "first":
        pick, code = rank == 0, ReturnType.FIRST
    elif rx.return_mode == "last":
        pick, code = rank == count - 1, ReturnType.LAST
    else:
        strongest = np.full(len(cloud), -1, np.int64)
        np.maximum.at(strongest, start, cloud["intensity"].astype(np.int64))
        first_best = np.flatnonzero(cloud["intensity"] == strongest[start])
        pick = np.zeros(len(cloud), bool)
        pick[first_best[np.unique(start[first_best], return_index=True)[1]]] = True
        code = ReturnType.STRONGEST
    cloud = cloud[pick]
    if "return_type" in (cloud.dtype.names or ()):
        cloud["return_type"] = code
    return cloud
