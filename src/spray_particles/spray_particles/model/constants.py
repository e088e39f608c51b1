"""Model constants from ``config/spray.yaml`` (validated; errors name file, key and value).

Every number the spray model needs that is not a scenario parameter lives in that
file with its source; this module only reads it.
"""

from __future__ import annotations

from functools import lru_cache
from pathlib import Path

from pydantic import Field

from lidar_weather_sim.core.config import ConfigModel, load_yaml


class Physics(ConfigModel):
    gravity_m_s2: float = Field(gt=0)
    air_density_kg_m3: float = Field(gt=0)
    air_viscosity_pa_s: float = Field(ge=0)
    water_density_kg_m3: float = Field(gt=0)
    water_surface_tension_n_m: float = Field(gt=0)
    drag_coefficient: float = Field(gt=0)


class Tyre(ConfigModel):
    size: str = Field(description="ISO metric tyre size, e.g. 255/40R19")
    grooves: int = Field(ge=1)
    groove_width_m: float = Field(gt=0)
    tread_height_m: float = Field(gt=0)
    ring_vertices: int = Field(ge=3)
    treads_across: int = Field(ge=1)


class Water(ConfigModel):
    drop_size_k: float = Field(gt=0)


class Emission(ConfigModel):
    gain_per_mm_m_s: float = Field(ge=0)
    threshold_speed_m_s: float = Field(ge=0)
    frame_period_s: float = Field(gt=0)


class LateralWind(ConfigModel):
    slope: float = Field(ge=0)
    threshold_speed_m_s: float = Field(ge=0)


class Particles(ConfigModel):
    diameter_m: float = Field(gt=0)
    mesh_diameter_m: float = Field(gt=0)
    single_scattering_albedo: float = Field(ge=0, le=1)
    backscatter_phase: float = Field(gt=0, le=1)
    lateral_field_range_m: tuple[float, float]


class Drops(ConfigModel):
    airborne_fraction: float = Field(gt=0, le=1)
    size_sigma_ln: float = Field(gt=0)
    min_diameter_m: float = Field(gt=0)
    max_diameter_m: float = Field(gt=0)


class Mist(ConfigModel):
    initial_radius_m: float = Field(gt=0)
    mixing_length_m: float = Field(ge=0)


class Reference(ConfigModel):
    drops_per_wheel_per_tick: int = Field(ge=1)
    lifetime_s: float = Field(gt=0)
    range_cell_m: float = Field(gt=0)
    kernel_radius_m: float = Field(gt=0)


class SprayConstants(ConfigModel):
    physics: Physics
    particles: Particles
    drops: Drops
    mist: Mist
    tyre: Tyre
    water: Water
    emission: Emission
    lateral_wind: LateralWind
    reference: Reference


def constants_path() -> Path:
    from lidar_weather_sim.core.paths import config_dir

    return config_dir() / "spray.yaml"


@lru_cache(maxsize=4)
def load_constants(path: str | None = None) -> SprayConstants:
    """The constants of ``path`` (default ``config/spray.yaml``)."""
    return load_yaml(Path(path) if path else constants_path(), SprayConstants)
