"""The seeded draw of cases over the fixed generators, written once to ``config/generator_draw.yaml``.

Every combination of profile (scala4, os1_128_1024), cover (none or dirty) and weather slot (fog_loss, fog_spread,
fog_shell with fog; precip_dsd with rain; precip_dsd with snow) appears :data:`REPLICAS` times: 40 cases on the
``highway_clear`` scenario. Main values are drawn uniformly in log space: fog visual range 40-400 m, rain
2-40 mm/h, snow 0.5-5 mm/h; a dirty cover's one-way transmission uniformly in 0.6-0.9; each case's measurement
seed in [0, 2^31). The draw uses ``numpy.random.default_rng(SEED)`` in the order of :func:`draw_cases` and depends
on nothing else. Each case's ``hide`` list is what ``make-measured --generator <generator> --hide`` takes.

Run ``python -m lidar_weather_sim.references.generators.draw OUT.yaml`` to write it (the committed file was written
so, before any gap search ran on the generators).
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import yaml

SEED = 520052
SCENARIO = "highway_clear"
PROFILES = ("scala4", "os1_128_1024")
SLOTS = (("fog_loss", "atmosphere.fog"), ("fog_spread", "atmosphere.fog"), ("fog_shell", "atmosphere.fog"),
         ("precip_dsd", "atmosphere.rain"), ("precip_dsd", "atmosphere.snow"))  # fmt: skip
RANGES = {"atmosphere.fog": ("visual_range", 40.0, 400.0), "atmosphere.rain": ("intensity", 2.0, 40.0),
          "atmosphere.snow": ("intensity", 0.5, 5.0)}  # fmt: skip
COVER_TRANSMISSION = (0.6, 0.9)
REPLICAS = 2


def draw_cases(seed: int = SEED) -> list[dict]:
    """The cases in order (module doc): index, generator, effect, value, cover (transmission or None), profile,
    scenario, seed, hide."""
    rng = np.random.default_rng(seed)
    cases = []
    for _ in range(REPLICAS):
        for profile in PROFILES:
            for dirty in (False, True):
                for generator, effect in SLOTS:
                    key, lo, hi = RANGES[effect]
                    value = float(f"{np.exp(rng.uniform(np.log(lo), np.log(hi))):.4g}")
                    cover = round(float(rng.uniform(*COVER_TRANSMISSION)), 3) if dirty else None
                    hide = [f"{effect}:{key}={value:g}"] + ([f"cover.dirt:transmission={cover:g}"] if dirty else [])
                    cases.append({"index": len(cases), "generator": generator, "effect": effect, "value": value,
                                  "cover": cover, "profile": profile, "scenario": SCENARIO,
                                  "seed": int(rng.integers(0, 2**31 - 1)), "hide": hide})  # fmt: skip
    return cases


def write(path: str | Path, seed: int = SEED) -> None:
    """Write the draw of ``seed`` to ``path`` (YAML, with its seed)."""
    text = yaml.safe_dump({"seed": seed, "cases": draw_cases(seed)}, sort_keys=False, width=120)
    header = ("# The seeded draw over the fixed generators (lidar_weather_sim.references.generators.draw), written\n"
              "# once with the generators, before any gap search ran on them. Change nothing here: a new draw is a\n"
              "# new file.\n")  # fmt: skip
    Path(path).write_text(header + text)


if __name__ == "__main__":
    write(sys.argv[1])
