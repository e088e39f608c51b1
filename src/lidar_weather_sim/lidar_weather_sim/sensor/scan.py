"""Scan pattern: which beams fire when, and the sub-ray directions of each beam.

Precomputed once per profile: for every column its firing time within the
frame (s) and azimuth; for every channel its elevation; for every sub-ray its
angular offset inside the beam divergence and its share of the beam energy
(Gaussian beam, divergence = full 1/e^2 width). Directions are unit vectors in
the sensor frame (REP-103). The sub-ray directions of every column are computed
once per set of active channels (:meth:`ScanPattern.direction_table`) and
sliced per batch.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from lidar_weather_sim.sensor.profile import SensorProfile


@dataclass(frozen=True)
class ColumnBatch:
    """Rays of a run of columns of one frame, shaped (columns, channels, sub-rays)."""

    columns: np.ndarray  # (C,) column indices
    time_s: np.ndarray  # (C,) firing time after the frame start (s)
    channels: np.ndarray  # (B,) active channel numbers
    directions: np.ndarray  # (C, B, S, 3) float64 unit vectors, sensor frame (read-only)
    weights: np.ndarray  # (S,) share of the beam energy per sub-ray, sums to 1


def _subray_offsets(count: int, divergence_rad: float) -> tuple[np.ndarray, np.ndarray]:
    """Angular offsets (rad) of ``count`` sub-rays across a Gaussian beam and their 1D weights.

    Each sub-ray stands for an equal-width slice of [-div, +div] (two 1/e^2
    half-widths, 95 % of the power of a Gaussian whose 1/e^2 full width is
    ``divergence_rad``); its weight is the Gaussian power in that slice.
    """
    if count == 1 or divergence_rad == 0.0:
        return np.zeros(1), np.ones(1)
    from scipy.special import erf

    edges = np.linspace(-divergence_rad, divergence_rad, count + 1)
    centres = 0.5 * (edges[:-1] + edges[1:])
    w0 = 0.5 * divergence_rad  # 1/e^2 intensity radius
    cdf = 0.5 * (1.0 + erf(np.sqrt(2.0) * edges / w0))
    weights = np.diff(cdf)
    return centres, weights / weights.sum()


class ScanPattern:
    """Firing geometry and timing of one sensor profile."""

    def __init__(self, profile: SensorProfile) -> None:
        self.profile = profile
        scan = profile.scan
        order = profile.channel_order
        self.elevation = np.deg2rad([profile.beams[i].elevation_deg for i in order])  # per channel
        self.azimuth_offset = np.deg2rad([profile.beams[i].azimuth_offset_deg for i in order])
        self.n_channels = len(order)
        self.n_columns = scan.columns
        lo, hi = np.deg2rad(scan.azimuth_min_deg), np.deg2rad(scan.azimuth_max_deg)
        step = (hi - lo) / scan.columns
        centres = lo + (np.arange(scan.columns) + 0.5) * step
        # cw seen from above sweeps from the left edge (max azimuth) to the right edge.
        self.column_azimuth = centres[::-1] if scan.direction == "cw" else centres
        self.sweep_s = profile.period_s * scan.sweep_fraction
        self.column_time_s = np.arange(scan.columns) * (self.sweep_s / scan.columns)
        optics = profile.optics
        dh, wh = _subray_offsets(optics.subrays_h, 1e-3 * optics.divergence_h_mrad)
        dv, wv = _subray_offsets(optics.subrays_v, 1e-3 * optics.divergence_v_mrad)
        self.subray_dh = np.repeat(dh, len(dv))
        self.subray_dv = np.tile(dv, len(dh))
        self.subray_weight = np.outer(wh, wv).ravel()
        self.n_subrays = len(self.subray_weight)
        self._tables: dict[tuple[int, ...], np.ndarray] = {}
        schedule = profile.scan.layer_schedule or [range(self.n_channels)]
        self._channels = [np.array(sorted(layers), dtype=np.int64) for layers in schedule]
        for channels in self._channels:
            channels.flags.writeable = False

    def active_channels(self, frame_index: int) -> np.ndarray:
        """Channel numbers fired in frame ``frame_index``, ascending (read-only, shared)."""
        return self._channels[frame_index % len(self._channels)]

    def rays_per_frame(self, frame_index: int = 0) -> int:
        return self.n_columns * len(self.active_channels(frame_index)) * self.n_subrays

    def columns_between(self, t0_s: float, t1_s: float) -> np.ndarray:
        """Columns whose firing time t (s after the frame start) satisfies t0 <= t < t1."""
        return np.arange(
            np.searchsorted(self.column_time_s, t0_s, side="left"),
            np.searchsorted(self.column_time_s, t1_s, side="left"),
        )

    def direction_table(self, frame_index: int) -> np.ndarray:
        """Sensor-frame sub-ray directions of every column for the channels active in frame
        ``frame_index``: (columns, active channels, sub-rays, 3) float64, read-only, cached."""
        channels = self.active_channels(frame_index)
        key = tuple(channels.tolist())
        table = self._tables.get(key)
        if table is None:
            az = (
                self.column_azimuth[:, None, None]
                + self.azimuth_offset[channels][None, :, None]
                + self.subray_dh[None, None, :]
            )
            el = np.broadcast_to(self.elevation[channels][None, :, None] + self.subray_dv[None, None, :], az.shape)
            cos_el = np.cos(el)
            table = np.stack([cos_el * np.cos(az), cos_el * np.sin(az), np.sin(el)], axis=-1)
            table.flags.writeable = False
            self._tables[key] = table
        return table

    def batch(self, frame_index: int, columns: np.ndarray) -> ColumnBatch:
        """Sensor-frame sub-ray directions of ``columns`` of frame ``frame_index``."""
        columns = np.asarray(columns)
        table = self.direction_table(frame_index)
        if len(columns) and np.all(np.diff(columns) == 1):
            directions = table[columns[0] : columns[-1] + 1]  # a view: no copy for a run of columns
        else:
            directions = table[columns]
        return ColumnBatch(
            columns, self.column_time_s[columns], self.active_channels(frame_index), directions, self.subray_weight
        )
