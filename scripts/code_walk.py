"""How far a reader walks to follow one command: project functions and files visited, and jumps back.

Runs ``lidar-weather-sim ARGS...`` in this process under ``sys.setprofile`` and counts, over the project's
own packages' source files (wherever they are imported from):

- places: distinct project functions called (file, function name);
- files: distinct project files those functions live in;
- jumps back: calls from one project file into another project file that the walk had already left
  (the reader turns back to a file they had closed); counted per call and per distinct (from, to) pair of
  files.

    python scripts/code_walk.py run highway_clear --frames 1 --out /tmp/walk_run --overwrite
    python scripts/code_walk.py gap --scenario highway_clear MEASURED_BAG --out /tmp/walk_gap
    python scripts/code_walk.py --pairs run ...   (also list every distinct jump back)
"""

from __future__ import annotations

import sys
from collections import Counter
from pathlib import Path

PACKAGES = ("lidar_weather_sim", "spray_particles", "weather_filter")


def walk(argv: list[str]) -> tuple[int, set[tuple[str, str]], list[tuple[str, str]]]:
    """Exit status, places (file, function) and jumps back (from file, to file) of ``lidar-weather-sim argv``."""
    from lidar_weather_sim.cli import main

    import importlib

    roots = tuple(str(Path(importlib.import_module(name).__file__).parent) + "/" for name in PACKAGES)
    places: set[tuple[str, str]] = set()
    left: set[str] = set()
    jumps: list[tuple[str, str]] = []

    def profile(frame, event, _arg):
        if event != "call":
            return
        callee = frame.f_code.co_filename
        if not callee.startswith(roots):
            return
        places.add((callee, frame.f_code.co_name))
        caller = frame.f_back.f_code.co_filename if frame.f_back is not None else ""
        if caller.startswith(roots) and caller != callee:
            if callee in left:
                jumps.append((caller, callee))
            left.add(caller)

    sys.setprofile(profile)
    try:
        status = main(argv)
    except SystemExit as exit_:
        status = exit_.code
    finally:
        sys.setprofile(None)
    return status, places, jumps


def _short(path: str) -> str:
    """``path`` from its package's folder on (``lidar_weather_sim/sim/offline.py``)."""
    return path[max(path.rfind(f"/{name}/") for name in PACKAGES) + 1:]


def main() -> int:
    pairs_wanted = "--pairs" in sys.argv[1:2]
    argv = sys.argv[2:] if pairs_wanted else sys.argv[1:]
    status, places, jumps = walk(argv)
    files = Counter(f for f, _ in places)
    pairs = set(jumps)
    print(f"lidar-weather-sim {' '.join(argv)}: exit {status}, {len(places)} places in {len(files)} files, "
          f"{len(jumps)} jumps back ({len(pairs)} distinct file pairs)")  # fmt: skip
    back_into = Counter(to for _, to in pairs)
    for path, count in sorted(files.items(), key=lambda kv: (-back_into[kv[0]], kv[0])):
        print(f"  {count:4d} places, jumped back into from {back_into[path]:3d} files: {_short(path)}")
    if pairs_wanted:
        for source, target in sorted(pairs):
            print(f"  jump back: {_short(source)} -> {_short(target)}")
    return 0 if status in (0, None) else 1


if __name__ == "__main__":
    sys.exit(main())
