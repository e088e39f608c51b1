"""`gap` on the draw over the fixed generators (config/generator_draw.yaml, issue 52), every case reported.

    python benchmarks/validation/generator_draw.py [--only 0,1,2] [--profiles scala4] [--frames 24] [--out DIR] [--json F]

Per case, in the draw's order: a "measured" bag of ``FRAMES`` frames of the case's scenario and profile made by
its generator (`make-measured --generator G --hide ...` at the case's seed, with make-measured's nuisance), then
run_gap (the library call of `lidar-weather-sim gap`, weather family) with the budgets of the project's own draw
(config/gap_cases.yaml: 10 calibration, 10 held-out, 4 screening frames). One row per case: what was hidden, what
gap named, the verdict and the held-out gap before -> after, seconds:

- ``right``: exactly the hidden effects named (the weather, and cover.dirt when the case has a dirty cover), each
  main parameter within 25 %;
- ``right name``: the right effects, a main parameter off by more than 25 %;
- ``wrong``: an effect named that was not hidden (a wrong name);
- ``unexplained``: a subset of the hidden effects named, nothing else, and zones reported unexplained (the
  judgement after the search, lidar_weather_sim.gap.unexplained: what the named effects leave);
- ``missed``: a subset of the hidden effects named, nothing else and nothing reported unexplained.

Only the effects the judgement names count (an accepted effect it refuses is in the ``fitted`` column, not named);
the unexplained zones are listed with their shapes.

The generators and the draw were committed before any search ran on them (session 35); neither changes after.
"""

from __future__ import annotations

import argparse
import json
import tempfile
import time
from pathlib import Path

import yaml

from lidar_weather_sim.core.paths import config_dir
from lidar_weather_sim.gap.command import run_gap
from lidar_weather_sim.references.measured import make_measured
from lidar_weather_sim.scenario.effects import EFFECTS, parse_effect
from lidar_weather_sim.scenario.schema import load_scenario

FRAMES = 24  # frames per measured bag, and the search's budgets: those of config/gap_cases.yaml
BUDGETS = {"fit_frames": 10, "heldout_frames": 10, "screen_frames": 4}
TOLERANCE = 0.25


def verdict(hidden: dict[str, float], named: dict[str, float], unexplained: list[str] = ()) -> str:
    """The case's verdict (module doc) from the hidden and named effects' main parameters and the unexplained
    zones."""
    if set(named) - set(hidden):
        return "wrong"
    if set(named) != set(hidden):
        return "unexplained" if unexplained else "missed"
    return "right" if all(abs(named[n] / v - 1.0) <= TOLERANCE for n, v in hidden.items()) else "right name"


def budgets(frames: int) -> dict[str, int]:
    """The search's budgets for a bag of ``frames`` frames: :data:`BUDGETS` at :data:`FRAMES`, fewer below."""
    fit = min(BUDGETS["fit_frames"], frames // 2)
    return {"fit_frames": fit, "heldout_frames": fit, "screen_frames": min(BUDGETS["screen_frames"], max(1, fit // 2))}


def judged(result: dict) -> tuple[dict[str, float], dict[str, float], list[str]]:
    """(named, fitted and not named, unexplained zones) of a gap result (gap.json's content): each effect by its
    main parameter, each zone as "label, shape (N sigma)"."""
    named: dict[str, float] = {}
    fitted: dict[str, float] = {}
    for e in result["effects"]:
        (named if e.get("named", True) else fitted).setdefault(e["name"], float(e["params"][EFFECTS[e["name"]].main]))
    return named, fitted, [f"{u['label']}, {u['shape']} ({u['sigma']:.0f} sigma)" for u in result.get("unexplained", [])]


def effects_text(effects: dict[str, float]) -> str:
    """``name value, ...`` or ``nothing``."""
    return ", ".join(f"{k} {v:.4g}" for k, v in effects.items()) or "nothing"


def append_row(path: str | None, row: dict) -> None:
    """Append ``row`` to the JSON-lines file ``path`` (none: nothing)."""
    if path:
        with open(path, "a") as f:
            f.write(json.dumps(row) + "\n")


def run_case(case: dict, work: Path, frames: int = FRAMES) -> dict:
    """Make the case's bag of ``frames`` frames, search it, and score it."""
    start = time.perf_counter()
    effects = [parse_effect(text) for text in case["hide"]]
    bag = work / f"case_{case['index']:02d}"
    scenario = load_scenario(case["scenario"])
    make_measured(scenario, effects, bag, frames=frames, seed=case["seed"], profile=case["profile"],
                  generator=case["generator"], overwrite=True)  # fmt: skip
    result = run_gap(bag, scenario, work / f"gap_{case['index']:02d}", profile=case["profile"], **budgets(frames))
    hidden = {e.name: e.value for e in effects}
    named, fitted, unexplained = judged(result)
    return {"index": case["index"], "generator": case["generator"], "profile": case["profile"], "hidden": hidden,
            "named": named, "fitted_not_named": fitted, "unexplained": unexplained,
            "verdict": verdict(hidden, named, unexplained), "gap_before": result["gap_before"],
            "gap_after": result["gap_after"], "seconds": time.perf_counter() - start}  # fmt: skip


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--only", help="comma-separated case indices to run")
    parser.add_argument("--profiles", default="scala4,os1_128_1024", help="run only the cases of these profiles")
    parser.add_argument("--out", help="keep bags and gap reports here (default: a temporary directory)")
    parser.add_argument("--json", help="append each case's row to this JSON-lines file")
    parser.add_argument("--frames", type=int, default=FRAMES, help="frames per bag (default %(default)s; fewer: "
                        "the budgets shrink to half the frames each, a quarter for screening)")
    args = parser.parse_args()
    cases = yaml.safe_load((config_dir() / "generator_draw.yaml").read_text())["cases"]
    profiles = set(args.profiles.split(","))
    cases = [c for c in cases if c["profile"] in profiles]
    if args.only:
        keep = {int(i) for i in args.only.split(",")}
        cases = [c for c in cases if c["index"] in keep]
    print("| # | generator | profile | hidden | named | fitted, not named | unexplained | verdict | "
          "held-out gap before -> after | s |\n|---:|---|---|---|---|---|---|---|---|---:|", flush=True)  # fmt: skip
    with tempfile.TemporaryDirectory() as tmp:
        work = Path(args.out or tmp)
        work.mkdir(parents=True, exist_ok=True)
        for case in cases:
            row = run_case(case, work, args.frames)
            text = effects_text
            print(f"| {row['index']} | {row['generator']} | {row['profile']} | {text(row['hidden'])} | "
                  f"{text(row['named'])} | {text(row['fitted_not_named'])} | {'; '.join(row['unexplained']) or '-'} | "
                  f"{row['verdict']} | {row['gap_before']:.4f} -> {row['gap_after']:.4f} | "
                  f"{row['seconds']:.0f} |", flush=True)  # fmt: skip
            append_row(args.json, row)


if __name__ == "__main__":
    main()
