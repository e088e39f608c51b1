"""Gap-search generalisation baseline: `gap` on the seeded cases of config/gap_cases.yaml.

    python benchmarks/validation/gap_generalisation.py [--cases K] [--only 3,7] [--cases-file F] [--out DIR]
        [--fast-via-sim] [--reuse-bags] [--json F] [--frames N --budgets FIT,HELDOUT,SCREEN]

Cases come from lidar_weather_sim.references.cases.draw_cases (ranges and seed committed before anything ran on
them). Per case a "measured" scala4 highway_clear bag of `measurement.frames` frames is made by its
generator: fast = make-measured --on a clear base bag (make-measured with nothing hidden, made once;
the effects at the scenario's seed), reference = make-measured --reference, hahner = make-measured
--generator hahner (both at the case's seed, with make-measured's nuisance). Then run_gap (the library call
of `lidar-weather-sim gap`) with the file's budgets. One row per case: the true effects and values, what
gap named (its judgement's names: an effect it fitted and refused is listed apart, as fitted), exact-name hit,
main parameter within 25 % (every true effect, only with an exact-name hit), phantom (a named effect not hidden),
held-out gap before -> after, seconds. A summary per generator follows. ``--frames`` and ``--budgets`` override
the file's frames per bag and the search's frame budgets (a case at more frames than the draw affords).
"""

from __future__ import annotations

import argparse
import json
import tempfile
import time
from pathlib import Path

from lidar_weather_sim.augment.command import augment_recording
from lidar_weather_sim.references.cases import Case, draw_cases
from lidar_weather_sim.gap.command import run_gap
from lidar_weather_sim.scenario.effects import EFFECTS
from lidar_weather_sim.references.measured import make_measured
from lidar_weather_sim.scenario.schema import load_scenario


def score(case: Case, result: dict, tolerance: float) -> dict:
    """The case's row: what was hidden (``truth``), what the judgement named (``found``; an effect the search fitted
    and the judgement refused is in ``fitted``, not named: gap.json's ``named``), exact name, main parameters
    within ``tolerance``, phantom (a named effect not hidden)."""
    truth = {e.name: e.value for e in case.parsed()}
    found, fitted = {}, {}
    for e in result["effects"]:
        main = EFFECTS[e["name"]].main
        (found if e.get("named", True) else fitted).setdefault(e["name"], float(e["params"][main]))
    exact = set(found) == set(truth)
    within = exact and all(abs(found[n] / v - 1.0) <= tolerance for n, v in truth.items())
    return {"truth": truth, "found": found, "fitted": fitted, "exact": exact, "within": within,
            "phantom": bool(set(found) - set(truth)), "gap_before": result["gap_before"],
            "gap_after": result["gap_after"]}  # fmt: skip


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--cases", type=int, help="run only the first K cases of the draw")
    parser.add_argument("--only", help="comma-separated case indices to run")
    parser.add_argument("--cases-file", help="default config/gap_cases.yaml")
    parser.add_argument("--out", help="keep bags and gap reports here (default: a temporary directory)")
    parser.add_argument("--json", help="append each case's row to this JSON-lines file as the case ends")
    parser.add_argument("--fast-via-sim", action="store_true",
                        help="make the fast cases by simulating the scenario with the effects (make-measured, at the "
                             "case's seed) instead of make-measured --on the clear base bag (a supplementary check)")
    parser.add_argument("--reuse-bags", action="store_true",
                        help="search a case bag already in --out instead of making it again (when only the search "
                             "changed since it was made)")
    parser.add_argument("--frames", type=int, help="frames per case bag (default: the file's measurement.frames)")
    parser.add_argument("--budgets", help="FIT,HELDOUT,SCREEN frames of the search (default: the file's)")
    args = parser.parse_args()
    config, cases = draw_cases(args.cases_file)
    if args.only:
        keep = {int(i) for i in args.only.split(",")}
        cases = [c for c in cases if c.index in keep]
    elif args.cases:
        cases = cases[: args.cases]
    m = config["measurement"]
    if args.frames:
        m["frames"] = args.frames
    if args.budgets:
        m["fit_frames"], m["heldout_frames"], m["screen_frames"] = (int(v) for v in args.budgets.split(","))
    tolerance = float(config["success"]["parameter_tolerance"])
    scenario = load_scenario(config["scenario"])
    budgets = {"fit_frames": m["fit_frames"], "heldout_frames": m["heldout_frames"],
               "screen_frames": m["screen_frames"]}  # fmt: skip
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        work = Path(args.out or tmp)
        work.mkdir(parents=True, exist_ok=True)
        base = work / "base_clear"
        if any(c.generator == "fast" for c in cases) and not args.fast_via_sim and not base.exists():
            make_measured(scenario, [], base, frames=m["frames"], profile=config["profile"])
        print("| # | generator | true | named | fitted, not named | exact | within 25 % | phantom | held-out gap "
              "before -> after | s |\n|---:|---|---|---|---|---|---|---|---|---:|", flush=True)  # fmt: skip
        for case in cases:
            start = time.perf_counter()
            bag = work / f"case_{case.index:02d}"
            effects = case.parsed()
            if args.reuse_bags and (bag / "metadata.yaml").exists():
                pass
            elif case.generator == "fast" and args.fast_via_sim:
                make_measured(scenario, effects, bag, frames=m["frames"], seed=case.seed, profile=config["profile"],
                              overwrite=True)  # fmt: skip
            elif case.generator == "fast":
                augment_recording(base, scenario, effects, bag, profile=config["profile"], overwrite=True)
            else:
                make_measured(scenario, effects, bag, frames=m["frames"], seed=case.seed, profile=config["profile"],
                              generator=case.generator, overwrite=True)  # fmt: skip
            result = run_gap(bag, scenario, work / f"gap_{case.index:02d}", profile=config["profile"], **budgets)
            row = {"index": case.index, "generator": case.generator, "effects": list(case.effects),
                   **score(case, result, tolerance), "seconds": time.perf_counter() - start}  # fmt: skip
            rows.append(row)
            if args.json:  # as each case ends: a run stopped early keeps the cases it finished
                with open(args.json, "a") as f:
                    f.write(json.dumps(row) + "\n")
            named = ", ".join(f"{n} {v:.4g}" for n, v in row["found"].items()) or "none"
            fitted = ", ".join(f"{n} {v:.4g}" for n, v in row["fitted"].items()) or "-"
            true = ", ".join(f"{n} {v:.4g}" for n, v in row["truth"].items())
            yes = {True: "yes", False: "no"}
            print(f"| {case.index} | {case.generator} | {true} | {named} | {fitted} | {yes[row['exact']]} "
                  f"| {yes[row['within']]} | {yes[row['phantom']]} | {row['gap_before']:.4f} -> {row['gap_after']:.4f} "
                  f"| {row['seconds']:.0f} |", flush=True)  # fmt: skip
    print("\n| generator | cases | exact name | exact + within 25 % | phantom | median held-out gap ratio |\n"
          "|---|---:|---:|---:|---:|---:|")  # fmt: skip
    for gen in dict.fromkeys(r["generator"] for r in rows):
        sub = [r for r in rows if r["generator"] == gen]
        ratios = sorted(r["gap_after"] / r["gap_before"] if r["gap_before"] > 0 else 1.0 for r in sub)
        print(f"| {gen} | {len(sub)} | {sum(r['exact'] for r in sub)} | {sum(r['within'] for r in sub)} | "
              f"{sum(r['phantom'] for r in sub)} | {ratios[len(ratios) // 2]:.2f} |")


if __name__ == "__main__":
    main()
