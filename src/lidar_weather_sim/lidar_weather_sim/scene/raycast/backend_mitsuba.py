"""Mitsuba 3 (PyPI ``mitsuba``), CPU variant ``llvm_ad_rgb``: coherent batched ray casts.

Mitsuba's LLVM variants JIT-compile through Dr.Jit, which loads ``libLLVM`` at
run time and needs LLVM >= 15 (with LLVM 14 Dr.Jit shuts its LLVM backend
down and the process dies with SIGFPE at the first kernel). Debian 12 ships it
as ``libllvm15`` (``/usr/lib/x86_64-linux-gnu/libLLVM-15.so.1``). Unless
``DRJIT_LIBLLVM_PATH`` is already set, ``check()`` points it at the newest
``libLLVM-N`` with N >= 15 before Dr.Jit is imported, so an older libLLVM
that happens to be installed too is never picked.

Mitsuba's variant is process-global: the caster switches to ``llvm_ad_rgb``
for its own calls and switches back to any other variant that was set.

Dr.Jit's worker threads (nanothread) spin on its task queue for ~20-30 ms after
every kernel before they sleep: on a small machine they would take the cores
from the simulator's kernels that follow each cast (+15 ms per OS1-128 frame on
2 cores). A large cast (or a scene build) therefore starts the workers (Dr.Jit's
thread count, all cores by default) and stops them when it is done (~30 us);
smaller casts, where threads gain nothing, run on the calling thread alone.
"""

from __future__ import annotations

import glob
import os
import re
import sys
from contextlib import contextmanager
from functools import cache

import numpy as np

from lidar_weather_sim.core import workers

from .backend import CasterBase

VARIANT = "llvm_ad_rgb"
MIN_LLVM = 15
#: Rays from which a cast also runs on Dr.Jit's worker threads.
PARALLEL_RAYS = 1 << 16
_LLVM_GLOBS = ("/usr/lib/*/libLLVM-*.so*", "/usr/lib/llvm-*/lib/libLLVM*.so*", "/usr/lib64/libLLVM-*.so*")


def _llvm_major(path: str) -> int | None:
    m = re.search(r"libLLVM[-.]?(\d+)", os.path.basename(path)) or re.search(r"llvm-(\d+)", path)
    return int(m.group(1)) if m else None


def find_libllvm() -> str | None:
    """Path of the newest installed libLLVM with major version >= 15, or None."""
    found = [(_llvm_major(p), p) for g in _LLVM_GLOBS for p in glob.glob(g)]
    found = [(v, p) for v, p in found if v is not None and v >= MIN_LLVM]
    return max(found)[1] if found else None


def check() -> None:
    path = os.environ.get("DRJIT_LIBLLVM_PATH")
    if path:
        major = _llvm_major(path)
        if major is not None and major < MIN_LLVM:
            raise RuntimeError(f"DRJIT_LIBLLVM_PATH={path} is LLVM {major}; Dr.Jit needs LLVM >= {MIN_LLVM}")
    elif "drjit" not in sys.modules:
        path = find_libllvm()
        if path is None:
            raise RuntimeError(f"no libLLVM >= {MIN_LLVM} found (Debian: apt-get install libllvm15)")
        os.environ["DRJIT_LIBLLVM_PATH"] = path
    import drjit as dr
    import mitsuba as mi

    if not dr.has_backend(dr.JitBackend.LLVM):
        raise RuntimeError(f"Dr.Jit's LLVM backend did not start (libLLVM: {path or 'Dr.Jit default search'})")
    if VARIANT not in mi.variants():
        raise RuntimeError(f"mitsuba {mi.__version__} lacks the {VARIANT} variant")


@cache
def _threads() -> int:
    """Dr.Jit's thread count before our first use (all cores unless the user set it), at most the
    simulator's own (``LWS_SIM_THREADS``: 1 in a sweep's worker processes)."""
    import drjit as dr

    return max(1, min(dr.thread_count(), workers.THREADS))


@contextmanager
def _workers(active: bool):
    """Dr.Jit's worker threads during the block if ``active`` (else the calling thread alone), none after it."""
    import drjit as dr

    dr.set_thread_count(_threads() if active else 1)
    try:
        yield
    finally:
        dr.set_thread_count(1)  # no spinning workers afterwards


@contextmanager
def _variant():
    import mitsuba as mi

    previous = mi.variant()
    if previous != VARIANT:
        mi.set_variant(VARIANT)
    try:
        yield mi
    finally:
        if previous not in (None, VARIANT):
            mi.set_variant(previous)


class Caster(CasterBase):
    """Vertices (V, 3) float32 m, triangles (T, 3) uint32; rays in the same frame."""

    def __init__(self, vertices: np.ndarray, triangles: np.ndarray) -> None:
        with _variant() as mi, _workers(True):
            mesh = mi.Mesh("mesh", len(vertices), len(triangles))
            params = mi.traverse(mesh)
            params["vertex_positions"] = mi.Float(vertices.ravel())
            params["faces"] = mi.UInt32(triangles.ravel())
            params.update()
            self._scene = mi.load_dict({"type": "scene", "mesh": mesh})

    def _cast(self, o, d):
        import drjit as dr

        with _variant() as mi:
            # one contiguous array per coordinate: Dr.Jit converts a strided (o.T) view element by element
            # (no copy for column-major rays)
            o_t, d_t = np.ascontiguousarray(o.T), np.ascontiguousarray(d.T)
            ray = mi.Ray3f(mi.Point3f(*map(mi.Float, o_t)), mi.Vector3f(*map(mi.Float, d_t)))
            pi = self._scene.ray_intersect_preliminary(ray, coherent=True)
            valid = pi.is_valid()
            t = dr.select(valid, pi.t, dr.inf)
            prim = dr.select(valid, mi.Int32(pi.prim_index), -1)
            with _workers(len(o) >= PARALLEL_RAYS):
                dr.eval(t, prim)
                dr.sync_thread()  # the kernel runs asynchronously: done here, while the workers are on
            return t.numpy().astype(np.float32, copy=False), prim.numpy().astype(np.int64)
