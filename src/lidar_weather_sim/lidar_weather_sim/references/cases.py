"""The seeded case draw of the gap-generalisation benchmark from ``config/gap_cases.yaml``.

Each case is a generator (``fast``: the project's effects put on a clear base recording by
``make-measured --on``; ``reference``: ``make-measured --reference``; ``hahner``: ``make-measured --generator
hahner``), one effect or a pair with its main parameter drawn in the file's ranges (uniformly, or uniformly
in log space), and a seed for the measurement. The draw depends only on the file: the same file gives the
same cases, in order. Drawn cases alternate between the file's ``generators``; ``extra`` cases follow.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
import yaml

from lidar_weather_sim.scenario.effects import EFFECTS, Effect, conflicts, parse_effect


@dataclass(frozen=True)
class Case:
    index: int
    generator: str
    effects: tuple[str, ...]  # NAME:main=value, as make-measured --hide takes them
    seed: int

    def parsed(self) -> list[Effect]:
        return [parse_effect(text) for text in self.effects]


def default_cases_file() -> Path:
    from lidar_weather_sim.core.paths import config_dir

    return config_dir() / "gap_cases.yaml"


def _value(rng: np.random.Generator, spec: dict, main: str) -> float:
    lo, hi = spec[main]
    if spec.get("scale", "linear") == "log":
        return float(np.exp(rng.uniform(np.log(lo), np.log(hi))))
    return float(rng.uniform(lo, hi))


def _draw(rng: np.random.Generator, config: dict, index: int, generator: str) -> Case:
    pairs = config["pairs"].get(generator) or []
    if pairs and rng.random() < config["pair_fraction"]:
        names = pairs[int(rng.integers(len(pairs)))]
    else:
        singles = config["single"][generator]
        names = [singles[int(rng.integers(len(singles)))]]
    texts = []
    for name in names:
        main = EFFECTS[name].main
        texts.append(f"{name}:{main}={_value(rng, config['ranges'][name], main):.4g}")
    case = Case(index, generator, tuple(texts), int(rng.integers(0, 2**31 - 1)))
    problem = conflicts(case.parsed())
    if problem:
        raise ValueError(f"case {index}: {', '.join(texts)}: {problem}")
    return case


def draw_cases(path: str | Path | None = None) -> tuple[dict, list[Case]]:
    """(the file's settings, its cases in order) of ``path`` (default config/gap_cases.yaml)."""
    config = yaml.safe_load(Path(path or default_cases_file()).read_text())
    rng = np.random.default_rng(int(config["seed"]))
    generators = config["generators"]
    cases = [_draw(rng, config, i, generators[i % len(generators)]) for i in range(int(config["cases"]))]
    for generator, count in (config.get("extra") or {}).items():
        for _ in range(int(count)):
            cases.append(_draw(rng, config, len(cases), generator))
    return config, cases
