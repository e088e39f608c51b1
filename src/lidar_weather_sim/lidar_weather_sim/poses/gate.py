"""Plausibility gate for a pose stream (odometry): outliers are skipped before they reach the transform buffer.

An interpolating buffer turns one bad sample into wrong poses for every column
cast between its neighbours, so a sample is refused when its stamp lies more
than ``max_gap_s`` from the last accepted one, or when reaching its position
from the last accepted one needs more than ``max_speed_m_s``. A genuine jump
(a bag loop or seek, a reset of the odometry) is accepted once a second sample
confirms it: within ``max_gap_s`` of the refused one and plausible from it.
Stamps in ns, positions in m in the fixed frame. No ROS import.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

MIN_DT_S = 1e-3  # repeated stamps: speed over at least this interval


@dataclass
class _Sample:
    stamp_ns: int
    position: np.ndarray


class PoseGate:
    def __init__(self, max_gap_s: float = 1.0, max_speed_m_s: float = 100.0) -> None:
        if max_gap_s <= 0 or max_speed_m_s <= 0:
            raise ValueError(f"max_gap_s ({max_gap_s}) and max_speed_m_s ({max_speed_m_s}) must be positive")
        self.max_gap_s, self.max_speed_m_s = float(max_gap_s), float(max_speed_m_s)
        self._last: _Sample | None = None
        self._pending: _Sample | None = None  # a refused jump, waiting for confirmation
        self.jumped = False  # the last accepted sample confirmed a jump: restart what depends on continuity

    def _why_not(self, ref: _Sample, sample: _Sample) -> str | None:
        dt = abs(sample.stamp_ns - ref.stamp_ns) * 1e-9
        if dt > self.max_gap_s:
            return f"stamp jumps {(sample.stamp_ns - ref.stamp_ns) * 1e-9:+.3f} s (max_gap_s {self.max_gap_s:g})"
        speed = float(np.linalg.norm(sample.position - ref.position)) / max(dt, MIN_DT_S)
        if speed > self.max_speed_m_s:
            return f"position implies {speed:.3g} m/s (max_speed_m_s {self.max_speed_m_s:g})"
        return None

    def check(self, stamp_ns: int, position) -> str | None:
        """None if the sample is accepted (and becomes the reference), else why it is refused."""
        sample = _Sample(int(stamp_ns), np.asarray(position, dtype=np.float64))
        self.jumped = False
        if self._last is None:
            self._last = sample
            return None
        why = self._why_not(self._last, sample)
        if why is None:
            self._last, self._pending = sample, None
            return None
        if self._pending is not None and self._why_not(self._pending, sample) is None:
            self._last, self._pending, self.jumped = sample, None, True
            return None
        self._pending = sample
        return why

