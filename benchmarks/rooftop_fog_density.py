"""How dense the thesis' rooftop fog can have been for the physical atmosphere.

The rooftop fog's visual range was never measured: the physical runs' states (``config/rooftop_physical.yaml``,
fitted by ``benchmarks/fit_physical_rooftop.py``) hold ~2.8 km. Its near field (paper 2 Table 3, fog, 0-5 m) holds 313 +- 55 detections a frame without sun,
EPW 0.94 m, barely above the clear nights' 244, which the thesis puts on the cover (lines 329, 498, 1626).
This script runs ``lidar_weather_sim.experiments.reproduce.simulate`` with the physical atmosphere
(``atmosphere_model="physical"``, with the states' window ghosts) on the rooftop fog rows at each visual range of
``--ranges`` and prints the atmosphere region's n_total, n_peak, x_sigma and EPW and the street's n_e2 beside
the paper's, to show at which fog density the single-scattering volume return stops filling every beam.
The physical model takes a visual range of 10 km or more as clear air
(``regions.atmosphere.PHYSICAL_FOG_LIMIT_M``), so the ranges stay below it.

    python benchmarks/rooftop_fog_density.py [--ranges 500,1000,2000,5000,9000] [--frames 10] [--seed 0]
"""

from __future__ import annotations

import argparse

import numpy as np

from lidar_weather_sim.experiments.reproduce import load_tables, simulate
from lidar_weather_sim.experiments.rooftop_states import RooftopStates, load_states
from lidar_weather_sim.core.frame_parameters import summarize

ATMOSPHERE = ("n_total", "n_peak", "x_sigma", "epw_mean")
PAPER = {"n_total": "n_total", "n_peak": "n_peak", "x_sigma": "x_sigma_cm", "epw_mean": "epw_m"}


def row(cells: list[str]) -> str:
    return "| " + " | ".join(cells) + " |"


def states_at(visual_range_m: float) -> RooftopStates:
    """The shipped rooftop states with the fog class's visual range set to ``visual_range_m`` (m)."""
    data = load_states().model_dump()
    data["classes"]["fog"]["fog_visual_range_m"] = float(visual_range_m)
    return RooftopStates.model_validate(data)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--ranges", default="500,1000,2000,5000,9000", help="fog visual ranges (m)")
    parser.add_argument("--frames", type=int, default=10)
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()
    tables = load_tables()
    print(row(["V m", "sun", "n_total", "n_peak", "x_sigma cm", "EPW m", "street n_e2"]))
    print(row(["---:"] * 7))
    for sun in (False, True):
        key = "sun_true" if sun else "sun_false"
        paper = [tables["atmosphere_region"][PAPER[f]]["fog"][key] for f in ATMOSPHERE]
        paper.append(tables["street_region"]["n_e2"]["fog"][key])
        print(row(["paper", "w" if sun else "w/o", *(f"{m:g} +- {s:g}" for m, s in paper)]))
    for visual_range in (float(v) for v in args.ranges.split(",")):
        for sun in (False, True):
            c = simulate("fog", sun, args.frames, args.seed, atmosphere_model="physical", states=states_at(visual_range))
            near = summarize([f["atmosphere"] for f in c.frames])
            street = summarize([f["street"] for f in c.frames])
            cells = [near[f][0] * (100.0 if f == "x_sigma" else 1.0) for f in ATMOSPHERE] + [street["n_e2"][0]]
            print(row([f"{visual_range:g}", "w" if sun else "w/o",
                       *("n/a" if not np.isfinite(v) else f"{v:.3g}" for v in cells)]), flush=True)  # fmt: skip


if __name__ == "__main__":
    main()
