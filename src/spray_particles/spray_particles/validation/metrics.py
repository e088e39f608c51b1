"""The thesis' validation metrics for spray point clouds (paper 3, Fig. 23-24, Tables VII-VIII).

Bird's-eye 2D histograms of detections (sensor frame x forward, y left, m) with 0.5 m
cells; Pearson correlation of two histograms; Jaccard distance of the binarised
histograms (share of the non-empty cells that differ, %); Hamming distance (share of all
cells that differ, %); histogram of detections per frame.
"""

from __future__ import annotations

import numpy as np

CELL_M = 0.5


def bev_histogram(xy: np.ndarray, x_range=(0.0, 40.0), y_range=(-10.0, 10.0), cell_m: float = CELL_M) -> np.ndarray:
    """Counts per cell of points ``xy`` (n, 2) m."""
    bins = [np.arange(x_range[0], x_range[1] + cell_m / 2, cell_m), np.arange(y_range[0], y_range[1] + cell_m / 2, cell_m)]
    xy = np.asarray(xy, dtype=np.float64).reshape(-1, 2)
    return np.histogram2d(xy[:, 0], xy[:, 1], bins=bins)[0]


def compare_histograms(a: np.ndarray, b: np.ndarray) -> dict[str, float]:
    """``pearson`` (nan if either is empty), ``jaccard_pct`` and ``hamming_pct`` of two histograms."""
    pearson = float(np.corrcoef(a.ravel(), b.ravel())[0, 1]) if a.any() and b.any() else float("nan")
    ba, bb = a > 0, b > 0
    union = int(np.sum(ba | bb))
    return {"pearson": pearson, "jaccard_pct": 100.0 * float(np.sum(ba ^ bb)) / max(union, 1),
            "hamming_pct": 100.0 * float(np.mean(ba ^ bb))}  # fmt: skip


def per_frame_overlap(counts_a, counts_b) -> float:
    """Overlap (0-1) of the normalised histograms of detections per frame (1 = identical)."""
    a, b = np.asarray(counts_a, dtype=np.int64), np.asarray(counts_b, dtype=np.int64)
    n = int(max(a.max(initial=0), b.max(initial=0))) + 1
    return float(np.minimum(np.bincount(a, minlength=n) / max(len(a), 1), np.bincount(b, minlength=n) / max(len(b), 1)).sum())
