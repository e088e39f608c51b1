"""Per-detection extents of the bird's-eye cluster a detection belongs to (the v3 obstacle model's extra features).

Paper 4's features are counts in fixed cells around a detection; they cannot tell a 1.85 m wide, 1.45 m tall
car rear in the ego lane from a box of those sides. A cluster's extent can: the detections above the road
(more than :data:`ABOVE_FLOOR_M` above the lowest detection of their 50 cm cell, the extractor's ``dz_min``) are
put in :data:`CELL_M` bird's-eye cells, 8-connected occupied cells form a cluster, and every detection gets its
cluster's point count, depth (x) and width (y) extents and height (its highest detection above the lowest floor
of its cells; m); detections on the road (their cell's floor) get zeros.

Frames: the sensor frame (REP-103), m.
"""

from __future__ import annotations

import numpy as np
from scipy import ndimage

#: The features, in their column order.
CLUSTER_FEATURES = ("cl_count", "cl_depth", "cl_width", "cl_height")
CELL_M = 0.25
ABOVE_FLOOR_M = 0.1
_EIGHT = np.ones((3, 3), dtype=bool)


def cluster_extents(x: np.ndarray, y: np.ndarray, z: np.ndarray, dz_min: np.ndarray) -> np.ndarray:
    """(N, 4) float32 :data:`CLUSTER_FEATURES` of detections at ``x``, ``y``, ``z`` (m) with heights ``dz_min`` (m)
    above the lowest detection of their 50 cm cell (module doc)."""
    out = np.zeros((len(x), len(CLUSTER_FEATURES)), np.float32)
    above = np.flatnonzero(dz_min > ABOVE_FLOOR_M)
    if not len(above):
        return out
    ax, ay, az = (np.asarray(v, np.float64)[above] for v in (x, y, z))
    floor = az - np.asarray(dz_min, np.float64)[above]
    ix = np.floor((ax - ax.min()) / CELL_M).astype(np.int64)
    iy = np.floor((ay - ay.min()) / CELL_M).astype(np.int64)
    grid = np.zeros((ix.max() + 1, iy.max() + 1), dtype=bool)
    grid[ix, iy] = True
    labels, n = ndimage.label(grid, structure=_EIGHT)
    lab = labels[ix, iy] - 1
    count = np.bincount(lab, minlength=n)
    extents = []
    for low, high in ((ax, ax), (ay, ay), (floor, az)):
        lo = np.full(n, np.inf)
        hi = np.full(n, -np.inf)
        np.minimum.at(lo, lab, low)
        np.maximum.at(hi, lab, high)
        extents.append((hi - lo)[lab])
    out[above] = np.stack([count[lab], *extents], axis=-1)
    return out
