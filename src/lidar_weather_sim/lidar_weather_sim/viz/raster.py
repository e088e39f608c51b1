"""Points into palette-index images with numpy: a bird's-eye view and a range image (no per-point loop).

Bird's-eye view (:class:`BevView`): looking down the sensor frame's z axis, x forward is up in the
image and y left is left; the sensor (origin) sits at pixel (:attr:`BevView.origin_px`). A pixel is
``metres_per_px`` wide; where several points fall in one pixel the highest (largest z) is drawn (a
z-buffer: one sort of the key pixel * 2^16 + quantised z).

Range image (:class:`RangeView`): one row per ``channel`` (channel 0, the lowest beam, at the bottom),
one column per azimuth bin (left = larger azimuth = the sensor's left, as seen from the sensor); where
several returns fall in one cell (echoes of a beam, neighbouring firings) the nearest is drawn.

Points in a cell beyond the image are dropped. ``grow`` widens each drawn pixel into its empty
neighbours (right and down), so sparse clouds stay visible without covering drawn points.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from lidar_weather_sim.viz.colors import BACKGROUND


@dataclass(frozen=True)
class BevView:
    """The bird's-eye window: x in [x_min_m, x_max_m], y in [-half_width_m, half_width_m] (m,
    sensor frame), ``size_px`` square pixels a side."""

    x_min_m: float
    x_max_m: float
    half_width_m: float
    size_px: int

    @classmethod
    def ahead(cls, range_m: float, size_px: int = 800) -> BevView:
        """A square window ``1.5 * range_m`` a side: ``range_m`` ahead, ``range_m / 2`` behind."""
        return cls(-0.5 * range_m, range_m, 0.75 * range_m, size_px)

    @property
    def metres_per_px(self) -> float:
        return max(self.x_max_m - self.x_min_m, 2 * self.half_width_m) / self.size_px

    @property
    def origin_px(self) -> tuple[float, float]:
        """(column, row) of the sensor."""
        return self.to_px(np.zeros(1), np.zeros(1))[0][0], self.to_px(np.zeros(1), np.zeros(1))[1][0]

    def to_px(self, x: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Float (column, row) of sensor-frame x, y (m); pixel centres at .5."""
        scale = 1.0 / self.metres_per_px
        return (self.half_width_m - np.asarray(y, float)) * scale, (self.x_max_m - np.asarray(x, float)) * scale


def zbuffer(cells: np.ndarray, depth: np.ndarray, keep: str) -> tuple[np.ndarray, np.ndarray]:
    """Per occupied cell (flat index) the point kept: the one with the largest ``depth``
    (``keep='max'``) or smallest (``'min'``). Returns (cells, point indices), one entry per cell."""
    if not len(cells):
        return np.zeros(0, np.int64), np.zeros(0, np.int64)
    finite = np.nan_to_num(np.asarray(depth, np.float64), nan=0.0, posinf=0.0, neginf=0.0)
    low, high = finite.min(), finite.max()
    q = np.rint((finite - low) / max(high - low, 1e-9) * 65535).astype(np.int64)
    if keep == "min":
        q = 65535 - q
    order = np.argsort(cells.astype(np.int64) * 65536 + q)  # ties (same cell and depth) are alike
    sorted_cells = cells[order]
    last = np.r_[sorted_cells[1:] != sorted_cells[:-1], True]
    return sorted_cells[last], order[last]


def grow(image: np.ndarray, px: int) -> np.ndarray:
    """``image`` with each drawn (non-background) pixel widened to a ``px`` x ``px`` square towards the
    right and below, over background pixels only (in place; returns it)."""
    original = image.copy()
    rows, cols = image.shape
    for dr in range(px):
        for dc in range(px):
            if dr or dc:
                src, dst = original[: rows - dr, : cols - dc], image[dr:, dc:]
                fill = (dst == BACKGROUND) & (src != BACKGROUND)
                dst[fill] = src[fill]
    return image


def bev_image(points: np.ndarray, colors: np.ndarray, view: BevView, point_px: int = 1) -> np.ndarray:
    """(size_px, size_px) uint8 palette image of ``points`` (x, y, z in m) seen from above."""
    col, row = view.to_px(points["x"], points["y"])
    col, row = np.floor(col).astype(np.int64), np.floor(row).astype(np.int64)
    n = view.size_px
    inside = (col >= 0) & (col < n) & (row >= 0) & (row < n)
    cells, kept = zbuffer(row[inside] * n + col[inside], points["z"][inside], "max")
    image = np.full((n, n), BACKGROUND, np.uint8)
    image.reshape(-1)[cells] = colors[inside][kept]
    return grow(image, point_px)


@dataclass(frozen=True)
class RangeView:
    """The range image's grid: ``channels`` rows; columns of ``bin_rad`` from ``azimuth_max_rad`` down."""

    channels: int
    azimuth_max_rad: float
    bin_rad: float
    columns: int

    @classmethod
    def of(cls, points: np.ndarray, max_columns: int = 1024) -> RangeView:
        """The grid fitting a frame: its channels, its azimuth span (0.1-99.9 percentile; a full turn
        when it covers more than 300 deg) at the finest azimuth step the firings show (the median step
        between sorted azimuths of one channel), at most ``max_columns``."""
        az = _azimuth(points)
        channels = int(points["channel"].max()) + 1 if len(points) else 1
        if len(az) < 2:
            return cls(channels, np.pi, 2 * np.pi / max_columns, max_columns)
        lo, hi = np.percentile(az, [0.1, 99.9])
        if hi - lo > np.radians(300):
            lo, hi = -np.pi, np.pi
        busiest = np.bincount(points["channel"].astype(np.int64)).argmax()
        steps = np.diff(np.unique(np.round(az[points["channel"] == busiest], 6)))
        step = float(np.median(steps)) if len(steps) else (hi - lo) / max_columns
        columns = int(np.clip(np.ceil((hi - lo) / max(step, 1e-6)), 16, max_columns))
        return cls(channels, float(hi), float(hi - lo) / columns, columns)

    def column_of(self, azimuth_rad: np.ndarray) -> np.ndarray:
        """Float column of each azimuth (rad); left = larger azimuth."""
        return (self.azimuth_max_rad - np.asarray(azimuth_rad, float)) / self.bin_rad


def _azimuth(points: np.ndarray) -> np.ndarray:
    if "azimuth" in (points.dtype.names or ()):
        return points["azimuth"].astype(np.float64)
    return np.arctan2(points["y"].astype(np.float64), points["x"].astype(np.float64))


def range_image(points: np.ndarray, colors: np.ndarray, view: RangeView) -> np.ndarray:
    """(channels, columns) uint8 palette image: channel 0 in the bottom row; the nearest return per cell."""
    col = np.floor(view.column_of(_azimuth(points))).astype(np.int64)
    row = view.channels - 1 - points["channel"].astype(np.int64)
    inside = (col >= 0) & (col < view.columns) & (row >= 0) & (row < view.channels)
    distance = np.sqrt(points["x"].astype(np.float64) ** 2 + points["y"] ** 2 + points["z"] ** 2)
    cells, kept = zbuffer(row[inside] * view.columns + col[inside], distance[inside], "min")
    image = np.full((view.channels, view.columns), BACKGROUND, np.uint8)
    image.reshape(-1)[cells] = colors[inside][kept]
    return image
