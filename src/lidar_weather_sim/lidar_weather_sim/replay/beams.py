"""Beams of a cloud by channel and azimuth column: the key that pairs the returns of two clouds of one sensor
(a recording and its re-simulation) beam by beam."""

from __future__ import annotations

import numpy as np


def beam_keys(points: np.ndarray, columns: int) -> np.ndarray:
    """One integer per point naming its beam: channel x columns + azimuth column."""
    col = np.floor((points["azimuth"].astype(np.float64) + np.pi) / (2.0 * np.pi) * columns).astype(np.int64)
    return points["channel"].astype(np.int64) * columns + np.clip(col, 0, columns - 1)


def nearest_returns(points: np.ndarray, columns: int) -> tuple[np.ndarray, np.ndarray]:
    """(beam keys, index into ``points``) of each beam's nearest return, sorted by key."""
    keys = beam_keys(points, columns)
    order = np.lexsort((points["distance"], keys))
    keys = keys[order]
    first = np.ones(len(keys), bool)
    first[1:] = keys[1:] != keys[:-1]
    return keys[first], order[first]


def paired_beams(a: np.ndarray, b: np.ndarray, columns: int) -> tuple[np.ndarray, np.ndarray]:
    """Indices into ``a`` and into ``b`` of each beam's nearest return, over the beams both frames return on."""
    ka, ia = nearest_returns(a, columns)
    kb, ib = nearest_returns(b, columns)
    _, ja, jb = np.intersect1d(ka, kb, assume_unique=True, return_indices=True)
    return ia[ja], ib[jb]
