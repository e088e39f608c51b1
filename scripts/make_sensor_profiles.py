#!/usr/bin/env python3
"""Generate the Velodyne and Ouster sensor profiles from measured beam calibrations.

Beam angles are read, never retyped:
- Velodyne VLP-16, VLP-32C, HDL-64E: the calibration files shipped in the PyPI
  wheel ``velodyne-decoder`` (``velodyne_decoder/calibrations/*.yml``);
  ``vert_correction`` -> elevation, ``rot_correction`` -> azimuth offset.
- Ouster OS1-128: ``beam_altitude_angles`` / ``beam_azimuth_angles`` of the real
  recording ``sdk/tests/pcaps/OS-1-128_v2.3.0_1024x10.json`` in the ouster-sdk
  1.0.1 sdist (downloaded by scripts/setup.sh). Ouster's azimuth offsets are
  clockwise, so the REP-103 offset is their negative.

Timing, range, optics and pulse values come from the public data sheets (table
below). ``power_constant`` puts a 10 % Lambertian target at the rated range
exactly at the dark threshold.

Return mode: every profile reports ``all`` its echoes (the multi-echo clouds the shipped learned
weather filter was trained on). The real drivers default to a single return (``DRIVER_RETURN_MODE``,
written into each profile's header): Velodyne's factory setting is Strongest (VLP-16 / VLP-32C /
HDL-64E S3 manuals: Strongest, Last or Dual), Ouster's default single-return lidar profile
(LEGACY, RNG19_RFL8_SIG16_NIR16) reports the strongest return (return_order STRONGEST_TO_WEAKEST),
dual return (RNG19_RFL8_SIG16_NIR16_DUAL, newer firmware) the two strongest. Switching the defaults
waits for a retrain of the learned filter on single-return clouds.

Usage: make_sensor_profiles.py OUSTER_SDIST.tar.gz OUT_DIR
"""

from __future__ import annotations

import json
import math
import sys
import tarfile
from importlib import resources
from pathlib import Path

import yaml

OUSTER_METADATA = "sdk/tests/pcaps/OS-1-128_v2.3.0_1024x10.json"

# name: (source, calibration, frame rate Hz, columns, range m (10 % target), resolution m, noise m,
#        divergence h/v mrad, sub-rays h x v, echoes, pulse FWHM m)
DATASHEET = {
    "vlp16": ("VLP-16 data sheet (Velodyne 63-9229 Rev-H)", "VLP-16.yml", 10.0, 1800, 100.0, 0.03, 0.015,
              (3.0, 1.5), (3, 1), 2, 0.9),
    "vlp32c": ("VLP-32C data sheet (Velodyne 63-9378 Rev-E)", "VLP-32C.yml", 10.0, 1800, 200.0, 0.03, 0.015,
               (3.0, 1.5), (3, 1), 2, 0.9),
    "hdl64e": ("HDL-64E S3 data sheet; VeloView calibration", "HDL-64E_S3-VeloView.yml", 10.0, 2083, 120.0, 0.02,
               0.01, (2.0, 2.0), (3, 1), 2, 0.75),
    "os1_128_1024": ("Ouster OS1 rev6 data sheet; beam angles of a real OS1-128 recording", None, 10.0, 1024, 120.0,
                     0.03, 0.01, (3.1, 3.1), (3, 1), 2, 0.75),
    "os1_128_2048": ("Ouster OS1 rev6 data sheet; beam angles of a real OS1-128 recording", None, 10.0, 2048, 120.0,
                     0.03, 0.01, (3.1, 3.1), (3, 1), 2, 0.75),
}  # fmt: skip

# Physical optics (lidar_weather_sim.physics, the atmosphere reference): wavelength (nm) from the data
# sheets; lens separation (m), receiver FOV (mrad) and aperture radii (m) are ASSUMED (no data sheet gives
# them), chosen so that the geometric overlap starts near the rated minimum range and is full within a few m.
# name: (wavelength nm and its source, lens separation m, receiver FOV mrad, tx / rx aperture radius m)
OPTICS = {
    "vlp16": (903.0, "VLP-16 data sheet 63-9229 Rev-H: 903 nm", 0.03, 8.0, 0.005, 0.02),
    "vlp32c": (903.0, "VLP-32C data sheet 63-9378 Rev-E: 903 nm", 0.03, 8.0, 0.005, 0.02),
    "hdl64e": (905.0, "HDL-64E S3 data sheet: 905 nm", 0.03, 6.0, 0.005, 0.02),
    "os1_128_1024": (865.0, "Ouster OS1 rev6 data sheet: 865 nm", 0.02, 8.0, 0.004, 0.012),
    "os1_128_2048": (865.0, "Ouster OS1 rev6 data sheet: 865 nm", 0.02, 8.0, 0.004, 0.012),
}

NOISE_MEAN, NOISE_SIGMA, THRESHOLD_SIGMA = 1.0, 1.0, 3.0
RETURN_MODE = "all"
DRIVER_RETURN_MODE = {
    "vlp16": "strongest (Velodyne factory setting; last and dual available)",
    "vlp32c": "strongest (Velodyne factory setting; last and dual available)",
    "hdl64e": "strongest (Velodyne factory setting; last and dual available)",
    "os1_128_1024": "strongest (Ouster single-return profile, return_order STRONGEST_TO_WEAKEST; dual = two strongest)",
    "os1_128_2048": "strongest (Ouster single-return profile, return_order STRONGEST_TO_WEAKEST; dual = two strongest)",
}


def velodyne_beams(calibration: str) -> list[dict]:
    text = resources.files("velodyne_decoder").joinpath("calibrations", calibration).read_text()
    lasers = yaml.safe_load(text)["lasers"]
    return [
        {
            "elevation_deg": round(math.degrees(laser["vert_correction"]), 6),
            "azimuth_offset_deg": round(math.degrees(laser.get("rot_correction", 0.0)), 6),
        }
        for laser in sorted(lasers, key=lambda laser: laser["laser_id"])
    ]


def ouster_beams(sdist: Path) -> list[dict]:
    with tarfile.open(sdist) as tar:
        member = next(m for m in tar.getmembers() if m.name.endswith(OUSTER_METADATA))
        meta = json.load(tar.extractfile(member))
    intrinsics = meta.get("beam_intrinsics", meta)
    return [
        {"elevation_deg": float(alt), "azimuth_offset_deg": -float(az)}
        for alt, az in zip(intrinsics["beam_altitude_angles"], intrinsics["beam_azimuth_angles"])
    ]


def profile(name: str, beams: list[dict]) -> dict:
    source, _, rate, columns, range_m, resolution, noise, (div_h, div_v), (sub_h, sub_v), echoes, fwhm = DATASHEET[name]
    threshold = NOISE_MEAN + THRESHOLD_SIGMA * NOISE_SIGMA
    return {
        "name": name,
        "description": f"{name}: {len(beams)} beams, {columns} columns at {rate:g} Hz, generated from calibration data",
        "source": source,
        "beams": beams,
        "scan": {"frame_rate_hz": rate, "azimuth_min_deg": -180.0, "azimuth_max_deg": 180.0, "columns": columns,
                 "direction": "cw", "sweep_fraction": 1.0},
        "range": {"min_m": 0.3, "max_m": 1.5 * range_m, "resolution_m": resolution, "noise_sigma_m": noise},
        "optics": {"divergence_h_mrad": div_h, "divergence_v_mrad": div_v, "subrays_h": sub_h, "subrays_v": sub_v,
                   "overlap_start_m": 0.0, "overlap_full_m": 0.0, "wavelength_nm": OPTICS[name][0],
                   "lens_separation_m": OPTICS[name][2], "receiver_fov_mrad": OPTICS[name][3],
                   "tx_aperture_radius_m": OPTICS[name][4], "rx_aperture_radius_m": OPTICS[name][5]},
        "pulse": {"fwhm_m": fwhm},
        "detection": {"max_echoes": echoes, "return_mode": RETURN_MODE, "power_constant": threshold * range_m**2 / 0.1, "noise_mean": NOISE_MEAN,
                      "noise_sigma": NOISE_SIGMA, "threshold_sigma": THRESHOLD_SIGMA, "sun_noise_per_w_m2": 0.0,
                      "sun_sigma_per_w_m2": 0.0, "false_alarms_per_beam": 0.0, "intensity_dynamic_range": 1.0e4},
    }  # fmt: skip


def main(argv: list[str]) -> int:
    if len(argv) != 2:
        print(__doc__.strip().splitlines()[-1], file=sys.stderr)
        return 2
    sdist, out = Path(argv[0]), Path(argv[1])
    out.mkdir(parents=True, exist_ok=True)
    ouster = ouster_beams(sdist)
    for name, row in DATASHEET.items():
        beams = velodyne_beams(row[1]) if row[1] else ouster
        header = ("# Generated by scripts/make_sensor_profiles.py from measured calibrations; do not edit.\n"
                  f"# return_mode: {RETURN_MODE} (the multi-echo clouds the learned weather filter was trained on); "
                  f"the real driver's default: {DRIVER_RETURN_MODE[name]}. The switch waits for a retrain.\n"
                  f"# optics.wavelength_nm: {OPTICS[name][1]}; lens separation, receiver FOV and apertures are "
                  "assumed (scripts/make_sensor_profiles.py OPTICS).\n")
        (out / f"{name}.yaml").write_text(header + yaml.safe_dump(profile(name, beams), sort_keys=False))
        print(f"wrote {out / name}.yaml ({len(beams)} beams)")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
