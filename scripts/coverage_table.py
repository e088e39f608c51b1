"""Line coverage per package of each tier's coverage JSON (``make coverage``), and the fast tier's share of the full run's.

    python scripts/coverage_table.py log/coverage/fast.json log/coverage/all.json
"""

from __future__ import annotations

import json
import sys
from collections import defaultdict
from pathlib import Path

PACKAGES = ("lidar_weather_sim", "spray_particles", "weather_filter")


def by_package(path: Path) -> dict[str, tuple[int, int]]:
    """package -> (covered lines, statements), from coverage.py's JSON report."""
    totals: dict[str, list[int]] = defaultdict(lambda: [0, 0])
    for name, data in json.loads(path.read_text())["files"].items():
        package = next((p for p in PACKAGES if f"/{p}/{p}/" in "/" + name or name.startswith(f"{p}/")), None)
        if package is None:
            continue
        totals[package][0] += data["summary"]["covered_lines"]
        totals[package][1] += data["summary"]["num_statements"]
    totals["all"] = [sum(v[0] for v in totals.values()), sum(v[1] for v in totals.values())]
    return {k: (v[0], v[1]) for k, v in totals.items()}


def main(paths: list[str]) -> int:
    tiers = {Path(p).stem: by_package(Path(p)) for p in paths}
    names = list(tiers)
    print("| package | " + " | ".join(f"{n} tier: lines covered" for n in names)
          + (f" | {names[0]} / {names[-1]} |" if len(names) > 1 else " |"))
    print("|---" * (len(names) + 1 + (len(names) > 1)) + "|")
    for package in (*PACKAGES, "all"):
        cells = []
        for name in names:
            covered, total = tiers[name].get(package, (0, 0))
            cells.append(f"{100 * covered / max(total, 1):.1f} % ({covered} of {total})")
        ratio = ""
        if len(names) > 1:
            first, last = tiers[names[0]].get(package, (0, 1)), tiers[names[-1]].get(package, (0, 1))
            ratio = f" | {100 * first[0] / max(last[0], 1):.0f} %"
        print(f"| {package} | " + " | ".join(cells) + ratio + " |")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
