"""A scene caster that keeps the hits it cast, for re-simulations that cast the same rays again.

The gap search re-simulates the same recorded frames with other weather hundreds of times (one evaluation per
effect value): the sensor poses, the actors and the scene are those of the recording every time, so every
evaluation casts the same rays into the same scene. :class:`MemoCaster` casts a batch of rays once and hands out
copies of its hits afterwards: the same hits bit for bit. A batch is known by its rays (the float32 origins and
directions, byte for byte), the actors' poses, the range and whether the static hits' attributes were gathered,
so anything that moves a ray (a channel's elevation offset, the beams' origin) casts anew.
"""

from __future__ import annotations

from dataclasses import fields

import numpy as np

from lidar_weather_sim.scene.raycast.scene_caster import Hits

#: Hits and rays kept at most (bytes): beyond it a batch not yet kept is cast and not kept (60 bytes a sub-ray:
#: ~47 MB an OS1-128 x 2048 frame of 3 sub-rays a beam, ~0.2 MB a scala4 frame).
DEFAULT_MAX_BYTES = 1 << 30


class MemoCaster:
    """``caster`` (a :class:`~lidar_weather_sim.scene.raycast.scene_caster.SceneCaster`) whose casts are kept and
    handed out again as copies (module doc); every other attribute is the caster's."""

    def __init__(self, caster, max_bytes: int = DEFAULT_MAX_BYTES) -> None:
        self.caster = caster
        self.max_bytes = int(max_bytes)
        self.kept_bytes = 0
        self.hits = 0  # casts answered from the kept hits
        self._kept: dict[tuple, Hits] = {}

    def __getattr__(self, name: str):
        return getattr(self.caster, name)

    def cast(self, origins: np.ndarray, directions: np.ndarray, actor_poses: dict[int, np.ndarray],
             max_range_m: float, *, reuse: bool = False, gather: bool = True) -> Hits:  # fmt: skip
        """:meth:`SceneCaster.cast`, from the kept hits where these rays were cast before (new arrays either way:
        ``reuse`` is not passed on, as the kept hits must not be overwritten)."""
        key = _key(origins, directions, actor_poses, max_range_m, gather)
        kept = self._kept.get(key)
        if kept is None:
            kept = self.caster.cast(origins, directions, actor_poses, max_range_m, gather=gather)
            size = sum(getattr(kept, f.name).nbytes for f in fields(Hits)) + len(key[0]) + len(key[1])
            if self.kept_bytes + size > self.max_bytes:
                return kept
            self._kept[key] = kept
            self.kept_bytes += size
        else:
            self.hits += 1
        return Hits(*(getattr(kept, f.name).copy() for f in fields(Hits)))


def _key(origins: np.ndarray, directions: np.ndarray, actor_poses: dict[int, np.ndarray], max_range_m: float,
         gather: bool) -> tuple:  # fmt: skip
    """A cast's inputs as a dictionary key: the rays' bytes as the caster takes them (float32, in their memory
    order: the simulator's are column-major), the poses', the range and gather. Equal keys are equal inputs (the
    dictionary compares the bytes, not only their hash)."""
    rays = []
    for r in (origins, directions):
        r = np.asarray(r, np.float32).reshape(-1, 3)
        rays.append(r.T.tobytes() if r.T.flags.c_contiguous else r.tobytes(order="C") + b"C")
    poses = b"".join(int(a).to_bytes(8, "little", signed=True) + np.asarray(p, np.float64).tobytes()
                     for a, p in sorted(actor_poses.items()))  # fmt: skip
    return (*rays, poses, float(max_range_m), bool(gather))
