"""How well the calibration scans can tell a near-field ghost rate: the counting limit of the ghost draws.

For every ghost case of ``config/ghost_effect_cases.yaml`` (the profile's cases, numbered and seeded as
``sensor_effect_recovery.py --cases config/ghost_effect_cases.yaml`` numbers them: case k measured with seed
1000 + k) this counts the cover-zone returns (< 0.5 m) in the calibration scans (0 and 2) of the case's
"measured" re-simulation, and compares them with what the model gives at the hidden rate (mean over
``--redraws`` draws of the search's own scenario seed): the Poisson relative standard deviation of the count,
how many sigma the measured count lies from its expectation, and the rate the count reads on the model's
count-rate curve (counts at log-spaced rates, each the mean over the redraws, interpolated). A rate read
from the counts alone is as good as any estimator from these scans can be; when it misses the hidden rate by
more than the 15 % the draws ask, so must the search.

    python benchmarks/ghost_count_limit.py [--profile vlp16] [--redraws 4]
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np
import yaml
from sensor_effect_recovery import MEASURED_SEED, draw_cases

CALIBRATION = [0, 2]  # the search's fit frames of the 3-scan recording (even frames calibrate)


def main() -> None:
    from lidar_weather_sim.core.paths import cache_dir
    from lidar_weather_sim.scenario.effects import Effect
    from lidar_weather_sim.gap.ghost import cover_returns as cover_count
    from lidar_weather_sim.replay.resimulator import Resimulator
    from lidar_weather_sim.io.recording import Recording
    from lidar_weather_sim.scenario.schema import load_scenario

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--cases", default="config/ghost_effect_cases.yaml")
    parser.add_argument("--profile", default="vlp16")
    parser.add_argument("--scenario", default="ouster_street")
    parser.add_argument("--recording", default=str(cache_dir() / "ouster_real" / "os1_128_street"))
    parser.add_argument("--redraws", type=int, default=4, help="model draws averaged per rate (default 4)")
    args = parser.parse_args()
    spec = yaml.safe_load(Path(args.cases).read_text())
    cases = [c for c in draw_cases(spec) if c[0] == args.profile]
    recording, scenario = Recording.load(args.recording), load_scenario(args.scenario)
    model = Resimulator(recording, scenario, args.profile)
    name = "sensor.near_field_ghost"

    def expected(rate: float) -> float:
        effects = [Effect(name, {"rate": rate})]
        return float(np.mean([cover_count(model.frames(effects, CALIBRATION, redraw=d)) for d in range(args.redraws)]))

    low, high = spec["effects"][name]["range"]
    rates = np.geomspace(0.5 * low, 2.0 * high, 13)
    curve = np.array([expected(r) for r in rates])
    base = float(np.mean([cover_count(model.frames([], CALIBRATION, redraw=d)) for d in range(args.redraws)]))
    print(f"{args.profile}: cover-zone returns in calibration scans {CALIBRATION} (mean of {args.redraws} model draws); "
          f"without ghosts {base:.1f}")  # fmt: skip
    print(f"{'#':>3} {'hidden':>8} {'measured':>8} {'expected':>8} {'poisson':>8} {'sigma':>6} {'count reads':>11} {'error':>7}")
    for k, (_, effect, rate) in enumerate(cases):
        if effect != name:
            continue
        measured = Resimulator(recording, scenario.model_copy(update={"seed": MEASURED_SEED + k}), args.profile)
        got = cover_count(measured.frames([Effect(name, {"rate": rate})], CALIBRATION))
        mean = expected(rate)
        reads = float(np.exp(np.interp(got, curve, np.log(rates))))  # the curve rises with the rate
        print(f"{k:3d} {rate:8.4f} {got:8d} {mean:8.1f} {100 / np.sqrt(max(mean, 1.0)):7.1f}% "
              f"{(got - mean) / np.sqrt(max(mean, 1.0)):+6.2f} {reads:11.4f} {100 * (reads / rate - 1):+6.1f}%", flush=True)  # fmt: skip


if __name__ == "__main__":
    main()
