"""Nearest-hit ray casting over a static map mesh plus rigidly moving actors.

Every caster is built once: the static mesh in the map frame, each actor's mesh
in its body frame. Moving an actor rebuilds nothing (hand instancing): per cast
and per actor, rays are culled against the actor's bounding sphere, the
survivors are moved into the actor's body frame and cast there, and the
nearest hit over the static mesh and all actors wins.

Culling per actor is two-stage. Consecutive rays are grouped in blocks of 128
with a bounding cone each, computed once per cast (a spinning lidar's rays are
ordered, so the cones are narrow); a block survives when its cone can meet the
cone of directions from the origins' bounding box to the actor's sphere (the
sphere grown by the box's radius, seen from its centre). The rays of the
surviving blocks then get the exact float64 test in perpendicular-distance form,
|v - (v.d) d| <= r with v the sphere centre minus the ray origin: the textbook
float32 |v|^2 - (v.d)^2 loses everything below ~2e-4 m^2 at 50 m and misses
centimetre-sized actors. Surviving rays start at the sphere (origin advanced by
max(0, v.d - r), exact in float64) before the float32 cast, so small far actors
keep their precision. Unordered rays make wide cones: still correct, only slower.
All actors are culled in one pass, against the static mesh's hits: a ray an actor
hides from another is cast at both, and the nearer hit wins as it would.

The per-ray passes (hit attributes, cones, culling, facing the normals to the
ray) are numba kernels that reproduce the numpy expressions bit for bit. With
the Mitsuba backend the rays of every backend call are padded to one of a few
sizes per octave (far misses): Dr.Jit compiles one kernel per ray count (~12 ms
each), and culled actor batches would otherwise have a new count on every cast.

Why one module of ~560 lines: it is the one place that knows how actors are instanced, culled and
padded for every backend; the pieces share its instance tables and make sense only together.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import NamedTuple

import numba
import numpy as np

from lidar_weather_sim.core import workers
from lidar_weather_sim.core.scratch import Scratch, allocator
from lidar_weather_sim.scene.mesh import TriangleMesh

from .backend import MeshCaster, default_backend, make_caster

_BLOCK = 128  # rays per culling block
_COS_MARGIN = 1e-5  # slack on a block's float32 min cos(angle to its axis); the float64 test decides
_PAD_BACKENDS = frozenset({"mitsuba"})  # backends that compile a kernel per distinct ray count
_PAD_DIRECTION = np.float32([0.0, 0.0, 1.0])  # of the padding rays: up, away from the part


@dataclass
class Hits:
    """Nearest hit per ray (N rays); frames are the map (world) frame.

    distance: (N,) float32 m along the unit ray, ``inf`` for a miss or beyond max range.
    triangle: (N,) int64 static-mesh triangle hit, -1 for a miss or an actor hit.
    normal: (N, 3) float32 unit face normal of the hit triangle, flipped to face the
        ray (normal . direction <= 0); zeros for a miss.
    material: (N,) int32 material index of the hit triangle, -1 for a miss.
    object_id: (N,) uint32 object id of the hit triangle, 0 for a miss.
    hit_actor: (N,) int32 id of the actor hit, -1 for the static mesh or a miss.

    Cast with ``gather=False``, normal, material, object_id and hit_actor hold the actors'
    hits only (elsewhere undefined; a hit with triangle -1 is an actor's): a static hit's
    are the rows ``triangle`` of :attr:`SceneCaster.static_tables` (the normal there not flipped).
    """

    distance: np.ndarray
    triangle: np.ndarray
    normal: np.ndarray
    material: np.ndarray
    object_id: np.ndarray
    hit_actor: np.ndarray

    @property
    def hit(self) -> np.ndarray:
        """(N,) bool: the ray hit something within range."""
        return np.isfinite(self.distance)


class TriangleTables(NamedTuple):
    """Per-triangle attributes of a mesh (T triangles), one extra last row for "no hit"."""

    normal: np.ndarray  # (T + 1, 3) float32 unit face normal (mesh frame; zeros for no hit)
    material: np.ndarray  # (T + 1,) int32 material index (-1 for no hit)
    object_id: np.ndarray  # (T + 1,) uint32 (0 for no hit)


class RayAttributes(NamedTuple):
    """The gathered attributes of each ray's hit (N rays), as in :class:`Hits`."""

    normal: np.ndarray  # (N, 3) float32, facing the ray
    material: np.ndarray  # (N,) int32
    object_id: np.ndarray  # (N,) uint32
    hit_actor: np.ndarray  # (N,) int32


class BlockCones(NamedTuple):
    """What :func:`_static_run` computes for culling: the bounding cone of each full block of
    ``size`` consecutive rays and the origins' box (only when ``wanted``)."""

    wanted: bool
    size: int  # rays per block
    cos_margin: float  # subtracted from the block's min cos(angle to its axis)
    axis: np.ndarray  # (B, 3) float64 unit, map frame
    half_angle: np.ndarray  # (B,) float64 rad
    box: np.ndarray  # (6,) float64 m: min (box[:3]) and max (box[3:]) of the chunk's origins


class CulledRays(NamedTuple):
    """The rays :func:`_cull` keeps for an actor's sphere (K rays), map frame."""

    index: np.ndarray  # (K,) int64 ray index
    shift: np.ndarray  # (K,) float64 m, where the ray may start without skipping the sphere
    start: np.ndarray  # (K, 3) float64 m, origin + shift x direction
    direction: np.ndarray  # (K, 3) float64 unit


@dataclass(frozen=True)
class _Part:
    """One mesh's caster with its per-triangle attributes, in the mesh's own frame.

    The attribute tables have one extra last row for "no hit" (zero normal,
    material -1, object id 0), so gathering with triangle index -1 yields it.
    """

    caster: MeshCaster
    normals: np.ndarray  # (T + 1, 3) float32 unit
    material: np.ndarray  # (T + 1,) int32
    object_id: np.ndarray  # (T + 1,) uint32
    centre: np.ndarray  # (3,) float64 m, bounding sphere
    radius: float  # m
    pad_origin: np.ndarray  # (3,) float32: padding rays start far above the sphere, pointing away

    @classmethod
    def build(cls, mesh: TriangleMesh, backend: str) -> "_Part":
        centre, radius = mesh.bounding_sphere()
        radius = radius * (1 + 1e-6) + 1e-5  # covers float32 rounding of vertices and rays
        return cls(
            make_caster(backend, mesh.vertices, mesh.triangles),
            np.vstack([mesh.face_normals, np.zeros((1, 3))]).astype(np.float32),
            np.append(mesh.material.astype(np.int32), np.int32(-1)),
            np.append(mesh.object_id, np.uint32(0)),
            centre,
            radius,
            (centre + np.array([0.0, 0.0, 2.0 * radius + 10.0])).astype(np.float32),
        )


class SceneCaster:
    """Static mesh (map frame) + actor meshes (body frames, keyed by actor id), built once.

    ``backend`` is a name from ``available_backends()``; None means ``default_backend()``.
    """

    def __init__(self, static: TriangleMesh, actors: dict[int, TriangleMesh], backend: str | None = None) -> None:
        self.backend = backend or default_backend()
        self._static = _Part.build(static, self.backend)
        self._actors = {int(k): _Part.build(m, self.backend) for k, m in actors.items()}
        self._pad = self.backend in _PAD_BACKENDS
        self._scratch = Scratch()

    @property
    def actor_ids(self) -> list[int]:
        return list(self._actors)

    @property
    def static_tables(self) -> TriangleTables:
        """Float32 face normal, material and object id per static triangle, a last row for "no hit"."""
        return TriangleTables(self._static.normals, self._static.material, self._static.object_id)

    def _cast_part(self, part: _Part, o: np.ndarray, d: np.ndarray, key: str) -> tuple[np.ndarray, np.ndarray]:
        """``part.caster.cast`` of the rays rounded to float32; for padding backends the batch is
        padded to a bucketed size (in buffers reused from cast to cast, one pair per ``key``:
        the static mesh's and each actor's casts keep their own sizes)."""
        n = len(o)
        size = _padded_size(n) if self._pad else n
        if size == n:
            return part.caster.cast(o, d)
        # column-major like the simulator's rays: the copies and the backend's per-coordinate arrays are contiguous
        o_pad = self._scratch.get(f"pad_origins_{key}", (3, size), np.float32).T
        d_pad = self._scratch.get(f"pad_directions_{key}", (3, size), np.float32).T
        o_pad[:n], d_pad[:n] = o, d
        o_pad[n:], d_pad[n:] = part.pad_origin, _PAD_DIRECTION  # misses at the root of the BVH
        dist, tri = part.caster.cast(o_pad, d_pad)
        return dist[:n], tri[:n]

    def cast(
        self,
        origins: np.ndarray,
        directions: np.ndarray,
        actor_poses: dict[int, np.ndarray],
        max_range_m: float,
        *,
        reuse: bool = False,
        gather: bool = True,
    ) -> Hits:
        """Cast rays (N, 3) origins (m) and unit directions, map frame.

        ``actor_poses`` maps actor id -> 4x4 rigid body->map transform; actors not
        listed are absent from this cast. Hits farther than ``max_range_m`` are misses.
        ``reuse``: the normals, materials, object ids and actor ids are views of arrays
        this caster overwrites on its next ``reuse`` cast (saves fresh memory per cast).
        ``gather``: False leaves the static hits' attributes to ``triangle`` (see :class:`Hits`).
        """
        o = np.asarray(origins, dtype=np.float32).reshape(-1, 3)  # C or column-major (see CasterBase)
        d = np.asarray(directions, dtype=np.float32).reshape(-1, 3)
        if len(o) != len(d):
            raise ValueError(f"{len(o)} origins but {len(d)} directions")
        unknown = set(actor_poses) - set(self._actors)
        if unknown:
            raise KeyError(f"poses for actors without a mesh: {sorted(unknown)}; known actors: {self.actor_ids}")
        best, tri = self._cast_part(self._static, o, d, "static")
        best = np.ascontiguousarray(best, dtype=np.float32)
        tri = np.ascontiguousarray(tri, dtype=np.int64)
        new = allocator(self._scratch if reuse else None)
        normal, material, object_id, hit_actor, origin_box, axis, half_angle = _static_pass(
            best, tri, np.float32(max_range_m), o, d, self._static, bool(actor_poses) and len(o) > 0, gather, new
        )
        posed = [(int(a), self._actors[int(a)], *_rigid(pose, a)) for a, pose in actor_poses.items()] if len(o) else []
        if posed:
            # every actor's rays are culled against the static hits at once: rays an actor nearer
            # in the list hides are cast too, and _closer keeps the nearest hit all the same
            spheres, cones = np.empty((len(posed), 4)), np.empty((len(posed), 5))
            box_centre, box_radius = origin_box[0], float(origin_box[1])
            widest = float(half_angle.max()) if len(half_angle) else 0.0  # the widest block cone (rad)
            for k, (_, part, rot, trans) in enumerate(posed):
                centre = rot @ part.centre + trans
                spheres[k, :3], spheres[k, 3] = centre, part.radius
                # u and angle only pre-select blocks (with margins): Python floats are enough
                ux, uy, uz = (centre - box_centre).tolist()
                reach = math.sqrt(ux * ux + uy * uy + uz * uz)
                if reach > part.radius + box_radius:
                    # a ray from o hitting the sphere means the same direction from the box centre
                    # hits the sphere grown by box_radius, seen within this half-angle
                    u, angle = (ux / reach, uy / reach, uz / reach), math.asin((part.radius + box_radius) / reach)
                else:
                    u, angle = (1.0, 0.0, 0.0), -1.0  # every block is a candidate
                # a block is tested (arccos) only if its axis is within the widest block's cone of u, with
                # a margin: this cheap test never rejects a block the exact one keeps
                limit = widest + angle + 1e-6 + 1e-7
                cones[k] = (*u, angle, math.cos(limit) - 1e-9 if limit < math.pi else -2.0)
            culled, counts = _cull(o, d, axis, half_angle, spheres, cones, best, float(max_range_m), self._scratch)
        end = 0
        for (actor_id, part, rot, trans), count in zip(posed, counts if posed else ()):
            end += count
            if not count:
                continue
            idx, shift, start, d64 = (x[end - count : end] for x in culled)
            # row vectors: x_body = R^T (x_map - t)  <=>  (x_map - t) @ R
            dist_b, tri_b = self._cast_part(part, (start - trans) @ rot, d64 @ rot, str(actor_id))
            rays, tri_b, normals_b = _closer(idx, shift, dist_b, tri_b, part.normals, best, float(max_range_m))
            _set_hits(rays, tri_b, normals_b @ rot.T.astype(np.float32), d, part.material, part.object_id, actor_id,
                      tri, normal, material, object_id, hit_actor)  # fmt: skip
        return Hits(best, tri, normal, material, object_id, hit_actor)


def _padded_size(n: int) -> int:
    """``n`` rounded up to a power of two up to 2^14 (casts that small cost the per-call overhead),
    above that to a multiple of 2^(floor(log2 n) - 3): 8 sizes per octave, <= 12.5 % padding."""
    if n <= 1 << 14:
        return max(256, 1 << (int(n) - 1).bit_length())
    step = 1 << (int(n).bit_length() - 4)
    return -(-n // step) * step


def _rigid(pose: np.ndarray, actor_id: int) -> tuple[np.ndarray, np.ndarray]:
    """Rotation (3, 3) and translation (3,) float64 of a 4x4 body->map pose, checked rigid."""
    pose = np.asarray(pose, dtype=np.float64)
    if pose.shape != (4, 4):
        raise ValueError(f"actor {actor_id}: pose must be 4x4, got {pose.shape}")
    rot = pose[:3, :3]
    if not _is_rotation(rot):
        raise ValueError(f"actor {actor_id}: pose rotation is not a proper rotation")
    return rot, pose[:3, 3]


@numba.njit(cache=True, nogil=True)
def _is_rotation(rot):
    """``np.allclose(rot.T @ rot, np.eye(3), atol=1e-6) and np.linalg.det(rot) >= 0``, without
    numpy's per-call overhead (rot is near-orthonormal when it passes: the determinant's sign is clear)."""
    for i in range(3):
        for j in range(3):
            g = rot[0, i] * rot[0, j] + rot[1, i] * rot[1, j] + rot[2, i] * rot[2, j]
            eye = 1.0 if i == j else 0.0
            if not abs(g - eye) <= 1e-6 + 1e-5 * eye:
                return False
    det = (rot[0, 0] * (rot[1, 1] * rot[2, 2] - rot[1, 2] * rot[2, 1])
           - rot[0, 1] * (rot[1, 0] * rot[2, 2] - rot[1, 2] * rot[2, 0])
           + rot[0, 2] * (rot[1, 0] * rot[2, 1] - rot[1, 1] * rot[2, 0]))  # fmt: skip
    return det >= 0


@numba.njit(cache=True, inline="always")
def _origin_box(o, lo, hi, box):
    """Min (box[:3]) and max (box[3:]) of the origins lo..hi, in two independent lanes."""
    lo0, lo1, lo2 = o[lo, 0], o[lo, 1], o[lo, 2]
    hi0, hi1, hi2 = lo0, lo1, lo2
    mo0, mo1, mo2, mx0, mx1, mx2 = lo0, lo1, lo2, lo0, lo1, lo2
    for i in range(lo + 1, hi - 1, 2):
        lo0, hi0 = min(lo0, o[i, 0]), max(hi0, o[i, 0])
        lo1, hi1 = min(lo1, o[i, 1]), max(hi1, o[i, 1])
        lo2, hi2 = min(lo2, o[i, 2]), max(hi2, o[i, 2])
        mo0, mx0 = min(mo0, o[i + 1, 0]), max(mx0, o[i + 1, 0])
        mo1, mx1 = min(mo1, o[i + 1, 1]), max(mx1, o[i + 1, 1])
        mo2, mx2 = min(mo2, o[i + 1, 2]), max(mx2, o[i + 1, 2])
    e0, e1, e2 = o[hi - 1, 0], o[hi - 1, 1], o[hi - 1, 2]
    box[0], box[1], box[2] = min(min(lo0, mo0), e0), min(min(lo1, mo1), e1), min(min(lo2, mo2), e2)
    box[3], box[4], box[5] = max(max(hi0, mx0), e0), max(max(hi1, mx1), e1), max(max(hi2, mx2), e2)


@numba.njit(cache=True, nogil=True)
def _closer(idx, shift, dist_b, tri_b, normals, best, max_range):
    """The actor's hits (distance ``shift + dist_b`` along rays ``idx``, triangles ``tri_b``)
    nearer than ``best`` and within ``max_range``: ``best`` takes them (float32); returns their
    rays, triangles and the triangles' ``normals`` (body frame, (K, 3))."""
    rays, tri, nrm = np.empty(len(idx), np.int64), np.empty(len(idx), np.int64), np.empty((len(idx), 3), normals.dtype)
    count = 0
    for j in range(len(idx)):
        i = idx[j]
        dist = shift[j] + np.float64(dist_b[j])
        if dist < best[i] and dist <= max_range:
            best[i] = dist
            t = tri_b[j]
            rays[count], tri[count] = i, t
            nrm[count, 0], nrm[count, 1], nrm[count, 2] = normals[t, 0], normals[t, 1], normals[t, 2]
            count += 1
    return rays[:count], tri[:count], nrm[:count]


@numba.njit(cache=True, nogil=True)
def _set_hits(sel, tri, normals, d, materials, object_ids, actor_id, triangle, normal, material, object_id,
              hit_actor):  # fmt: skip
    """Rays ``sel`` hit the actor's triangles ``tri``: its map-frame float32 normals (flipped to
    face the ray, float32 dot product as numpy), material, object id and actor id (no static triangle)."""
    for j in range(len(sel)):
        i = sel[j]
        n0, n1, n2 = normals[j, 0], normals[j, 1], normals[j, 2]
        dot = n0 * d[i, 0]
        dot += n1 * d[i, 1]
        dot += n2 * d[i, 2]
        if dot > 0:
            n0, n1, n2 = -n0, -n1, -n2
        normal[i, 0], normal[i, 1], normal[i, 2] = n0, n1, n2
        material[i] = materials[tri[j]]
        object_id[i] = object_ids[tri[j]]
        hit_actor[i] = actor_id
        triangle[i] = -1


#: Rays per chunk when a cast's per-ray passes are shared between threads (:mod:`lidar_weather_sim.core.workers`).
CHUNK_RAYS = 32768


def _static_pass(best, tri, max_range, o, d, part: _Part, blocks: bool, gather: bool, new):
    """Static-mesh hits to per-ray attributes (see :func:`_static_run`; ``new(name, shape, dtype)``
    allocates them; the actor ids are -1; without ``gather`` only allocated), and with ``blocks``
    the origins' bounding box (centre, radius) and the cones of the blocks of rays (else None)."""
    n = len(best)
    attributes = RayAttributes(new("normal", (n, 3), np.float32), new("material", n, np.int32),
                               new("object_id", n, np.uint32), new("hit_actor", n, np.int32))  # fmt: skip
    tables = TriangleTables(part.normals, part.material, part.object_id)
    axis = np.empty((n // _BLOCK if blocks else 0, 3))
    half = np.empty(len(axis))
    cuts = workers.bounds(n, CHUNK_RAYS, align=_BLOCK)
    boxes = np.zeros((len(cuts) - 1, 6))
    workers.run_chunks(
        lambda c: _static_run(best, tri, max_range, o, d, tables, cuts[c], cuts[c + 1], gather, attributes,
                              BlockCones(blocks, _BLOCK, _COS_MARGIN, axis, half, boxes[c])),  # fmt: skip
        len(cuts) - 1,
    )
    box = _bounding_sphere(boxes) if blocks else None
    return *attributes, box, axis, half


@numba.njit(cache=True, nogil=True)
def _bounding_sphere(boxes):
    """Centre (3,) and radius (m) of the sphere around the union of boxes (K, 6) (min, max):
    ``0.5 * (lo + hi)`` and ``0.5 * |hi - lo|`` as numpy's expressions."""
    lo, hi = boxes[0, :3].copy(), boxes[0, 3:].copy()
    for k in range(1, len(boxes)):
        for j in range(3):
            lo[j], hi[j] = min(lo[j], boxes[k, j]), max(hi[j], boxes[k, 3 + j])
    e = hi - lo
    return 0.5 * (lo + hi), 0.5 * np.sqrt(e[0] * e[0] + e[1] * e[1] + e[2] * e[2])


@numba.njit(cache=True, nogil=True)
def _static_run(best, tri, max_range, o, d, tables, lo, hi, gather, attributes, cones):
    """Rays lo..hi (lo a multiple of ``cones.size``). In place: hits beyond ``max_range`` (float32)
    become misses (triangle -1). With ``gather``, writes into ``attributes`` (:class:`RayAttributes`)
    per ray the normal of :class:`TriangleTables` ``tables`` (facing the ray), material and object
    id (a miss gathers the tables' last row) and actor id -1; if ``cones.wanted``, also the
    :class:`BlockCones` (unit axis, half-angle widened by ``cones.cos_margin``) of each full block
    of ``cones.size`` consecutive rays and the origins' min (box[:3]) and max (box[3:])."""
    normals, materials, object_ids = tables
    normal, material, object_id, hit_actor = attributes
    blocks, block, cos_margin, axis, half, box = cones
    miss = len(materials) - 1
    for i in range(lo, hi):
        if best[i] > max_range:
            best[i] = np.inf
            tri[i] = -1
        if not gather:
            continue
        hit_actor[i] = -1
        t = tri[i] if tri[i] >= 0 else miss
        n0, n1, n2 = normals[t, 0], normals[t, 1], normals[t, 2]
        dot = n0 * d[i, 0] + n1 * d[i, 1] + n2 * d[i, 2]  # float32, as numpy
        if dot > 0:
            n0, n1, n2 = -n0, -n1, -n2
        normal[i, 0], normal[i, 1], normal[i, 2] = n0, n1, n2
        material[i] = materials[t]
        object_id[i] = object_ids[t]
    if not blocks or hi <= lo:
        return
    _origin_box(o, lo, hi, box)
    for b in range(lo // block, min(hi // block, len(axis))):
        # a cone only has to hold its rays (the exact test decides): its axis is the block's middle
        # ray; minima in two independent lanes (block is even), which the CPU runs side by side
        i0, mid = b * block, b * block + block // 2
        x, y, z = np.float64(d[mid, 0]), np.float64(d[mid, 1]), np.float64(d[mid, 2])
        norm = np.sqrt(x * x + y * y + z * z)
        if norm > 0:
            ax, ay, az = x / norm, y / norm, z / norm
        else:
            ax, ay, az = 1.0, 0.0, 0.0
        axis[b, 0], axis[b, 1], axis[b, 2] = ax, ay, az
        a0, a1, a2 = np.float32(ax), np.float32(ay), np.float32(az)
        m0 = m1 = np.float32(1.0)
        for i in range(i0, i0 + block, 2):
            m0 = min(m0, d[i, 0] * a0 + d[i, 1] * a1 + d[i, 2] * a2)
            m1 = min(m1, d[i + 1, 0] * a0 + d[i + 1, 1] * a1 + d[i + 1, 2] * a2)
        half[b] = min(max(np.float64(min(m0, m1)) - cos_margin, -1.0), 1.0)
    for b in range(lo // block, min(hi // block, len(axis))):  # independent: the CPU overlaps them
        half[b] = np.arccos(half[b])


def _cull(o, d, axis, half_angle, spheres, cones, best, max_range, scratch):
    """Per sphere (centre, radius: (S, 4)), the rays that may hit it before ``best`` and ``max_range`` (m).

    Candidates are the rays of the blocks whose cone comes within ``angle`` (rad) of the
    unit vector ``u`` (cones: (S, 5) u, angle and the pre-filter's min cos; all blocks if
    ``angle`` < 0) plus the rays after the last full block; each gets the exact float64
    test (numpy's operation order). Returns the :class:`CulledRays` (indices ascending per
    sphere), sphere after sphere, as views of ``scratch`` buffers, and how many rays each
    sphere got (list). The (sphere, block) pairs are shared between threads.
    """
    nb = len(axis)
    pairs = scratch.get("cull_pairs", (len(spheres) * (nb + 1), 2), np.int64)
    pairs = pairs[: _cull_blocks(axis, half_angle, cones, len(o) > nb * _BLOCK, pairs)]
    size = len(pairs) * _BLOCK  # each pair's rays are written from pair index x _BLOCK on
    out = CulledRays(scratch.get("cull_idx", size, np.int64), scratch.get("cull_shift", size, np.float64),
                     scratch.get("cull_start", (size, 3), np.float64),
                     scratch.get("cull_d64", (size, 3), np.float64))  # fmt: skip
    counts = np.empty(len(pairs), np.int64)
    cuts = workers.bounds(len(pairs), CHUNK_RAYS // _BLOCK)
    workers.run_chunks(lambda c: _cull_run(o, d, pairs, spheres, _BLOCK, best, max_range, cuts[c], cuts[c + 1],
                                           out, counts), len(cuts) - 1)  # fmt: skip
    per_sphere = _compact_cull(*out, counts, pairs[:, 0], _BLOCK, len(spheres))
    return out, per_sphere.tolist()


@numba.njit(cache=True, nogil=True)
def _cull_blocks(axis, half_angle, cones, tail, pairs):
    """The (sphere, block) pairs of :func:`_cull`, sphere-major, into ``pairs``; block
    ``len(axis)`` (with ``tail``): the rays after the last full block. Returns how many."""
    nb = len(axis)
    count = 0
    for k in range(len(cones)):
        u0, u1, u2, angle, min_cos = cones[k, 0], cones[k, 1], cones[k, 2], cones[k, 3], cones[k, 4]
        for b in range(nb):
            if angle >= 0:
                cos_gap = axis[b, 0] * u0 + axis[b, 1] * u1 + axis[b, 2] * u2
                if cos_gap < min_cos:
                    continue
                gap = np.arccos(min(max(cos_gap, -1.0), 1.0))
                if not gap <= half_angle[b] + angle + 1e-6:
                    continue
            pairs[count, 0], pairs[count, 1] = k, b
            count += 1
        if tail:
            pairs[count, 0], pairs[count, 1] = k, nb
            count += 1
    return count


@numba.njit(cache=True, nogil=True)
def _compact_cull(idx, shift, start, d64, counts, sphere, block, n_spheres):
    """Move the rays of :func:`_cull`'s pairs (each written from its index x ``block`` on)
    together, in place; returns how many each sphere got."""
    per_sphere = np.zeros(n_spheres, np.int64)
    count = 0
    for p in range(len(counts)):
        src = p * block
        if src != count:
            for k in range(counts[p]):
                idx[count + k], shift[count + k] = idx[src + k], shift[src + k]
                for j in range(3):
                    start[count + k, j], d64[count + k, j] = start[src + k, j], d64[src + k, j]
        count += counts[p]
        per_sphere[sphere[p]] += counts[p]
    return per_sphere


@numba.njit(cache=True, nogil=True)
def _cull_run(o, d, pairs, spheres, block, best, max_range, q0, q1, out, counts):
    """Pairs q0..q1 of :func:`_cull`: each pair's rays written into ``out`` (:class:`CulledRays`)
    from its index x ``block`` on, how many in ``counts``."""
    idx, shift, start, d64 = out
    n = len(o)
    far = np.float32(max_range)
    for q in range(q0, q1):
        k, b = pairs[q, 0], pairs[q, 1]
        centre, radius = spheres[k, :3], spheres[k, 3]
        r2 = radius * radius
        count = q * block
        o0 = o1 = o2 = np.float32(np.nan)  # the origin of the previous ray: rays share origins (a column's)
        v0 = v1 = v2 = vv = limit = 0.0
        i0, i1 = b * block, min((b + 1) * block, n)
        for i in range(i0, i1):
            if not (o[i, 0] == o0 and o[i, 1] == o1 and o[i, 2] == o2):
                o0, o1, o2 = o[i, 0], o[i, 1], o[i, 2]
                v0 = centre[0] - np.float64(o0)
                v1 = centre[1] - np.float64(o1)
                v2 = centre[2] - np.float64(o2)
                vv = v0 * v0 + v1 * v1 + v2 * v2
                limit = r2 + 1e-6 * vv + 1e-9
            x, y, z = np.float64(d[i, 0]), np.float64(d[i, 1]), np.float64(d[i, 2])
            # cheap rejection before normalising: |v|^2 |d|^2 - (v.d)^2 is |d|^2 times the squared
            # perpendicular distance, computed within ~1e-15 |v|^2 |d|^2 (the tolerance is far wider)
            dd = x * x + y * y + z * z
            vd = v0 * x + v1 * y + v2 * z
            if vv * dd - vd * vd > limit * dd:
                continue
            norm = np.sqrt(x * x + y * y + z * z)
            x, y, z = x / norm, y / norm, z / norm
            along = (v0 * x + v2 * z) + v1 * y  # numpy einsum's order
            p0, p1, p2 = v0 - along * x, v1 - along * y, v2 - along * z
            if not (p0 * p0 + p2 * p2) + p1 * p1 <= r2:
                continue
            if not along + radius >= 0:
                continue
            if not along - radius < min(best[i], far):
                continue
            s = max(along - radius, 0.0)
            idx[count] = i
            shift[count] = s
            start[count, 0] = np.float64(o[i, 0]) + s * x
            start[count, 1] = np.float64(o[i, 1]) + s * y
            start[count, 2] = np.float64(o[i, 2]) + s * z
            d64[count, 0], d64[count, 1], d64[count, 2] = x, y, z
            count += 1
        counts[q] = count - q * block
