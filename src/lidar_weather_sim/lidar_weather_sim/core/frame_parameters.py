"""The 12 per-frame parameters of a region's detections (thesis paper 2, Fig. 4, line 1571).

ROS-free; used by ``reproduce rooftop``, the weather filter and the gap workflow.
Input: the x distances (m) of one frame's detections inside a region (the paper
measures them horizontally along the sensor's axis of symmetry), their echo
numbers (1-based) and echo pulse widths (m). Histograms use the paper's 5 cm
bins starting at the region's lower bound. Output units are SI (m, counts):

============ ============================================================
n_peak       detections in the fullest bin
x_max        centre of the fullest bin (m)
n_total      detections in the region
x_mean       mean x distance (m)
x_sigma      standard deviation of the x distance (m)
x_90         right edge of the bin where the cumulative count reaches 90 % (m)
n_dd         non-empty bins ("discrete distances") relative to n_total (0-1)
n_e1..n_e3   detections with echo number 1, 2, 3
epw_mean     mean echo pulse width (m)
epw_std      standard deviation of the echo pulse width (m)
============ ============================================================

Empty regions give counts 0 and NaN for the distance and EPW statistics.
"""

from __future__ import annotations

import numpy as np

FEATURES = ("n_peak", "x_max", "n_total", "x_mean", "x_sigma", "x_90", "n_dd",
            "n_e1", "n_e2", "n_e3", "epw_mean", "epw_std")  # fmt: skip
UNITS = {"n_peak": "1", "x_max": "m", "n_total": "1", "x_mean": "m", "x_sigma": "m", "x_90": "m", "n_dd": "1",
         "n_e1": "1", "n_e2": "1", "n_e3": "1", "epw_mean": "m", "epw_std": "m"}  # fmt: skip
BIN_M = 0.05


def region_mask(x_m: np.ndarray, lo_m: float, hi_m: float) -> np.ndarray:
    """Detections with lo <= x < hi (m)."""
    x_m = np.asarray(x_m)
    return (x_m >= lo_m) & (x_m < hi_m)


def frame_features(x_m, echo, epw_m, lo_m: float, hi_m: float, bin_m: float = BIN_M) -> dict[str, float]:
    """The 12 parameters of one frame's detections in the region [lo_m, hi_m) (see module doc)."""
    x_m, echo, epw_m = (np.asarray(a) for a in (x_m, echo, epw_m))
    if not (x_m.shape == echo.shape == epw_m.shape):
        raise ValueError(f"x, echo and epw must have one shape, got {x_m.shape}, {echo.shape}, {epw_m.shape}")
    inside = region_mask(x_m, lo_m, hi_m)
    x, e, w = x_m[inside].astype(np.float64), echo[inside], epw_m[inside].astype(np.float64)
    n = len(x)
    n_bins = max(int(round((hi_m - lo_m) / bin_m)), 1)
    counts = np.bincount(np.clip(((x - lo_m) / bin_m).astype(np.int64), 0, n_bins - 1), minlength=n_bins)
    nan = float("nan")
    out = {
        "n_peak": float(counts.max()),
        "x_max": lo_m + (int(np.argmax(counts)) + 0.5) * bin_m if n else nan,
        "n_total": float(n),
        "x_mean": float(x.mean()) if n else nan,
        "x_sigma": float(x.std()) if n else nan,
        "x_90": lo_m + (int(np.searchsorted(np.cumsum(counts), 0.9 * n)) + 1) * bin_m if n else nan,
        "n_dd": float(np.count_nonzero(counts)) / n if n else nan,
        "n_e1": float(np.count_nonzero(e == 1)),
        "n_e2": float(np.count_nonzero(e == 2)),
        "n_e3": float(np.count_nonzero(e == 3)),
        "epw_mean": float(w.mean()) if n else nan,
        "epw_std": float(w.std()) if n else nan,
    }
    return out


def summarize(rows: list[dict[str, float]]) -> dict[str, tuple[float, float]]:
    """Mean and standard deviation over frames of each parameter (NaN frames skipped)."""
    out = {}
    for key in FEATURES:
        values = np.array([r[key] for r in rows], dtype=np.float64)
        values = values[np.isfinite(values)]
        out[key] = (float(values.mean()), float(values.std())) if len(values) else (float("nan"), float("nan"))
    return out
