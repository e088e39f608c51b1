"""Physical atmosphere: ms to build its volume tables (one ``PhysicalAir``: the far table and the near field's
``REALISATIONS`` realisations, :mod:`lidar_weather_sim.regions.air_volume`) per profile and weather state, as the
gap search does once per candidate weather state.

Per profile, ``first`` is the first construction in the process (fog 30 m: numba's cached kernels loaded, the
profile's overlap sampled once per optics); each weather state's row is then the median of ``--repeats``
constructions.

    python benchmarks/performance/volume_table_time.py [--profiles scala4 os1_128_2048] [--repeats N]
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from lidar_weather_sim.regions.physical_air import PhysicalAir
from lidar_weather_sim.sensor.profile import load_profile

#: weather state -> (fog visual range m or None, precipitation (kind, mm/h) or None)
STATES = {
    "fog 30 m": (30.0, None),
    "fog 50 m": (50.0, None),
    "fog 500 m": (500.0, None),
    "rain 10 mm/h": (None, ("rain", 10.0)),
    "snow 5 mm/h": (None, ("snow", 5.0)),
    "fog 300 m + rain 2 mm/h": (300.0, ("rain", 2.0)),
}


def build_ms(profile, fog: float | None, precipitation: tuple[str, float] | None) -> float:
    """ms of one ``PhysicalAir(profile, fog, precipitation)``."""
    t0 = time.perf_counter()
    PhysicalAir(profile, fog, precipitation)
    return 1e3 * (time.perf_counter() - t0)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--profiles", nargs="+", default=["scala4", "os1_128_2048"])
    ap.add_argument("--repeats", type=int, default=7, help="constructions per weather state (median)")
    args = ap.parse_args()
    print(f"{'profile':14s} {'weather':26s} {'ms':>8s}")
    for name in args.profiles:
        profile = load_profile(name)
        print(f"{name:14s} {'first (fog 30 m)':26s} {build_ms(profile, *STATES['fog 30 m']):8.1f}")
        for state, weather in STATES.items():
            ms = np.median([build_ms(profile, *weather) for _ in range(args.repeats)])
            print(f"{name:14s} {state:26s} {ms:8.1f}")


if __name__ == "__main__":
    main()
