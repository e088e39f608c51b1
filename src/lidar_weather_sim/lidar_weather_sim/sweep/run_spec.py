"""One run of a sweep and its identity.

A run's identity is the SHA-256 of its spec (validated scenario, seed, frames, profile,
return mode, what it computes) and of the code version (:func:`code_version`): the same
run of the same code is never run twice in one output directory; a change of the code,
the configuration or the maps makes every run new.
"""

from __future__ import annotations

import hashlib
import json
from dataclasses import asdict, dataclass, field
from functools import cache
from importlib.util import find_spec
from pathlib import Path
from typing import Any

#: Packages whose files are the simulator's behaviour (found without importing the plugins).
CODE_PACKAGES = ("lidar_weather_sim", "spray_particles", "weather_filter")
_SKIP_SUFFIXES = (".pyc", ".nbi", ".nbc")


@dataclass(frozen=True)
class RunSpec:
    scenario: dict[str, Any]  # the run's scenario, validated, as JSON data
    point: dict[str, Any]  # swept dotted key -> its value in this run
    seed: int
    frames: int
    profile: str | None = None
    return_mode: str | None = None
    compute: list[Any] = field(default_factory=list)

    def identity(self, version: str) -> str:
        """16 hex digits of the SHA-256 of this spec and the code ``version``."""
        text = json.dumps({"spec": asdict(self), "code": version}, sort_keys=True, default=str)
        return hashlib.sha256(text.encode()).hexdigest()[:16]


def _files(root: Path) -> list[Path]:
    return sorted(p for p in root.rglob("*") if p.is_file() and "__pycache__" not in p.parts
                  and not p.name.endswith(_SKIP_SUFFIXES))  # fmt: skip


@cache
def code_version() -> str:
    """SHA-256 (16 hex digits) of the files of :data:`CODE_PACKAGES` and the workspace's config/ and maps/."""
    from lidar_weather_sim.core.paths import config_dir, maps_dir

    roots = [Path(loc) for name in CODE_PACKAGES if (s := find_spec(name)) and s.submodule_search_locations
             for loc in s.submodule_search_locations]  # fmt: skip
    digest = hashlib.sha256()
    for root in [*roots, config_dir(), maps_dir()]:
        for path in _files(root.resolve()):
            digest.update(str(path.relative_to(root.resolve())).encode())
            digest.update(path.read_bytes())
    return digest.hexdigest()[:16]
