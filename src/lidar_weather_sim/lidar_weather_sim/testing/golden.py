"""Golden clouds: the first frames of every shipped scenario, recorded through ``run``, as committed hashes.

Like a driver's decoder tests against committed ground truth: ``test/test_golden_clouds.py`` simulates each
case below exactly as ``lidar-weather-sim run`` does (same :func:`~lidar_weather_sim.sim.offline.run_scenario`,
into a real bag) and compares every frame's point count and the SHA-256 of its cloud bytes with
``test/golden/clouds.yaml``. A change that changes clouds must rewrite that file in the same commit and say why:

    python -m lidar_weather_sim.testing.golden --write test/golden/clouds.yaml

Bit identity holds on one CPU type (numba and Embree compile for the host's instruction set): the file
records the CPU it was written on, and on another CPU the check falls back to each frame's point count
(within 1 %) and the per-field sums of its points (within 1e-4 relative).
"""

from __future__ import annotations

import argparse
import hashlib
import tempfile
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import yaml

from lidar_weather_sim.scenario.schema import load_scenario, scenarios_dir
from lidar_weather_sim.sim.offline import run_scenario

FRAMES = 3
SEED = 7
PROFILES = ("scala4", "os1_128_1024")  # every scenario runs on these two and on its own profile
EVERY_PROFILE_SCENARIO = "highway_spray"  # ... and this one on every shipped profile


@dataclass(frozen=True)
class Case:
    scenario: str
    profile: str

    @property
    def key(self) -> str:
        return f"{self.scenario} on {self.profile}"


def shipped_cases() -> list[Case]:
    """Every shipped scenario (``config/scenarios``) with an ego or a trajectory, on its own profile, scala4 and
    os1_128_1024; the spray highway on every shipped profile (``config/sensors``)."""
    profiles_dir = scenarios_dir().parent / "sensors"
    cases: dict[str, Case] = {}
    for path in sorted(scenarios_dir().glob("*.yaml")):
        scenario = load_scenario(path)
        if scenario.ego is None and not scenario.trajectory:
            continue
        for profile in (scenario.sensor.profile, *PROFILES):
            case = Case(path.stem, profile)
            cases[case.key] = case
    for path in sorted(profiles_dir.glob("*.yaml")):
        case = Case(EVERY_PROFILE_SCENARIO, path.stem)
        cases[case.key] = case
    return list(cases.values())


def host_cpu() -> str:
    """The CPU type numba compiles for (llvm's host CPU name)."""
    import llvmlite.binding as llvm

    return llvm.get_host_cpu_name()


def frame_record(points: np.ndarray) -> dict:
    """One frame's point count, SHA-256 of its bytes (first 16 hex digits) and each field's float64 sum."""
    sums = {name: float(np.sum(points[name], dtype=np.float64)) for name in points.dtype.names}
    return {"points": int(len(points)), "sha256": hashlib.sha256(points.tobytes()).hexdigest()[:16], "sums": sums}


def case_clouds(case: Case, frames: int = FRAMES, seed: int = SEED) -> list[np.ndarray]:
    """The first ``frames`` clouds of ``case``, run as ``lidar-weather-sim run`` runs it (into a real bag)."""
    clouds: list[np.ndarray] = []

    def keep(frame):
        clouds.append(frame.points)
        return frame.points

    with tempfile.TemporaryDirectory() as tmp:
        run_scenario(load_scenario(case.scenario), Path(tmp) / "bag", frames=frames, seed=seed,
                     profile=case.profile, postprocess=keep)  # fmt: skip
    return clouds


def record_case(case: Case, frames: int = FRAMES, seed: int = SEED) -> list[dict]:
    """:func:`frame_record` of each of ``case``'s first ``frames`` clouds."""
    return [frame_record(points) for points in case_clouds(case, frames, seed)]


def differences(expected: list[dict], actual: list[dict], same_cpu: bool) -> list[str]:
    """What differs between two cases' frame records: hashes on the same CPU, counts and sums on another."""
    if len(expected) != len(actual):
        return [f"{len(actual)} frames, golden has {len(expected)}"]
    found = []
    for k, (want, got) in enumerate(zip(expected, actual)):
        if same_cpu:
            if (want["points"], want["sha256"]) != (got["points"], got["sha256"]):
                found.append(f"frame {k}: {got['points']} points {got['sha256']}, golden {want['points']} "
                             f"points {want['sha256']}")  # fmt: skip
            continue
        if abs(got["points"] - want["points"]) > 0.01 * max(want["points"], 1):
            found.append(f"frame {k}: {got['points']} points, golden {want['points']}")
        for name, value in want["sums"].items():
            if not np.isclose(got["sums"].get(name, np.nan), value, rtol=1e-4, atol=1e-6):
                found.append(f"frame {k}: sum of {name} {got['sums'].get(name)}, golden {value}")
    return found


def write(path: Path) -> None:
    cases = {case.key: record_case(case) for case in shipped_cases()}
    header = {"cpu": host_cpu(), "frames": FRAMES, "seed": SEED}
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text("# written by: python -m lidar_weather_sim.testing.golden --write " + str(path) + "\n"
                    + yaml.safe_dump({**header, "cases": cases}, sort_keys=False, width=120))  # fmt: skip


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--write", type=Path, required=True, help="the golden file to (re)write")
    write(parser.parse_args().write)


if __name__ == "__main__":
    main()
