"""Scratch memory for the simulator's numba kernels.

:class:`Scratch` keeps the large per-batch temporaries from one batch to the next:
fresh memory costs a page fault per 4 KiB on first touch (several microseconds in a
VM), and glibc hands large blocks back to the OS when they are freed.
"""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np


class Scratch:
    """Named arrays reused from call to call; ``get`` returns a view valid until the next ``get``
    of the same name. Not thread-safe: one per simulator (or caster)."""

    def __init__(self) -> None:
        self._buffers: dict[str, tuple[np.ndarray, object]] = {}  # name -> (buffer, the dtype it was asked with)
        self._last: dict[str, tuple] = {}  # name -> (shape, dtype, view) of its last get: batches repeat sizes

    def get(self, name: str, shape: tuple[int, ...], dtype) -> np.ndarray:
        last = self._last.get(name)
        if last is not None and last[1] is dtype and type(last[0]) is type(shape) and last[0] == shape:
            return last[2]
        dims = (int(shape),) if isinstance(shape, (int, np.integer)) else tuple(shape)
        size = math.prod(dims)
        buf, asked = self._buffers.get(name, (None, None))
        if buf is None or buf.size < size or (asked is not dtype and buf.dtype != dtype):
            buf = np.empty(size + size // 8, dtype)  # headroom for growing batches
            self._buffers[name] = buf, dtype
        view = buf[:size] if len(dims) == 1 else buf[:size].reshape(dims)
        self._last[name] = (shape, dtype, view)
        return view


def allocator(scratch: Scratch | None) -> Callable[[str, tuple[int, ...], object], np.ndarray]:
    """``scratch.get``, or (without a scratch) ``np.empty`` behind the same signature."""
    return scratch.get if scratch is not None else lambda name, shape, dtype: np.empty(shape, dtype)
