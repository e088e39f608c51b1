"""Per-point features of paper 4 (thesis lines 2770-2795) for the learned filter.

Per detection: x, y, echo, layer (channel), EPW; counts of the bird's-eye
histogram cell holding it for five cell shapes (radial 1 deg, 10x10 cm,
20 cm x 2 m, 4 m x 10 cm, 50x50 cm); |radial count now - radial count of the
previous frame|; and the small-feature (10 cm) histogram convolved with the
paper's horizontal (A2), corner (A3), corner rotated 90 deg and impulse (A1)
matrices (Appendix B), read at the detection's cell. We add z, intensity and
range (the paper's sensor had no usable intensity in its feature list; ours does).

Histograms cover |x|, |y| <= ``extent_m`` (sensor frame); points outside get
the counts of the border cell clipped to, and zero convolution responses.
Everything is vectorised (bincount and one correlate per kernel).
"""

from __future__ import annotations

import numpy as np
from scipy import ndimage

IMPULSE = np.array([[-1, -1, -1], [-1, 4, -1], [-1, -1, -1]], dtype=np.float32)  # A1
HORIZONTAL = np.array([[-1] * 10, [2] * 10, [-1] * 10], dtype=np.float32)  # A2
CORNER = np.array(
    [[-1, -1, -1, -1, -1], [-1, 2, 2, 2, -1], [-1, -1, 2, 2, -1], [-1, -1, -1, 2, -1], [-1, -1, -1, 2, -1]],
    dtype=np.float32,
)  # A3

#: (name, cell size x m, cell size y m) of the Cartesian bird's-eye histograms.
CELL_SHAPES = (("small", 0.1, 0.1), ("rear", 0.2, 2.0), ("side", 4.0, 0.1), ("middle", 0.5, 0.5))
FEATURE_NAMES = (
    "x", "y", "z", "echo", "channel", "epw", "intensity", "range",
    "n_radial", "n_small", "n_rear", "n_side", "n_middle", "d_radial",
    "conv_horizontal", "conv_corner", "conv_corner_rot90", "conv_impulse",
)  # fmt: skip
REQUIRED_FIELDS = frozenset({"x", "y", "z", "echo", "channel", "epw", "intensity"})


def _grid_counts(x: np.ndarray, y: np.ndarray, cx: float, cy: float, extent_m: float):
    nx, ny = int(np.ceil(2 * extent_m / cx)), int(np.ceil(2 * extent_m / cy))
    ix = np.clip(((x + extent_m) / cx).astype(np.int64), 0, nx - 1)
    iy = np.clip(((y + extent_m) / cy).astype(np.int64), 0, ny - 1)
    flat = ix * ny + iy
    counts = np.bincount(flat, minlength=nx * ny)
    return counts, flat, (nx, ny)


def radial_histogram(points: np.ndarray, bin_deg: float = 1.0) -> np.ndarray:
    """Counts per azimuth bin over [-180, 180) deg."""
    az = np.degrees(np.arctan2(points["y"], points["x"]))
    idx = np.clip(((az + 180.0) / bin_deg).astype(np.int64), 0, int(360 / bin_deg) - 1)
    return np.bincount(idx, minlength=int(360 / bin_deg)), idx


class PointFeatures:
    """Feature extractor; keeps the previous frame's radial histogram for the frame-difference feature."""

    def __init__(self, extent_m: float = 30.0, radial_bin_deg: float = 1.0) -> None:
        self.extent_m = extent_m
        self.radial_bin_deg = radial_bin_deg
        self._previous_radial: np.ndarray | None = None

    def reset(self) -> None:
        self._previous_radial = None

    def __call__(self, points: np.ndarray) -> np.ndarray:
        """(N, len(FEATURE_NAMES)) float32."""
        n = len(points)
        x = points["x"].astype(np.float64)
        y = points["y"].astype(np.float64)
        out = np.empty((n, len(FEATURE_NAMES)), np.float32)
        out[:, 0], out[:, 1], out[:, 2] = x, y, points["z"]
        out[:, 3], out[:, 4], out[:, 5] = points["echo"], points["channel"], points["epw"]
        out[:, 6] = points["intensity"]
        out[:, 7] = np.hypot(x, y)
        radial, ridx = radial_histogram(points, self.radial_bin_deg)
        out[:, 8] = radial[ridx]
        small = None
        for col, (name, cx, cy) in enumerate(CELL_SHAPES, start=9):
            counts, flat, shape = _grid_counts(x, y, cx, cy, self.extent_m)
            out[:, col] = counts[flat]
            if name == "small":
                small, small_flat, small_shape = counts, flat, shape
        previous = self._previous_radial if self._previous_radial is not None else radial
        out[:, 13] = np.abs(radial - previous)[ridx]
        self._previous_radial = radial
        grid = small.reshape(small_shape).astype(np.float32)
        inside = (np.abs(x) < self.extent_m) & (np.abs(y) < self.extent_m)
        for col, kernel in enumerate((HORIZONTAL, CORNER, np.rot90(CORNER), IMPULSE), start=14):
            response = ndimage.correlate(grid, kernel, mode="constant").ravel()
            out[:, col] = np.where(inside, response[small_flat], 0.0)
        return out
