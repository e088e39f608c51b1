"""A small tf2-style transform buffer for /tf and /tf_static, without ROS.

Frames follow REP-103 (x forward, y left, z up) and REP-105 (map -> odom ->
base_link -> sensors); a leading '/' is stripped. Translations are metres,
quaternions (x, y, z, w), stamps integer nanoseconds, durations seconds.
``set_transform(parent, child, ...)`` stores the pose of ``child`` in ``parent``
(geometry_msgs/TransformStamped: header.frame_id = parent), i.e. it maps points
in ``child`` into ``parent``; ``lookup(target, source, t)`` maps points in
``source`` into ``target``, like tf2's lookupTransform. Only numpy is needed
(scipy is imported lazily by ``Transform.from_matrix``).
"""

from __future__ import annotations

import threading
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np

from lidar_weather_sim.core.geometry import quaternion_multiply, quaternion_rotate

_IDENTITY_Q = np.array([0.0, 0.0, 0.0, 1.0])


def _compose(ta, qa, tb, qb):
    """(ta, qa) * (tb, qb): apply b first, then a."""
    return ta + quaternion_rotate(qa, tb), quaternion_multiply(qa, qb)


def _invert(t, q):
    qi = q * np.array([-1.0, -1.0, -1.0, 1.0])
    return -quaternion_rotate(qi, t), qi


def _slerp(q0: np.ndarray, q1: np.ndarray, a: np.ndarray) -> np.ndarray:
    """Shortest-arc spherical interpolation, a in [0, 1] of shape (N,)."""
    dot = np.sum(q0 * q1, axis=-1)
    q1 = np.where((dot < 0.0)[:, None], -q1, q1)
    dot = np.abs(dot)
    theta = np.arccos(np.clip(dot, -1.0, 1.0))
    sin = np.sin(theta)
    near = sin < 1e-6  # (almost) identical: linear interpolation is exact enough
    safe = np.where(near, 1.0, sin)
    w0 = np.where(near, 1.0 - a, np.sin((1.0 - a) * theta) / safe)
    w1 = np.where(near, a, np.sin(a * theta) / safe)
    q = w0[:, None] * q0 + w1[:, None] * q1
    return q / np.linalg.norm(q, axis=-1, keepdims=True)


@dataclass(frozen=True, eq=False)
class Transform:
    """Rigid transform: ``p_parent = R(rotation) @ p_child + translation``.

    ``translation`` is (3,) in metres, ``rotation`` a unit quaternion (x, y, z, w).
    """

    translation: np.ndarray
    rotation: np.ndarray

    def __post_init__(self):
        t = np.array(self.translation, dtype=np.float64).reshape(3)
        q = np.array(self.rotation, dtype=np.float64).reshape(4)
        n = np.linalg.norm(q)
        if not (np.all(np.isfinite(t)) and np.isfinite(n) and n > 0.0):
            raise ValueError(f"invalid transform: translation {t}, rotation (x, y, z, w) {q}")
        for name, value in (("translation", t), ("rotation", q / n)):
            value.setflags(write=False)
            object.__setattr__(self, name, value)

    @classmethod
    def identity(cls) -> Transform:
        return cls(np.zeros(3), _IDENTITY_Q)

    @classmethod
    def from_matrix(cls, m) -> Transform:
        """From a 4x4 homogeneous matrix (rotation part must be orthonormal)."""
        from scipy.spatial.transform import Rotation  # scalar-last = (x, y, z, w)

        m = np.asarray(m, dtype=np.float64)
        return cls(m[:3, 3], Rotation.from_matrix(m[:3, :3]).as_quat())

    def as_matrix(self) -> np.ndarray:
        """4x4 homogeneous matrix."""
        m = np.eye(4)
        m[:3, :3] = quaternion_rotate(self.rotation, np.eye(3)).T  # columns = rotated axes
        m[:3, 3] = self.translation
        return m

    def inverse(self) -> Transform:
        return Transform(*_invert(self.translation, self.rotation))

    def compose(self, other: Transform) -> Transform:
        """``self * other``: apply ``other`` first, then ``self``."""
        return Transform(*_compose(self.translation, self.rotation,
                                   other.translation, other.rotation))

    def __mul__(self, other):
        return self.compose(other) if isinstance(other, Transform) else NotImplemented

    def apply(self, points) -> np.ndarray:
        """Transform (N, 3) points (m); returns float64 of the same shape."""
        p = np.asarray(points, dtype=np.float64)
        return p @ self.as_matrix()[:3, :3].T + self.translation


class TransformError(LookupError):
    """Base class for buffer lookup failures."""


class UnknownFrameError(TransformError):
    """A frame was never seen as parent or child."""


class ConnectivityError(TransformError):
    """The two frames are in disjoint trees."""


class ExtrapolationError(TransformError):
    """The requested time is outside an edge's data (beyond the tolerance)."""


class _Edge(NamedTuple):
    """Samples of ``child`` in ``parent``; arrays are replaced, never mutated."""

    parent: str
    child: str
    static: bool
    stamps: np.ndarray  # (M,) int64 ns, sorted ascending, unique
    trans: np.ndarray  # (M, 3) m
    quats: np.ndarray  # (M, 4) x, y, z, w


def _name(frame: str) -> str:
    name = str(frame).lstrip("/")
    if not name:
        raise ValueError("empty frame name")
    return name


class TransformBuffer:
    """Time-stamped tree of frames, one parent per frame (like tf2's BufferCore).

    ``cache_time_s``: history kept per dynamic edge behind its newest sample.
    ``extrapolation_tolerance_s``: how far outside an edge's data a request may
    be and still get the nearest sample (clamped, never extrapolated).
    """

    def __init__(self, cache_time_s: float = 10.0, extrapolation_tolerance_s: float = 0.05):
        self.cache_time_s = float(cache_time_s)
        self.extrapolation_tolerance_s = float(extrapolation_tolerance_s)
        self._cache_ns = int(round(cache_time_s * 1e9))
        self._tol_ns = int(round(extrapolation_tolerance_s * 1e9))
        self._edges: dict[str, _Edge] = {}  # keyed by child frame
        self._lock = threading.Lock()

    # -- insertion -----------------------------------------------------------
    def set_transform(self, parent: str, child: str, stamp_ns: int, translation,
                      rotation_xyzw, static: bool = False) -> None:
        """Store the pose of ``child`` in ``parent`` at ``stamp_ns`` (ns)."""
        parent, child, stamp = _name(parent), _name(child), int(stamp_ns)
        tf = Transform(translation, rotation_xyzw)  # validates and normalises
        t, q = tf.translation[None], tf.rotation[None]
        with self._lock:
            if parent == child or child in self._chain(parent):
                raise ValueError(f"'{parent}' -> '{child}' would create a loop in the tree")
            old = self._edges.get(child)
            if static or old is None or old.static or old.parent != parent:
                stamps = np.array([stamp], dtype=np.int64)
            else:  # dynamic: insert in order (a repeated stamp is replaced), prune
                keep = old.stamps != stamp
                s, ot, oq = old.stamps[keep], old.trans[keep], old.quats[keep]
                i = int(np.searchsorted(s, stamp))
                stamps = np.insert(s, i, stamp)
                t, q = np.insert(ot, i, t[0], axis=0), np.insert(oq, i, q[0], axis=0)
                lo = int(np.searchsorted(stamps, stamps[-1] - self._cache_ns))
                stamps, t, q = stamps[lo:], t[lo:], q[lo:]
            self._edges[child] = _Edge(parent, child, bool(static), stamps, t, q)

    def add_tf_message(self, msg, static: bool = False) -> list[str]:
        """Add every transform of a tf2_msgs/TFMessage (rclpy or rosbags, duck-typed).

        A bad transform (loop, non-finite values, zero quaternion) is skipped, not
        the whole message; returns one reason per skipped transform.
        """
        rejected = []
        for ts in msg.transforms:
            st, tr, rot = ts.header.stamp, ts.transform.translation, ts.transform.rotation
            try:
                self.set_transform(ts.header.frame_id, ts.child_frame_id,
                                   int(st.sec) * 1_000_000_000 + int(st.nanosec),
                                   (tr.x, tr.y, tr.z), (rot.x, rot.y, rot.z, rot.w), static)
            except ValueError as exc:
                rejected.append(f"{ts.header.frame_id} -> {ts.child_frame_id}: {exc}")
        return rejected

    # -- queries -------------------------------------------------------------
    def frames(self) -> set[str]:
        with self._lock:
            return self._frames()

    def root(self, frame: str) -> str:
        """The root of the tree ``frame`` hangs in (``frame`` itself if it has no parent)."""
        with self._lock:
            return self._chain(_name(frame))[-1]

    def time_range(self, child: str) -> tuple[int, int] | None:
        """(oldest, newest) stamp in ns of the edge above ``child``; None if static."""
        with self._lock:
            e = self._edges.get(_name(child))
        if e is None:
            raise UnknownFrameError(f"frame '{child}' has no parent in the buffer")
        return None if e.static else (int(e.stamps[0]), int(e.stamps[-1]))

    def can_transform(self, target_frame: str, source_frame: str, stamp_ns: int) -> bool:
        try:
            self.lookup(target_frame, source_frame, stamp_ns)
        except TransformError:
            return False
        return True

    def lookup(self, target_frame: str, source_frame: str, stamp_ns: int) -> Transform:
        """Transform mapping points in ``source_frame`` into ``target_frame``.

        ``stamp_ns == 0`` means the latest time all dynamic edges on the chain share.
        """
        t, q = self.lookup_many(target_frame, source_frame, np.array([stamp_ns]))
        return Transform(t[0], q[0])

    def lookup_many(self, target_frame: str, source_frame: str,
                    stamps_ns) -> tuple[np.ndarray, np.ndarray]:
        """Vectorised ``lookup``: (N,) ns -> ((N, 3) translations m, (N, 4) quaternions).

        Quaternions are returned with w >= 0.
        """
        target, source = _name(target_frame), _name(source_frame)
        stamps = np.asarray(stamps_ns).astype(np.int64).reshape(-1)
        with self._lock:  # snapshot the edges; their arrays are never mutated
            known = self._frames()
            for f in (target, source):
                if f not in known:
                    raise UnknownFrameError(
                        f"frame '{f}' does not exist; known frames: {sorted(known)}")
            up_s, up_t = self._chain(source), self._chain(target)
            edges = {f: self._edges[f] for f in up_s[:-1] + up_t[:-1]}
        in_s = set(up_s)
        common = next((f for f in up_t if f in in_s), None)
        if common is None:
            raise ConnectivityError(
                f"cannot transform '{source}' into '{target}': they are in disjoint trees "
                f"(roots '{up_s[-1]}' and '{up_t[-1]}')")
        src = [edges[f] for f in up_s[:up_s.index(common)]]
        tgt = [edges[f] for f in up_t[:up_t.index(common)]]
        dynamic = [e for e in src + tgt if not e.static]
        if dynamic and np.any(stamps == 0):
            latest = min(int(e.stamps[-1]) for e in dynamic)
            stamps = np.where(stamps == 0, latest, stamps)
        ts, qs = self._to_common(src, stamps)
        tt, qt = self._to_common(tgt, stamps)
        t, q = _compose(*_invert(tt, qt), ts, qs)
        return t, np.where(q[:, 3:] < 0.0, -q, q)

    # -- internals: _frames and _chain need the lock, the rest uses snapshots --
    def _frames(self) -> set[str]:
        return set(self._edges) | {e.parent for e in self._edges.values()}

    def _chain(self, frame: str) -> list[str]:
        """[frame, parent, grandparent, ..., root]."""
        chain = [frame]
        while chain[-1] in self._edges:
            chain.append(self._edges[chain[-1]].parent)
        return chain

    def _to_common(self, chain: list[_Edge], stamps: np.ndarray):
        """Compose the edges of ``chain`` (bottom-up) at every stamp."""
        t = np.zeros((len(stamps), 3))
        q = np.tile(_IDENTITY_Q, (len(stamps), 1))
        for edge in chain:
            t, q = _compose(*self._interpolate(edge, stamps), t, q)
        return t, q

    def _interpolate(self, e: _Edge, stamps: np.ndarray):
        """Edge pose at each stamp: lerp + slerp between bracketing samples."""
        if not e.static:
            self._check_range(e, stamps)
        if len(e.stamps) == 1:  # static, or a single dynamic sample
            return np.repeat(e.trans, len(stamps), axis=0), np.repeat(e.quats, len(stamps), axis=0)
        s = e.stamps
        tc = np.clip(stamps, s[0], s[-1])
        i = np.clip(np.searchsorted(s, tc, side="right"), 1, len(s) - 1)
        a = (tc - s[i - 1]) / (s[i] - s[i - 1])
        t = e.trans[i - 1] + a[:, None] * (e.trans[i] - e.trans[i - 1])
        return t, _slerp(e.quats[i - 1], e.quats[i], a)

    def _check_range(self, e: _Edge, stamps: np.ndarray) -> None:
        lo, hi = int(e.stamps[0]), int(e.stamps[-1])
        bad = (stamps < lo - self._tol_ns) | (stamps > hi + self._tol_ns)
        if np.any(bad):
            t = int(stamps[np.argmax(bad)])
            raise ExtrapolationError(
                f"'{e.parent}' -> '{e.child}' requested at {t * 1e-9:.9f} s, outside the "
                f"available data [{lo * 1e-9:.9f}, {hi * 1e-9:.9f}] s "
                f"(tolerance {self.extrapolation_tolerance_s} s)")
