"""The region plugin protocol (thesis framework: cover, atmosphere, object emission).

A region changes how light travels; it never decides detection or EPW (the echo
stage does, :mod:`lidar_weather_sim.sensor.echo`). For each batch of sub-rays a region
returns a :class:`RegionEffect`:

- ``transmission`` (N, S): one-way transmission factor (cover dirt, 0-1); the
  echo stage squares it (out and back);
- ``extinction_per_m`` (N, S): extinction coefficient alpha (1/m) of a
  homogeneous medium along the ray; the echo stage applies exp(-2 alpha R);
- ``scatterers``: extra candidate returns (drops, flakes, spray, cover
  multipath) at given ranges with an effective reflectance, an occlusion share
  of the sub-ray, a label and an object id;
- ``reflectance_scale`` (N, S): multiplies the reflectance of scene hits
  (wet asphalt), ``range_offset_m`` (N, S): moves scene hits along the ray
  (snow cover raises the road: negative offsets);
- ``volume``: volume returns (:class:`VolumeTerm`), a medium's waveform read per beam from a table
  (:mod:`lidar_weather_sim.sensor.volume_tables`), cut at the beam's hard target.

Regions advance in simulated time with ``step(t0_s, t1_s)`` and draw all
randomness from the generator they are given, seeded from (seed, frame,
plugin name, first column) by the simulator: same seed, same output.

Threads: on a large batch the simulator applies its regions side by side, one thread each, and
detects the batch in the background while the next one is cast and applied. So ``apply`` must not
change the batch or share mutable state with another region, and the arrays of the effect it returns
must stay as they are after it returns (new arrays, not buffers the region reuses next batch).

Plugins register under the entry-point group ``lidar_weather_sim.regions``::

    [options.entry_points] / setup(entry_points=...)
    lidar_weather_sim.regions = cover = my_pkg.cover:CoverRegion

A plugin class has a ``Params`` attribute (a :class:`~lidar_weather_sim.core.config.ConfigModel`
subclass) and is built as ``cls(params, context)``. A minimal plugin package to copy:
``templates/region_template`` at the repository root (its README says how to rename, build and use
it); the shipped regions' pages are in ``src/lidar_weather_sim/docs/regions``.
"""

from __future__ import annotations

import zlib
from dataclasses import dataclass
from typing import Any, ClassVar, Protocol, runtime_checkable

import numpy as np

from lidar_weather_sim.core.config import ConfigError, ConfigModel, validate
from lidar_weather_sim.core.registry import Registry
from lidar_weather_sim.sensor.volume_tables import VolumeTable

ENTRY_POINT_GROUP = "lidar_weather_sim.regions"


@dataclass(frozen=True)
class RegionContext:
    """What a region may know about the set-up: the sensor profile, the weather block of the
    scenario (may be None), the scene's materials table (may be None), the scenario's actors,
    a source of their poses over simulated time and the topic inputs (may be None)."""

    profile: Any
    weather: Any = None
    materials: Any = None
    actors: Any = None  # the scenario's actors (list of scenario.Actor), for emitting regions (spray)
    pose_source: Any = None  # anything with actor_poses(t) -> {actor id: 4x4 body-to-world}, e.g. the player
    inputs: Any = None  # a topic_inputs.TopicInputs: points other nodes publish (spray source: topic)
    #: a store the regions of successive builds with the same actors and pose source share (None: nothing shared):
    #: a region keeps there what it would otherwise compute again (the spray particles' states)
    memo: dict | None = None


@dataclass
class RayBatch:
    """Sub-rays of N beams x S sub-rays, world frame unless noted.

    ``origins`` (N, 3) m; ``directions`` (N, S, 3) unit; ``sensor_directions``
    (N, S, 3) unit in the sensor frame; ``channel`` (N,); ``time_s`` (N,) absolute
    simulated firing time (s); ``weights`` (S,) beam energy share; scene hits:
    ``distance`` (N, S) m (inf = miss), ``normal`` (N, S, 3), ``material`` (N, S)
    index (-1 miss), ``object_id`` (N, S), ``label`` (N, S); ``column`` (N,) the scan column of
    each beam (:class:`~lidar_weather_sim.sensor.scan.ScanPattern`; None when the rays are not
    from the pattern): with ``channel`` it indexes per-direction tables a region may keep.
    """

    frame_index: int
    origins: np.ndarray
    directions: np.ndarray
    sensor_directions: np.ndarray
    channel: np.ndarray
    time_s: np.ndarray
    weights: np.ndarray
    distance: np.ndarray
    normal: np.ndarray
    material: np.ndarray
    object_id: np.ndarray
    label: np.ndarray
    column: np.ndarray | None = None

    @property
    def shape(self) -> tuple[int, int]:
        return self.distance.shape


@dataclass
class Scatterers:
    """Candidate returns added by a region, one row each.

    ``beam``/``subray`` index the batch; ``range_m`` along the ray (m);
    ``reflectance`` effective (as for a surface hit: P = C w rho / R^2);
    ``occlusion`` share of the sub-ray's light blocked from there on (0-1);
    ``bypass_overlap`` (optional, bool) marks returns that reach the receiver by
    another path than the biaxial overlap (multipath inside the sensor cover):
    the echo stage uses O(R) = 1 for them.
    """

    beam: np.ndarray
    subray: np.ndarray
    range_m: np.ndarray
    reflectance: np.ndarray
    occlusion: np.ndarray
    label: np.ndarray
    object_id: np.ndarray
    bypass_overlap: np.ndarray | None = None

    @classmethod
    def concatenate(cls, parts: list["Scatterers"]) -> "Scatterers | None":
        parts = [p for p in parts if p is not None and len(p.beam)]
        if not parts:
            return None
        if any(p.bypass_overlap is not None for p in parts):
            parts = [p if p.bypass_overlap is not None else
                     cls(*(getattr(p, f) for f in list(cls.__dataclass_fields__)[:-1]), np.zeros(len(p.beam), bool))
                     for p in parts]  # fmt: skip
        return cls(*(None if getattr(parts[0], f) is None else np.concatenate([getattr(p, f) for p in parts])
                     for f in cls.__dataclass_fields__))  # fmt: skip


@dataclass
class VolumeTerm:
    """A volume return on the beams of a batch: ``table``'s waveform (noise units, the whole beam: it holds the
    overlap, 1/r^2 and the medium's own extinction) times ``scale`` (N,) on each beam (0: none), cut at ``hit_m``
    (N,) m along the beam (None: the central sub-ray's scene hit, moved by the range offset). The echo stage
    multiplies ``scale`` by the central sub-ray's two-way transmission (e.g. a dirty cover). ``table`` may be a
    tuple of tables (e.g. realisations of a fluctuating medium), of which beam i reads ``table[choice[i]]``."""

    table: VolumeTable | tuple[VolumeTable, ...]
    scale: np.ndarray
    hit_m: np.ndarray | None = None
    choice: np.ndarray | None = None  # (N,) index into ``table`` when it is a tuple

    @property
    def tables(self) -> tuple[VolumeTable, ...]:
        """The term's tables (one, or the tuple)."""
        return self.table if isinstance(self.table, tuple) else (self.table,)

    def beam_table(self, n: int) -> np.ndarray:
        """(n,) the index into :attr:`tables` that each beam reads."""
        if self.choice is None:
            return np.zeros(n, np.int64)
        return np.asarray(self.choice, np.int64)


@dataclass
class RegionEffect:
    transmission: np.ndarray | None = None
    extinction_per_m: np.ndarray | None = None
    scatterers: Scatterers | None = None
    reflectance_scale: np.ndarray | None = None
    range_offset_m: np.ndarray | None = None
    volume: list[VolumeTerm] | None = None


@runtime_checkable
class Region(Protocol):
    name: ClassVar[str]
    Params: ClassVar[type[ConfigModel]]

    def step(self, t0_s: float, t1_s: float) -> None: ...

    def apply(self, batch: RayBatch, rng: np.random.Generator) -> RegionEffect: ...


class RegionRegistry(Registry[type]):
    """Region classes by name: installed entry points (``ENTRY_POINT_GROUP``) plus explicit registrations;
    an unknown name raises :class:`ConfigError`."""

    def __init__(self) -> None:
        super().__init__("region", ENTRY_POINT_GROUP, ConfigError)

    def create(self, name: str, params: dict | None, context: RegionContext) -> Region:
        """Build region ``name`` from a parameter mapping validated by its schema."""
        cls = self.get(name)
        return cls(validate(params or {}, cls.Params, f"region '{name}' parameters"), context)


REGISTRY = RegionRegistry()


def region_rng(seed: int, frame_index: int, name: str, first_column: int) -> np.random.Generator:
    """The generator a region draws from for one batch: a pure function of its arguments."""
    return np.random.default_rng(region_entropy(seed, frame_index, name, first_column))


def region_entropy(seed: int, frame_index: int, name: str, first_column: int) -> list[int]:
    """The seed of :func:`region_rng` (``np.random.default_rng``'s entropy)."""
    return [seed & 0xFFFFFFFF, frame_index, zlib.crc32(name.encode()), first_column]


def combine(effects: list[RegionEffect], shape: tuple[int, int]) -> RegionEffect:
    """One effect equivalent to applying ``effects`` together (products, sums, concatenation)."""
    out = RegionEffect(
        transmission=np.ones(shape),
        extinction_per_m=np.zeros(shape),
        reflectance_scale=np.ones(shape),
        range_offset_m=np.zeros(shape),
    )
    for e in effects:
        if e.transmission is not None:
            out.transmission = out.transmission * e.transmission
        if e.extinction_per_m is not None:
            out.extinction_per_m = out.extinction_per_m + e.extinction_per_m
        if e.reflectance_scale is not None:
            out.reflectance_scale = out.reflectance_scale * e.reflectance_scale
        if e.range_offset_m is not None:
            out.range_offset_m = out.range_offset_m + e.range_offset_m
    out.scatterers = Scatterers.concatenate([e.scatterers for e in effects])
    out.volume = [term for e in effects for term in (e.volume or [])] or None
    return out
