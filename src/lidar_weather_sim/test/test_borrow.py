"""``core.borrow``: a kernel's uncounted views of its caller's arrays read and write the caller's memory."""

from __future__ import annotations

from typing import NamedTuple

import numba
import numpy as np

from lidar_weather_sim.core.borrow import borrow


class Pair(NamedTuple):
    values: np.ndarray
    labels: np.ndarray
    step: float


@numba.njit
def _scaled_sum(pair, out):
    """Writes values * step into ``out`` through borrowed views; returns the sum of the labels, read through one."""
    p, o = borrow(pair), borrow(out)
    total = 0
    for i in range(len(p.values)):
        o[i] = p.values[i] * p.step
        total += p.labels[i]
    return total


def test_borrowed_views_read_and_write_the_callers_arrays_and_keep_the_scalars():
    rng = np.random.default_rng(7)
    pair = Pair(rng.random(1000), rng.integers(0, 255, 1000).astype(np.uint8), 0.25)
    out = np.zeros(1000)
    before = [np.copy(pair.values), np.copy(pair.labels)]
    assert _scaled_sum(pair, out) == int(pair.labels.astype(np.int64).sum())
    np.testing.assert_array_equal(out, pair.values * 0.25)
    np.testing.assert_array_equal(pair.values, before[0])  # read, not changed
    np.testing.assert_array_equal(pair.labels, before[1])


def test_arrays_stay_alive_and_intact_after_many_borrowing_calls():
    """The caller's arrays stay its own and hold their values after repeated calls (a view that dropped a
    reference it never took would free them)."""
    pair = Pair(np.arange(64, dtype=np.float64), np.ones(64, np.uint8), 2.0)
    out = np.empty(64)
    for _ in range(10_000):
        _scaled_sum(pair, out)
    np.testing.assert_array_equal(out, np.arange(64) * 2.0)
    assert pair.values.flags.owndata and pair.values[63] == 63.0
