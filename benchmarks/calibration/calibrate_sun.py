#!/usr/bin/env python3
"""Calibrate the background-light noise model on the thesis' rooftop scene (paper 2, Table 2).

The thesis could only separate sun on/off (the sensor's automatic gain control); Table 2 gives
per-frame first/second echoes and mean EPW at night and by day in clear weather. We put the
mean irradiance of clear days (Fig. A3, 343 W/m^2) on the scene and fit the rise of the noise
mean per W/m^2 so that the first-echo ratio day/night matches the thesis; the second-echo and
EPW ratios are then predictions, printed next to the thesis' values.

Checked against Tables 3-4 (2026-11-23, with the fitted atmosphere model since removed): with the profile's
sun_noise_per_w_m2 set to 0.015 / 0.021 / 0.025 / 0.029 / 0.032 and the atmosphere refitted for each
(``git show 2d63ebe:benchmarks/calibration/fit_atmosphere.py``),
59 / 60 / 63 / 64 / 61 of their 80 means fall within +-1 sigma, against 62 for the shipped 0.0186
and its fit: within the +-2 by which refits from different starts differ, with the same misses
(street n_e2 at night, the street EPW under sun). So this Table 2 calibration stays.

Usage: python benchmarks/calibration/calibrate_sun.py [--profile scala4] [--frames 8]
"""

from __future__ import annotations

import argparse

import numpy as np
import yaml

from lidar_weather_sim.core.paths import config_dir
from lidar_weather_sim.experiments.rooftop import RooftopPose, rooftop_scene
from lidar_weather_sim.sensor.profile import load_profile
from lidar_weather_sim.sim.simulator import LidarSimulator


def frame_stats(profile, sun_w_m2: float, frames: int) -> dict[str, float]:
    sim = LidarSimulator(profile, rooftop_scene(), sun_irradiance_w_m2=sun_w_m2, seed=1)
    pose = RooftopPose.for_profile(profile)
    out = []
    t = 0.0
    while len(out) < frames:
        out += sim.advance(t, pose)
        t += 0.01
    e1 = [np.sum(f.points["echo"] == 1) for f in out]
    e2 = [np.sum(f.points["echo"] == 2) for f in out]
    epw = np.concatenate([f.points["epw"] for f in out])
    return {"n_e1": float(np.mean(e1)), "n_e2": float(np.mean(e2)), "epw_m": float(epw.mean()) if len(epw) else 0.0}


def fit(profile, irradiance: float, target_ratio: float, frames: int) -> tuple[float, dict, dict]:
    night = frame_stats(profile, 0.0, frames)
    lo, hi = 0.0, 1.0
    for _ in range(30):
        k = 0.5 * (lo + hi)
        trial = profile.model_copy(update={"detection": profile.detection.model_copy(update={"sun_noise_per_w_m2": k})})
        day = frame_stats(trial, irradiance, frames)
        if day["n_e1"] / night["n_e1"] > target_ratio:
            lo = k
        else:
            hi = k
    return k, night, day


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--profile", default="scala4")
    parser.add_argument("--frames", type=int, default=8)
    parser.add_argument("--tables", default=None, help="thesis_tables.yaml (default ../shared/data beside the workspace)")
    args = parser.parse_args()
    tables_path = args.tables or config_dir().parent.parent / "shared" / "data" / "thesis_tables.yaml"
    tables = yaml.safe_load(open(tables_path))["background_radiation_clear"]
    irradiance = tables["mean_irradiance_w_m2"]["clear"]
    thesis_night, thesis_day = tables["night"], tables["day"]
    target = thesis_day["n_e1"][0] / thesis_night["n_e1"][0]
    k, night, day = fit(load_profile(args.profile), irradiance, target, args.frames)
    print(f"profile {args.profile}, rooftop scene, clear, sun {irradiance} W/m^2 (thesis clear-day mean)")
    print(f"fitted detection.sun_noise_per_w_m2 = {k:.6g}")
    print(f"{'metric':8} {'thesis night':>13} {'thesis day':>11} {'ratio':>6} | {'sim night':>9} {'sim day':>8} {'ratio':>6}")
    for key in ("n_e1", "n_e2", "epw_m"):
        tn, td = thesis_night[key][0], thesis_day[key][0]
        sn, sd = night[key], day[key]
        ratio = f"{sd / sn:6.2f}" if sn else "   n/a"
        print(f"{key:8} {tn:13.2f} {td:11.2f} {td / tn:6.2f} | {sn:9.2f} {sd:8.2f} {ratio}")


if __name__ == "__main__":
    main()
