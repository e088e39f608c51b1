"""The material table: optical properties at 905 nm, looked up by name or index.

Meshes carry a material *index* per triangle (:class:`~lidar_weather_sim.scene.mesh.TriangleMesh`);
this table maps index <-> name <-> :class:`~lidar_weather_sim.scene.mesh.Material`. The
defaults live in ``config/materials.yaml`` (the single source of the numbers);
:meth:`MaterialTable.default` loads it.

YAML schema (``materials:`` mapping, order = index)::

    materials:
      asphalt_dry: {reflectivity: 0.12, retro_share: 0.0, label: STATIC, source: "..."}
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pydantic

from lidar_weather_sim.core.config import ConfigModel, load_yaml
from lidar_weather_sim.core.points import Label
from lidar_weather_sim.scene.mesh import Material


class MaterialSpec(ConfigModel):
    """One material entry of ``config/materials.yaml``."""

    reflectivity: float = pydantic.Field(ge=0.0, le=1.0, description="Diffuse (Lambertian) NIR albedo at 905 nm, 0-1")
    retro_share: float = pydantic.Field(
        0.0, ge=0.0, le=1.0, description="Fraction of returned power that is retro-reflected, 0-1"
    )
    label: str = pydantic.Field("STATIC", description="Ground-truth label name (points.Label), e.g. STATIC, VEHICLE")
    source: str = pydantic.Field("", description="Where the value comes from (citation or 'estimate')")

    @pydantic.field_validator("label")
    @classmethod
    def _known_label(cls, value: str) -> str:
        if value.upper() not in Label.__members__:
            raise ValueError(f"unknown label; expected one of {', '.join(Label.__members__)}")
        return value.upper()


class MaterialsFile(ConfigModel):
    """Top level of ``config/materials.yaml``."""

    materials: dict[str, MaterialSpec] = pydantic.Field(min_length=1, description="name -> optical properties")


class MaterialTable:
    """Ordered, immutable set of :class:`Material`; index = position (uint16 in meshes).

    Vectorised lookups for ray casters: :attr:`reflectivity`, :attr:`retro_share`
    and :attr:`labels` are arrays indexed by a mesh's ``material`` array.
    """

    def __init__(self, materials: list[Material]) -> None:
        names = [m.name for m in materials]
        if len(set(names)) != len(names):
            raise ValueError(f"duplicate material names in {names}")
        self.materials: tuple[Material, ...] = tuple(materials)
        self._index = {name: i for i, name in enumerate(names)}
        self.reflectivity = np.array([m.reflectivity for m in materials], dtype=np.float64)
        self.retro_share = np.array([m.retro_share for m in materials], dtype=np.float64)
        self.labels = np.array([int(m.label) for m in materials], dtype=np.uint8)
        for arr in (self.reflectivity, self.retro_share, self.labels):
            arr.flags.writeable = False

    @classmethod
    def from_config(cls, config: MaterialsFile) -> "MaterialTable":
        return cls(
            [
                Material(name, spec.reflectivity, spec.retro_share, Label[spec.label])
                for name, spec in config.materials.items()
            ]
        )

    @classmethod
    def from_yaml(cls, path: str | Path) -> "MaterialTable":
        """Load and validate a materials YAML file (:class:`ConfigError` names file and key)."""
        return cls.from_config(load_yaml(path, MaterialsFile))

    @classmethod
    def default(cls) -> "MaterialTable":
        """The workspace's ``config/materials.yaml`` (see :mod:`lidar_weather_sim.core.paths`)."""
        from lidar_weather_sim.core.paths import config_dir

        return cls.from_yaml(config_dir() / "materials.yaml")

    @property
    def names(self) -> list[str]:
        return [m.name for m in self.materials]

    def index(self, name: str) -> int:
        """Material index of ``name``; :class:`KeyError` listing the known names otherwise."""
        try:
            return self._index[name]
        except KeyError:
            raise KeyError(f"unknown material '{name}'; known: {', '.join(self._index)}") from None

    def __getitem__(self, key: int | str) -> Material:
        return self.materials[self.index(key) if isinstance(key, str) else key]

    def __contains__(self, name: object) -> bool:
        return name in self._index

    def __len__(self) -> int:
        return len(self.materials)

    def __iter__(self):
        return iter(self.materials)

    def __repr__(self) -> str:
        return f"MaterialTable({', '.join(self._index)})"


__all__ = ["MaterialSpec", "MaterialsFile", "MaterialTable"]
