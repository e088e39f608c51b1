"""SWEEP.yaml: what a sweep runs, and its expansion into runs.

Keys (unknown keys are errors)::

    scenario: highway_spray            # name or YAML path
    frames: 5                          # frames per run
    profile: scala4                    # optional: overrides the scenario's sensor profile
    return_mode: null                  # optional: strongest | last | dual | first | all
    seeds: [1, 2]                      # every point of the grid (or draw) runs once per seed
    grid:                              # dotted scenario keys -> values (the runs are the product)
      weather.fog.visual_range_m: [60, 200]
    random:                            # or: `count` draws of the keys (seeded by `seed`)
      count: 10
      seed: 7
      keys:
        weather.fog.visual_range_m: {low: 30, high: 500, log: true}
        weather.precipitation.intensity_mm_h: [1, 50]        # uniform
        actors.0.lead_gap_m: {low: 10, high: 30, integer: true}
        weather.precipitation.type: {choices: [rain, snow]}
    compute: [stats, eval, {compare: measured_bag}, "my_package.metrics:function"]

A dotted key names a field of the scenario (``weather.fog.visual_range_m``,
``actors.0.speed_m_s``, ``region_params.spray.film_cv``); every run's scenario is validated
before anything runs, so a key the scenario does not have, or a value it refuses, is an
error naming the key. Neither ``grid`` nor ``random``: one run per seed.
"""

from __future__ import annotations

import copy
import itertools
import math
from pathlib import Path
from typing import Any

import numpy as np
import pydantic
from pydantic import Field

from lidar_weather_sim.core.config import ConfigError, ConfigModel, format_validation_error, load_yaml
from lidar_weather_sim.scenario.schema import Scenario, load_scenario
from lidar_weather_sim.sensor.profile import ReturnMode
from lidar_weather_sim.sweep.run_spec import RunSpec

BUILTIN_COMPUTE = ("stats", "eval")
#: Weather blocks that act only through region plugins (the sun acts in the simulator itself): sweeping one in a
#: scenario without any of its regions would change nothing.
WEATHER_READERS = {"weather.fog": ("atmosphere",), "weather.precipitation": ("atmosphere", "spray"),
                   "weather.road": ("atmosphere", "spray"), "weather.wind": ("spray",)}  # fmt: skip


class RandomRange(ConfigModel):
    low: float | None = None
    high: float | None = None
    log: bool = Field(False, description="draw log-uniformly (low > 0)")
    integer: bool = Field(False, description="draw integers from low to high, both included")
    choices: list[Any] | None = None

    @pydantic.model_validator(mode="after")
    def _one_kind(self) -> "RandomRange":
        if self.choices is not None:
            if self.low is not None or self.high is not None or not self.choices:
                raise ValueError("give either non-empty 'choices' or 'low' and 'high'")
        elif self.low is None or self.high is None or not self.low <= self.high:
            raise ValueError(f"needs low <= high, got low={self.low}, high={self.high}")
        elif self.log and self.low <= 0:
            raise ValueError(f"log draws need low > 0, got {self.low}")
        return self


class RandomDraws(ConfigModel):
    count: int = Field(ge=1, le=1_000_000, description="number of draws")
    seed: int = Field(0, ge=0, le=2**32 - 1, description="seed of the draws (not of the simulations)")
    keys: dict[str, RandomRange] = Field(min_length=1)

    @pydantic.field_validator("keys", mode="before")
    @classmethod
    def _pairs(cls, value: Any) -> Any:
        if isinstance(value, dict):
            return {k: ({"low": v[0], "high": v[1]} if isinstance(v, (list, tuple)) and len(v) == 2 else v)
                    for k, v in value.items()}  # fmt: skip
        return value


class SweepSpec(ConfigModel):
    scenario: str = Field(description="scenario name or YAML path")
    frames: int = Field(ge=1, le=100_000, description="frames per run")
    profile: str | None = Field(None, description="sensor profile overriding the scenario's")
    return_mode: ReturnMode | None = Field(None, description="return mode overriding the scenario's and profile's")
    seeds: list[int] = Field(default_factory=lambda: [0], min_length=1)
    grid: dict[str, list[Any]] | None = None
    random: RandomDraws | None = None
    compute: list[str | dict[str, str]] = Field(default_factory=lambda: ["stats"], min_length=1)

    @pydantic.model_validator(mode="after")
    def _checks(self) -> "SweepSpec":
        if self.grid is not None and self.random is not None:
            raise ValueError("give 'grid' or 'random', not both")
        if self.grid is not None:
            if not self.grid:
                raise ValueError("'grid' is empty: give at least one key with values, or leave 'grid' out")
            empty = [k for k, v in self.grid.items() if not v]
            if empty:
                raise ValueError(f"'grid' key {empty[0]!r} has no values")
        for key, name in (("sensor.profile", "profile"), ("sensor.return_mode", "return_mode"), ("seed", "seeds")):
            if key in self.swept_keys and (getattr(self, name) is not None or name == "seeds"):
                raise ValueError(f"'{key}' is swept but '{name}' overrides it in every run: sweep one of them")
        if len(set(self.seeds)) != len(self.seeds) or min(self.seeds) < 0:
            raise ValueError(f"'seeds' must be distinct non-negative integers, got {self.seeds}")
        for item in self.compute:
            compute_kind(item)
        return self

    @property
    def swept_keys(self) -> list[str]:
        return list(self.grid or (self.random.keys if self.random else {}))


def compute_kind(item: str | dict[str, str]) -> str:
    """``stats``, ``eval``, ``compare`` or ``function``; ValueError for anything else."""
    if isinstance(item, dict):
        if list(item) != ["compare"]:
            raise ValueError(f"compute entry {item}: the only mapping is {{compare: REFERENCE_BAG}}")
        return "compare"
    if item in BUILTIN_COMPUTE:
        return item
    module, _, function = item.partition(":")
    if not module or not function.isidentifier():
        raise ValueError(f"compute entry {item!r}: expected stats, eval, {{compare: BAG}} or 'module:function'")
    return "function"


def load_sweep(path: str | Path) -> SweepSpec:
    return load_yaml(Path(path), SweepSpec)


def points(spec: SweepSpec) -> list[dict[str, Any]]:
    """The swept values of each run (before seeds): the grid's product, the random draws, or one empty point."""
    if spec.grid:
        keys = list(spec.grid)
        return [dict(zip(keys, values)) for values in itertools.product(*spec.grid.values())]
    if spec.random:
        rng = np.random.default_rng(spec.random.seed)
        columns = {key: _draw(rng, r, spec.random.count) for key, r in spec.random.keys.items()}
        return [{k: v[i] for k, v in columns.items()} for i in range(spec.random.count)]
    return [{}]


def _draw(rng: np.random.Generator, r: RandomRange, n: int) -> list[Any]:
    if r.choices is not None:
        return [r.choices[int(i)] for i in rng.integers(0, len(r.choices), n)]
    if r.log:
        return [float(v) for v in np.exp(rng.uniform(math.log(r.low), math.log(r.high), n))]
    if r.integer:
        return [int(v) for v in rng.integers(math.ceil(r.low), math.floor(r.high) + 1, n)]
    return [float(v) for v in rng.uniform(r.low, r.high, n)]


def set_dotted(data: dict, key: str, value: Any) -> None:
    """``data`` with ``key`` (a.b.0.c) set to ``value``; KeyError naming the first missing part. A new key is
    allowed only in a ``region_params`` entry (a region's parameters default when absent)."""
    parts = key.split(".")
    node: Any = data
    for depth, part in enumerate(parts):
        last = depth == len(parts) - 1
        if isinstance(node, list):
            if not part.isdigit() or int(part) >= len(node):
                raise KeyError(f"'{'.'.join(parts[:depth + 1])}': index out of range (the list has {len(node)} items)")
            index: Any = int(part)
        elif isinstance(node, dict):
            creatable = parts[0] == "region_params" and depth >= 1
            if part not in node and not creatable:
                raise KeyError(f"'{'.'.join(parts[:depth + 1])}': the scenario has no such key")
            if part not in node:
                node[part] = {}
            index = part
        else:
            raise KeyError(f"'{'.'.join(parts[:depth + 1])}': '{'.'.join(parts[:depth])}' is a value, not a block")
        if last:
            node[index] = value
        else:
            node = node[index]


def expand(spec: SweepSpec, source: str = "SWEEP") -> list[RunSpec]:
    """Every run of the sweep (points x seeds), each with its validated scenario; ConfigError naming the
    sweep file, the key and the value when a run's scenario is invalid."""
    base = load_scenario(spec.scenario)
    if base.ego is None:
        raise ConfigError(f"{source}: scenario '{base.name}' has no ego (mesh-only): a sweep runs scenarios")
    for key in spec.swept_keys:
        readers = next((r for block, r in WEATHER_READERS.items() if key.startswith(block + ".")), None)
        if readers and not set(readers) & set(base.regions):
            raise ConfigError(f"{source}: key '{key}' acts only through the region(s) {', '.join(readers)}, which "
                              f"scenario '{base.name}' does not list in 'regions': sweeping it would change nothing")
    base_data = base.model_dump(mode="json")
    # reference bags as absolute paths: a worker may run in another directory
    compute = [{"compare": str(Path(i["compare"]).resolve())} if isinstance(i, dict) else i for i in spec.compute]
    runs = []
    for point in points(spec):
        data = copy.deepcopy(base_data)
        for key, value in point.items():
            try:
                set_dotted(data, key, value)
            except KeyError as exc:
                raise ConfigError(f"{source}: key {exc.args[0]}") from None
        try:
            scenario = Scenario.model_validate(data)
        except pydantic.ValidationError as exc:
            where = ", ".join(f"{k}={v!r}" for k, v in point.items())
            raise ConfigError(f"{source} ({where}): {format_validation_error('scenario', exc, data)}") from None
        for seed in spec.seeds:
            runs.append(RunSpec(scenario=scenario.model_dump(mode="json"), point=point, seed=seed, frames=spec.frames,
                                profile=spec.profile, return_mode=spec.return_mode, compute=compute))  # fmt: skip
    return runs

