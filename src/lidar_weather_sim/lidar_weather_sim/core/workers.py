"""Work sharing for the simulator's numba kernels (their scratch memory: :mod:`lidar_weather_sim.core.scratch`).

A kernel that releases the GIL (``numba.njit(nogil=True)``) is called once per chunk
of its index range; the calling thread and ``THREADS - 1`` pool threads claim
chunks from a shared counter until none are left. Every chunk writes only its own
part of the outputs, so the result does not depend on which thread ran which chunk
(or on the thread count): runs are bit for bit identical. Chunks are claimed
dynamically, so a busy core only costs the chunk its thread is working on, and
with every core busy the caller does the work alone, as fast as without threads.

``LWS_SIM_THREADS`` sets the thread count (default: the CPUs this process may use;
1 disables the pool).

:func:`background` is one more thread, for a pipeline stage that runs behind its caller. A fork
(``os.fork``, multiprocessing's and DataLoaders' default on Linux) first waits for what it was given,
and the child starts its own threads on first use.
"""

from __future__ import annotations

import itertools
import os
import threading
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor

import numpy as np

MAX_CHUNKS = 32


def usable_cpus() -> int:
    """The CPUs this process may use."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except AttributeError:  # not on Linux
        return max(1, os.cpu_count() or 1)


def _default_threads() -> int:
    env = os.environ.get("LWS_SIM_THREADS", "").strip()
    return max(1, int(env)) if env else usable_cpus()


THREADS = _default_threads()
_pool: ThreadPoolExecutor | None = None
_pool_lock = threading.Lock()


def _workers() -> ThreadPoolExecutor:
    global _pool
    with _pool_lock:
        if _pool is None:
            _pool = ThreadPoolExecutor(THREADS - 1, thread_name_prefix="lws-sim")
        return _pool


_background: ThreadPoolExecutor | None = None


def background() -> ThreadPoolExecutor:
    """One thread that runs a stage of the pipeline behind the caller (the simulator's detection of a batch
    while it casts the next); tasks run in the order they are submitted."""
    global _background
    with _pool_lock:
        if _background is None:
            _background = ThreadPoolExecutor(1, thread_name_prefix="lws-background")
        return _background


def _finish_background_before_fork() -> None:
    """A forked child has none of its parent's threads: what the background thread was given must be done
    first (its futures are then complete in the child's copy too)."""
    if _background is None:
        return
    try:
        _background.submit(lambda: None).result()  # one thread, first in first out: all earlier tasks are done
    except RuntimeError:  # shut down (interpreter exit): nothing runs there any more
        pass


def _forget_threads_in_child() -> None:
    """The child starts its own pools on first use (the parent's threads are not there)."""
    global _pool, _background, _pool_lock
    _pool, _background, _pool_lock = None, None, threading.Lock()


if hasattr(os, "register_at_fork"):
    os.register_at_fork(before=_finish_background_before_fork, after_in_child=_forget_threads_in_child)


def bounds(n: int, min_size: int, max_chunks: int = MAX_CHUNKS, align: int = 1) -> np.ndarray:
    """Chunk boundaries (k + 1,) over range(n): chunks of at least ``min_size`` (but at most
    ``max_chunks`` of them), boundaries on multiples of ``align``; one chunk when n is small."""
    chunks = int(min(max_chunks, n // max(min_size, 1))) if THREADS > 1 else 1
    if chunks <= 1:
        return np.array([0, n], np.int64)
    cuts = (np.arange(1, chunks, dtype=np.int64) * n // chunks) // align * align
    return np.unique(np.concatenate([[0], cuts[cuts > 0], [n]])).astype(np.int64)


def run_chunks(fn: Callable[[int], object], n_chunks: int) -> list:
    """``[fn(c) for c in range(n_chunks)]``, the calls shared with the pool's threads."""
    results: list = [None] * n_chunks
    workers = min(THREADS, n_chunks) - 1
    if workers <= 0:
        for c in range(n_chunks):
            results[c] = fn(c)
        return results
    counter = itertools.count()  # next() is atomic under the GIL

    def work() -> None:
        for c in counter:
            if c >= n_chunks:
                return
            results[c] = fn(c)

    futures = [_workers().submit(work) for _ in range(workers)]
    try:
        work()
    finally:
        for f in futures:
            if not f.cancel():  # started: wait for (and re-raise from) the chunk it is on
                f.result()
    return results
