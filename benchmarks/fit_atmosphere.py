#!/usr/bin/env python3
"""Fit the atmosphere region's physical parameters to paper 2 Tables 3 and 4 (rooftop experiment).

The only place that reads the table values for fitting. For each weather class (clear, rain,
fog, snow) ONE parameter set is fitted against the paper's means of BOTH sun conditions
(sunlight acts only through the sensor's noise model, at ``day_irradiance_w_m2`` for every
'with sun' row, because the paper only separates sun on/off: automatic gain control). The
simulation is the one of ``lidar-weather-sim reproduce rooftop`` (same scene, seed, code).

Stages per class, each a Nelder-Mead search on a fixed seed (common random numbers) with the
loss sum(max(0, |z| - 0.8)^2) + 0.01 sum z^2, z = (sim - paper) / paper_sigma:
1. near field (Table 3: n_total, n_peak, x_sigma, n_e1, EPW): rate_per_beam, cover_share,
   cover_scale_m, amplitude_median, amplitude_sigma_ln;
2. street (Table 4: n_e2, EPW, x_mean): path_rate_per_beam, path_amplitude_median, wetness
   (not for clear: dry by definition) and snow_depth_m (snow only).
The reference weather (rain 2 mm/h, snow 1 mm/h water equivalent, fog visual range 500 m)
is an assumption: the paper reports the classes, not the intensities (rain mostly below
5 mm/h, Fig. A2). Output: config/atmosphere_fit.yaml (with the fit's residuals).

Usage: python benchmarks/fit_atmosphere.py [--frames 6] [--iters 60] [--classes clear,rain]
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np
import yaml
from scipy.optimize import minimize

from lidar_weather_sim.regions_atmosphere import WEATHER_CLASSES
from lidar_weather_sim.reproduce import default_tables_path, paper_value, rows_of, simulate

ROOT = Path(__file__).resolve().parents[1]
OUT = ROOT / "config" / "atmosphere_fit.yaml"
NEAR = {"rate_per_beam": "log", "cover_share": "logit", "cover_scale_m": "log", "amplitude_median": "log",
        "amplitude_sigma_ln": "log"}
STREET = {"path_rate_per_beam": "log", "path_amplitude_median": "log", "wetness": "logit", "snow_depth_m": "log"}
TARGETS = {"near": ("atmosphere", ["n_total", "n_peak", "x_sigma", "n_e1", "epw_mean"]),
           "street": ("street", ["n_e2", "epw_mean", "x_mean"])}


def encode(value: float, kind: str) -> float:
    v = min(max(value, 1e-4), 1 - 1e-4) if kind == "logit" else max(value, 1e-6)
    return np.log(v / (1 - v)) if kind == "logit" else np.log(v)


def decode(x: float, kind: str) -> float:
    return float(1 / (1 + np.exp(-x))) if kind == "logit" else float(np.exp(x))


def residuals(params: dict, weather: str, stage: str, tables: dict, frames: int, fit_file: str) -> np.ndarray:
    region, features = TARGETS[stage]
    z = []
    for sun in (False, True):
        cond = simulate(weather, sun, frames, seed=12345, fit_file=fit_file, overrides=params)
        for row in rows_of(cond, tables):
            if row["region"] == region and row["parameter"] in features and row["paper_mean"] is not None:
                sim = row["sim_mean"] if row["sim_mean"] is not None else 0.0
                z.append((sim - row["paper_mean"]) / row["paper_std"])
    return np.array(z)


def loss(z: np.ndarray) -> float:
    return float(np.sum(np.maximum(np.abs(z) - 0.8, 0.0) ** 2) + 0.01 * np.sum(z**2))


def fit_stage(current: dict, names: dict, weather, stage, tables, frames, iters, fit_file) -> tuple[dict, np.ndarray]:
    keys = list(names)
    x0 = np.array([encode(current[k], names[k]) for k in keys])

    def unpack(x):
        return {**current, **{k: decode(v, names[k]) for k, v in zip(keys, x)}}

    f = lambda x: loss(residuals(unpack(x), weather, stage, tables, frames, fit_file))  # noqa: E731
    res = minimize(f, x0, method="Nelder-Mead", options={"maxfev": iters, "xatol": 1e-3, "fatol": 1e-3,
                                                          "initial_simplex": x0 + np.vstack([np.zeros(len(x0)), 0.5 * np.eye(len(x0))])})
    best = unpack(res.x)
    return best, residuals(best, weather, stage, tables, frames, fit_file)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--frames", type=int, default=6)
    parser.add_argument("--iters", type=int, default=60)
    parser.add_argument("--classes", default=",".join(WEATHER_CLASSES))
    parser.add_argument("--tables", default=str(default_tables_path()))
    parser.add_argument("--out", default=str(OUT))
    args = parser.parse_args()
    tables = yaml.safe_load(Path(args.tables).read_text())
    data = yaml.safe_load(Path(args.out).read_text())
    for weather in args.classes.split(","):
        start = time.perf_counter()
        c = dict(data["classes"][weather])
        c, z_near = fit_stage(c, NEAR, weather, "near", tables, args.frames, args.iters, args.out)
        street = {k: v for k, v in STREET.items()
                  if not (k == "wetness" and weather in ("clear", "snow")) and not (k == "snow_depth_m" and weather != "snow")}
        c, z_street = fit_stage(c, street, weather, "street", tables, args.frames, args.iters, args.out)
        data["classes"][weather] = {k: round(float(v), 6) for k, v in c.items()}
        data.setdefault("fit_report", {})[weather] = {"z_atmosphere": [round(float(v), 2) for v in z_near],
                                                      "z_street": [round(float(v), 2) for v in z_street]}
        data["source"] = ("fitted by benchmarks/fit_atmosphere.py to paper 2 Tables 3 and 4 (thesis_tables.yaml "
                          "atmosphere_region, street_region); one set per weather class for both sun conditions")
        Path(args.out).write_text("# Written by benchmarks/fit_atmosphere.py; do not edit by hand.\n"
                                  + yaml.safe_dump(data, sort_keys=False))
        print(f"{weather}: {data['classes'][weather]}\n  z atmosphere {z_near.round(2)}  z street {z_street.round(2)}"
              f"  ({time.perf_counter() - start:.0f} s)", flush=True)


if __name__ == "__main__":
    main()
