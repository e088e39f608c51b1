"""The sensor's own near-field structure in a recording: a fixed ego part, kept out of the world mesh.

A roof rack, the car's roof edge or a bracket within reach of the beams returns at the same place *in the
sensor frame* in every frame while the world passes by. Meshed into the world it would be smeared along the
path; the twin writes it into the scenario as a fixed part of the sensor instead
(``sensor.fixed_parts``, :class:`lidar_weather_sim.scenario.schema.FixedPart`), which the simulator casts in
the sensor frame.

:func:`detect_ego_part`: only when the sensor moves more than :data:`MIN_TRAVEL_M` over at least
:data:`MIN_FRAMES` frames (standing still, the world is as fixed in the sensor frame as the ego is). Points within :data:`RADIUS_M` of the sensor
are binned in :data:`VOXEL_M` voxels of the sensor frame; a voxel is *present* in a frame when a point of that
frame lies in it or one of its 26 neighbours (range noise moves a fixed point across a voxel boundary). A voxel
with points is ego when it is present in at least :data:`MIN_SHARE` of the frames and the sensor positions of
those frames span more than :data:`MIN_TRAVEL_M` (bounding-box diagonal): a static world point near the sensor
at the start does not stay at one sensor-frame place while the sensor moves away. A flat road under a
sensor driving straight keeps its sensor-frame place too: a voxel is the world's when the other frames, looking
at its points' map-frame places (in direction bins of :data:`BIN_DEG`, the twin: its beam spacing), see a surface
there as often as they see through the place (an ego part is gone from where it was once the sensor moved on,
so a frame from elsewhere sees past it; the road is still there). Without such a look (no frame saw through the
place) a voxel is not called ego either.

:func:`ego_part_mesh`: the ego voxels as closed cubes (faces between two ego voxels left out), sensor frame, with
the reflectivity of each voxel's points (the twin's inversion at normal incidence) per face.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

RADIUS_M = 2.0  # points nearer the sensor than this may be the ego's
VOXEL_M = 0.05  # sensor-frame voxel (m)
MIN_TRAVEL_M = 2.0  # the sensor must move farther than this over the frames (and over a voxel's frames)
MIN_SHARE = 0.9  # of the frames a voxel must be present in
MIN_FRAMES = 3  # fewer frames say too little (two frames of near-field clutter can coincide)
MARGIN_M, MARGIN_FRACTION = 0.3, 0.03  # another frame's returns this far (+ share of the range) from a place
BIN_DEG = 1.0  # direction bins of the other frames' look at a candidate's place (deg; the twin: its beam spacing)

_OFFSETS = np.array([(i, j, k) for i in (-1, 0, 1) for j in (-1, 0, 1) for k in (-1, 0, 1)], dtype=np.int64)
_BIAS = 1 << 20  # voxel keys are packed as 3 x 21 bits (+-52 km at 5 cm, far beyond RADIUS_M)


@dataclass(frozen=True)
class EgoDetection:
    """Per frame the mask of its ego points; the ego voxels (K, 3) int keys of the sensor frame; how far the
    sensor moved (m); and one line saying what was found or why nothing was looked for."""

    masks: list[np.ndarray]
    voxels: np.ndarray
    travel_m: float
    note: str

    @property
    def points(self) -> int:
        return int(sum(int(m.sum()) for m in self.masks))


def _pack(keys: np.ndarray) -> np.ndarray:
    k = keys + _BIAS
    return (k[:, 0] << 42) | (k[:, 1] << 21) | k[:, 2]


def _unpack(packed: np.ndarray) -> np.ndarray:
    mask = (1 << 21) - 1
    return np.stack([(packed >> 42) & mask, (packed >> 21) & mask, packed & mask], axis=1) - _BIAS


def _span(positions: np.ndarray) -> float:
    return float(np.linalg.norm(positions.max(axis=0) - positions.min(axis=0))) if len(positions) else 0.0


def detect_ego_part(local: list[np.ndarray], world: list[np.ndarray], positions: np.ndarray,
                    poses: list[np.ndarray] | None = None, radius_m: float = RADIUS_M, voxel_m: float = VOXEL_M,
                    min_travel_m: float = MIN_TRAVEL_M, min_share: float = MIN_SHARE,
                    bin_deg: float = BIN_DEG) -> EgoDetection:  # fmt: skip
    """The ego part of frames given as their points in the sensor frame ``local`` (N_f, 3) m, the same points in
    the map frame ``world`` (N_f, 3) m, and the sensor position of each frame ``positions`` (F, 3) m; ``poses``
    (4x4 sensor -> map per frame, e.g. at mid-frame) place the other frames' looks at a candidate's place
    (default: a translation, read off the first point of each frame) (module doc)."""
    none = [np.zeros(len(x), dtype=bool) for x in local]
    positions = np.asarray(positions, dtype=np.float64).reshape(-1, 3)
    travel = _span(positions)
    if len(local) < MIN_FRAMES:
        return EgoDetection(none, np.zeros((0, 3), np.int64), travel,
                            f"{len(local)} frames (fewer than {MIN_FRAMES}): no ego part looked for")  # fmt: skip
    if travel <= min_travel_m:
        return EgoDetection(none, np.zeros((0, 3), np.int64), travel,
                            f"the sensor moved {travel:.2f} m (not more than {min_travel_m:g} m): no ego part looked for")  # fmt: skip
    near = [np.linalg.norm(x, axis=1) < radius_m for x in local]
    keys = [_pack(np.floor(x[m] / voxel_m).astype(np.int64)) for x, m in zip(local, near)]
    occupied = np.unique(np.concatenate(keys))
    # presence: the voxel or a neighbour holds a point of the frame; counted, with the frames' position span
    count = np.zeros(len(occupied), np.int64)
    lo = np.full((len(occupied), 3), np.inf)
    hi = np.full((len(occupied), 3), -np.inf)
    for f, k in enumerate(keys):
        if not len(k):
            continue
        present = np.unique(_pack((_unpack(np.unique(k))[:, None, :] + _OFFSETS[None]).reshape(-1, 3)))
        idx = _members(occupied, present)
        count[idx] += 1
        lo[idx] = np.minimum(lo[idx], positions[f])
        hi[idx] = np.maximum(hi[idx], positions[f])
    span = np.where(count > 0, np.linalg.norm(np.where(count[:, None] > 0, hi - lo, 0.0), axis=1), 0.0)
    ego = occupied[(count >= min_share * len(local)) & (span > min_travel_m)]
    masks = []
    for x, m, k in zip(local, near, keys):
        mask = np.zeros(len(x), dtype=bool)
        mask[np.flatnonzero(m)] = np.isin(k, ego)
        masks.append(mask)
    fixed = len(ego)
    ego, masks = _not_world(ego, masks, keys, near, world, positions, poses, np.radians(bin_deg))
    found = int(sum(int(m.sum()) for m in masks))
    world_note = f"; {fixed - len(ego)} more stay fixed but the other frames see the world there" if fixed > len(ego) else ""
    note = (f"{len(ego)} voxels of {voxel_m:g} m ({found} points) within {radius_m:g} m stay fixed in the sensor frame "
            f"while it moved {travel:.2f} m: a fixed ego part{world_note}" if len(ego) else
            f"no ego part: nothing within {radius_m:g} m stays fixed in the sensor frame while it moved {travel:.2f} m"
            f"{world_note}")  # fmt: skip
    return EgoDetection(masks, _unpack(ego), travel, note)


def _members(sorted_keys: np.ndarray, keys: np.ndarray) -> np.ndarray:
    """Indices into ``sorted_keys`` of those ``keys`` it holds."""
    idx = np.searchsorted(sorted_keys, keys)
    ok = idx < len(sorted_keys)
    ok[ok] = sorted_keys[idx[ok]] == keys[ok]
    return idx[ok]


def _direction_bins(local: np.ndarray, bin_rad: float) -> tuple[np.ndarray, np.ndarray]:
    """Range (N,) and a direction bin index (N,) (elevation row x azimuth column of ``bin_rad``) of sensor-frame points."""
    r = np.linalg.norm(local, axis=1)
    az = np.arctan2(local[:, 1], local[:, 0])
    el = np.arcsin(np.clip(local[:, 2] / np.maximum(r, 1e-9), -1.0, 1.0))
    columns = int(np.ceil(2 * np.pi / bin_rad))
    row = np.floor((el + 0.5 * np.pi) / bin_rad).astype(np.int64)
    col = np.floor((az + np.pi) / bin_rad).astype(np.int64) % columns
    return r, row * columns + col


def _not_world(ego: np.ndarray, masks: list[np.ndarray], keys: list[np.ndarray], near: list[np.ndarray],
               world: list[np.ndarray], positions: np.ndarray, poses: list[np.ndarray] | None,
               bin_rad: float) -> tuple[np.ndarray, list[np.ndarray]]:  # fmt: skip
    """``ego`` without the voxels whose points the other frames show as a surface of the world (module doc): each
    candidate point's map-frame place is looked at from every other frame, in its direction bin of ``bin_rad``;
    the other frame *saw through* it when all its returns in that bin lie beyond (range + :data:`MARGIN_M` +
    :data:`MARGIN_FRACTION` x range), and *saw a surface there* when its returns in that bin span the range
    within that margin. A voxel stays ego only with more see-through than surface observations: without a frame
    that saw past the place nothing says the structure left it with the sensor."""
    if not len(ego):
        return ego, masks
    frames = range(len(world))
    cand_world = [w[m] for w, m in zip(world, masks)]
    cand_key = [k[np.isin(k, ego)] for k in keys]
    through = np.zeros(len(ego))
    surface = np.zeros(len(ego))
    for j in frames:
        # frame j's points and the candidates seen from one pose (both deskewed to it, whatever the speed)
        rot, trans = (poses[j][:3, :3], poses[j][:3, 3]) if poses is not None else (np.eye(3), positions[j])
        r_j, bin_j = _direction_bins((world[j] - trans) @ rot, bin_rad)
        order = np.argsort(bin_j)
        bins, first = np.unique(bin_j[order], return_index=True)
        lo = np.minimum.reduceat(r_j[order], first) if len(first) else np.zeros(0)
        hi = np.maximum.reduceat(r_j[order], first) if len(first) else np.zeros(0)
        for k in frames:
            if k == j or not len(cand_world[k]) or not len(bins):
                continue
            r, b = _direction_bins((cand_world[k] - trans) @ rot, bin_rad)
            idx = np.searchsorted(bins, b)
            seen = idx < len(bins)
            seen[seen] = bins[idx[seen]] == b[seen]
            idx = np.minimum(idx, len(bins) - 1)
            margin = MARGIN_M + MARGIN_FRACTION * r
            beyond = seen & (lo[idx] > r + margin)
            there = seen & (lo[idx] - margin <= r) & (r <= hi[idx] + margin)
            voxel = np.searchsorted(ego, cand_key[k])
            through += np.bincount(voxel, weights=beyond, minlength=len(ego))
            surface += np.bincount(voxel, weights=there, minlength=len(ego))
    kept = ego[through > surface]
    if len(kept) == len(ego):
        return ego, masks
    out = []
    for m, k, n in zip(masks, keys, near):
        mask = np.zeros(len(m), dtype=bool)
        mask[np.flatnonzero(n)] = np.isin(k, kept)
        out.append(mask)
    return kept, out


def voxel_reflectivity(voxels: np.ndarray, local: np.ndarray, rho: np.ndarray, voxel_m: float = VOXEL_M) -> np.ndarray:
    """Per ego voxel (K,) the median reflectivity ``rho`` of the points ``local`` (sensor frame) in it (the median
    of all given points for a voxel without any)."""
    keys = _pack(np.floor(local / voxel_m).astype(np.int64))
    packed = _pack(voxels)
    order = np.argsort(packed)
    out = np.full(len(voxels), float(np.median(rho)) if len(rho) else 0.1)
    idx = np.searchsorted(packed[order], keys)
    ok = idx < len(packed)
    ok[ok] = packed[order][idx[ok]] == keys[ok]
    for k in np.unique(idx[ok]):
        out[order[k]] = float(np.median(rho[ok][idx[ok] == k]))
    return out


# the 6 faces of a unit cube: outward direction and its 4 corners (counter-clockwise seen from outside)
_FACES = [
    ((-1, 0, 0), [(0, 0, 0), (0, 0, 1), (0, 1, 1), (0, 1, 0)]),
    ((1, 0, 0), [(1, 0, 0), (1, 1, 0), (1, 1, 1), (1, 0, 1)]),
    ((0, -1, 0), [(0, 0, 0), (1, 0, 0), (1, 0, 1), (0, 0, 1)]),
    ((0, 1, 0), [(0, 1, 0), (0, 1, 1), (1, 1, 1), (1, 1, 0)]),
    ((0, 0, -1), [(0, 0, 0), (0, 1, 0), (1, 1, 0), (1, 0, 0)]),
    ((0, 0, 1), [(0, 0, 1), (1, 0, 1), (1, 1, 1), (0, 1, 1)]),
]


def ego_part_mesh(voxels: np.ndarray, reflectivity: np.ndarray, voxel_m: float = VOXEL_M) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Vertices (V, 3) m, triangles (T, 3) and per-triangle reflectivity (T,) of the voxels (K, 3) as cubes,
    sensor frame; a face shared by two voxels is left out."""
    voxels = np.asarray(voxels, dtype=np.int64).reshape(-1, 3)
    packed = np.sort(_pack(voxels)) if len(voxels) else np.zeros(0, np.int64)
    vertices, triangles, refl = [], [], []
    n = 0
    for direction, corners in _FACES:
        neighbour = _pack(voxels + np.array(direction))
        idx = np.searchsorted(packed, neighbour)
        shared = (idx < len(packed)) & (packed[np.minimum(idx, len(packed) - 1)] == neighbour) if len(packed) else np.zeros(0, bool)
        outer = voxels[~shared]
        if not len(outer):
            continue
        quad = (outer[:, None, :] + np.array(corners)[None]) * voxel_m  # (F, 4, 3)
        vertices.append(quad.reshape(-1, 3))
        base = n + 4 * np.arange(len(outer))[:, None]
        triangles.append(np.concatenate([base + [0, 1, 2], base + [0, 2, 3]]))
        refl.append(np.tile(reflectivity[~shared], 2))
        n += 4 * len(outer)
    if not vertices:
        return np.zeros((0, 3)), np.zeros((0, 3), np.int64), np.zeros(0)
    return np.concatenate(vertices), np.concatenate(triangles), np.concatenate(refl)
