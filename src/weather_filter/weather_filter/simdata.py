"""Labelled simulation runs for training and evaluating the weather filters.

A run is named by a spec ``SCENARIO:SEED:FRAMES[:PROFILE[:WEATHER]]`` (scenario
name - in config/scenarios or this package's ``scenarios/``, the filter's own ``wf_*`` runs - or a YAML path, simulation seed, frame count, optional
sensor profile overriding the scenario's (empty: the scenario's), optional
weather replacing the scenario's precipitation and fog: ``clear``, ``rainR``,
``snowR`` (R mm/h), ``fogV`` (V m visual range) or two joined by ``+``, e.g.
``rain2+fog400``; it acts only through the scenario's ``atmosphere`` region). :func:`simulate` writes it with
``lidar_weather_sim.sim.offline.run_scenario`` into a cache directory, one bag per
spec, and reuses the bag when it is already there (the simulator is
deterministic given the seed). The frames of a run are one sequence: the
learned filter's frame-difference feature resets between runs, never within.
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from functools import partial
from pathlib import Path
from typing import Iterator

import numpy as np

from lidar_weather_sim.core.names import TOPIC_POINTS


def scenario_directory() -> Path:
    """The filter's own scenarios (``wf_*.yaml``), registered under ``lidar_weather_sim.scenario_dirs``."""
    return Path(__file__).resolve().parent / "scenarios"


@dataclass(frozen=True)
class SimSpec:
    scenario: str
    seed: int
    frames: int
    profile: str | None = None
    weather: str | None = None

    @classmethod
    def parse(cls, text: str) -> "SimSpec":
        parts = text.split(":")
        if len(parts) not in (3, 4, 5) or not parts[0]:
            raise ValueError(f"simulation spec {text!r}: expected SCENARIO:SEED:FRAMES[:PROFILE[:WEATHER]]")
        try:
            seed, frames = int(parts[1]), int(parts[2])
        except ValueError:
            raise ValueError(f"simulation spec {text!r}: SEED and FRAMES must be integers") from None
        if frames < 1:
            raise ValueError(f"simulation spec {text!r}: FRAMES must be >= 1")
        profile = parts[3] if len(parts) >= 4 and parts[3] else None
        weather = parts[4] if len(parts) == 5 and parts[4] else None
        if weather:
            weather_update(weather)  # validates
        return cls(parts[0], seed, frames, profile, weather)

    def __str__(self) -> str:
        text = f"{self.scenario}:{self.seed}:{self.frames}"
        if self.profile or self.weather:
            text += f":{self.profile or ''}"
        return text + (f":{self.weather}" if self.weather else "")

    def load_scenario(self):
        from lidar_weather_sim.scenario.schema import load_scenario

        scenario = load_scenario(self.scenario)
        if self.weather:
            scenario = scenario.model_copy(update={"weather": scenario.weather.model_copy(update=weather_update(self.weather))})
        return scenario

    @property
    def bag_name(self) -> str:
        stem = re.sub(r"[^A-Za-z0-9_.-]", "_", Path(self.scenario).stem)
        return (f"{stem}_s{self.seed}_n{self.frames}" + (f"_{self.profile}" if self.profile else "")
                + (f"_w{re.sub(r'[^A-Za-z0-9.]', '_', self.weather)}" if self.weather else ""))  # fmt: skip


def weather_update(text: str) -> dict:
    """``clear`` / ``rainR`` / ``snowR`` / ``fogV``, joined by ``+``: fields of a Weather block."""
    from lidar_weather_sim.regions.weather import Fog, Precipitation

    update = {"fog": Fog(), "precipitation": Precipitation()}
    for part in text.split("+"):
        match = re.fullmatch(r"(clear|rain|snow|fog)([0-9.]*)", part)
        if not match or (match.group(1) != "clear") != bool(match.group(2)):
            raise ValueError(f"weather {text!r}: expected clear, rainR, snowR or fogV joined by '+'")
        kind, value = match.group(1), float(match.group(2) or 0)
        if kind in ("rain", "snow"):
            update["precipitation"] = Precipitation(type=kind, intensity_mm_h=value)
        elif kind == "fog":
            update["fog"] = Fog(visual_range_m=value)
    return update


def default_cache_dir() -> Path:
    """``.venv/cache/weather_filter`` of the workspace when it exists, else ``~/.cache/weather_filter``."""
    from lidar_weather_sim.core.paths import config_dir

    venv = config_dir().parent / ".venv"
    return (venv / "cache" / "weather_filter") if venv.is_dir() else Path.home() / ".cache" / "weather_filter"


def simulate(spec: SimSpec | str, cache_dir: str | Path | None = None) -> Path:
    """The bag of ``spec`` in ``cache_dir`` (simulated now unless already there)."""
    from lidar_weather_sim.sim.offline import run_scenario

    spec = SimSpec.parse(spec) if isinstance(spec, str) else spec
    cache = Path(cache_dir) if cache_dir else default_cache_dir()
    bag = cache / spec.bag_name
    if (bag / "metadata.yaml").exists():
        return bag
    cache.mkdir(parents=True, exist_ok=True)
    run_scenario(spec.load_scenario(), bag, frames=spec.frames, seed=spec.seed, profile=spec.profile, overwrite=True)
    return bag


def simulate_all(specs: list[SimSpec | str], cache_dir: str | Path | None = None, *, scheduler: str | None = None,
                 workers: int | None = 0, progress=None) -> list[Path]:  # fmt: skip
    """The bags of ``specs`` (in order), those not cached yet simulated on the Dask engine
    (:class:`lidar_weather_sim.core.engine.Engine`: ``workers=0`` in this process, ``N`` local worker
    processes, or a cluster at ``scheduler`` whose workers see ``cache_dir``). ``progress(spec, bag)``
    as each finishes. A run that fails raises after the others have finished (their bags are kept)."""
    from lidar_weather_sim.core.engine import Engine

    specs = [SimSpec.parse(s) if isinstance(s, str) else s for s in specs]
    cache = Path(cache_dir).resolve() if cache_dir else default_cache_dir()
    bags = [cache / spec.bag_name for spec in specs]
    todo = list(dict.fromkeys(spec for spec, bag in zip(specs, bags) if not (bag / "metadata.yaml").exists()))
    errors = []
    with Engine(scheduler, workers) if todo else Engine() as engine:
        if todo:
            engine.warm(_warm_up, todo[0])
        for outcome in engine.map(partial(simulate, cache_dir=str(cache)), todo):
            if outcome.error:
                errors.append(f"simulation {todo[outcome.index]}: {outcome.error}")
            elif progress:
                progress(todo[outcome.index], outcome.result)
    if errors:
        raise RuntimeError("; ".join(errors))
    return bags


def _warm_up(spec: SimSpec) -> None:
    """One frame of ``spec`` into a temporary directory (numba's kernels compiled once per machine)."""
    import tempfile

    with tempfile.TemporaryDirectory(prefix="wf-warm-") as tmp:
        simulate(SimSpec(spec.scenario, spec.seed, 1, spec.profile, spec.weather), tmp)


def frames_of(bag: str | Path, topic: str = TOPIC_POINTS) -> Iterator[np.ndarray]:
    from lidar_weather_sim.io.bags import read_clouds

    return (frame.points for frame in read_clouds(bag, topic))


_TRAIN_SCENARIOS = ("wf_train_rain_spray", "wf_train_fog", "wf_train_snow", "wf_train_clear_spray", "wf_train_fog_rain",
                    "wf_train_crosswind_spray")
#: Runs the shipped learned filter is trained on (``weather-filter train --sim ...``, see the model's
#: ``command``): rain + spray + dirt at 100 km/h, fog at 60 km/h, snow at 40 km/h on the curved road, spray in
#: dry air at 70 km/h, rain in fog at 80 km/h, spray blown over the ego's lane by a crosswind at 80 km/h
#: (weather_filter/scenarios/wf_train_*.yaml) and the proving ground's spray at 39 and 48 km/h;
#: scala4, a 128-channel profile at 1024 and 2048 columns, VLP-16 and HDL-64E (the histogram counts scale with
#: the scan's resolution: trained without VLP-16 and HDL-64E, the model kept 99.50 % / 98.80 % of the VLP-16 /
#: VLP-32C held-out solid points).
TRAIN_SPECS = (
    *(f"{s}:{seed}:40" for s in _TRAIN_SCENARIOS for seed in (1, 2)),
    "proving_ground_39:1:40", "proving_ground_48:1:40",
    *(f"{s}:3:6:os1_128_1024" for s in _TRAIN_SCENARIOS),
    *(f"{s}:4:3:os1_128_2048" for s in _TRAIN_SCENARIOS),
    *(f"{s}:5:10:vlp16" for s in _TRAIN_SCENARIOS),
    *(f"{s}:6:3:hdl64e" for s in _TRAIN_SCENARIOS),
)  # fmt: skip
#: Held-out runs: scenarios and seeds never used in training (highway_spray: rain + spray at 89 km/h;
#: proving_ground_55/60: spray at 55/60 km/h; wf_heldout_mixed: snow + fog + dirt + spray, curved road, 90 km/h),
#: on every shipped profile; vlp32c's scan pattern is in no training run.
HELDOUT_SPECS = (
    "highway_spray:100:40", "proving_ground_55:100:40", "proving_ground_60:100:40", "wf_heldout_mixed:100:40",
    "wf_heldout_mixed:101:6:os1_128_1024", "highway_spray:101:6:os1_128_1024",
    "wf_heldout_mixed:102:6:os1_128_2048", "highway_spray:102:4:os1_128_2048",
    "highway_spray:101:10:vlp16", "wf_heldout_mixed:101:10:vlp16",
    "highway_spray:101:8:vlp32c", "wf_heldout_mixed:101:8:vlp32c",
    "highway_spray:101:6:hdl64e", "wf_heldout_mixed:101:6:hdl64e",
)  # fmt: skip
