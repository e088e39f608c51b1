"""The weather filters on labelled simulation never used in training, and the per-frame KNN.

    python benchmarks/validation/weather_filter_eval.py [--no-train] [--methods dror,dsor,lior,echo,learned]
    python benchmarks/validation/weather_filter_eval.py --strip-epw [--no-train] [--profiles vlp16,...]

1. Simulates (or reuses, under .venv/cache/weather_filter) the training runs
   (weather_filter.simdata.TRAIN_SPECS) and the held-out runs (HELDOUT_SPECS: other
   scenarios and seeds), and the 131k+-point timing run (TIMING_SPEC, os1_128_2048).
2. Unless --no-train: reruns the shipped model's own ``command`` (weather-filter train
   --sim ...) into .venv/cache/weather_filter/models/ and reports whether the file is
   byte-identical to the shipped one; the table then uses the retrained file.
3. Prints method x (weather_f1, precision, recall, object_recall, object_recall_roi)
   micro-averaged over the held-out runs of each profile, per-run F1, and the repeated
   timing on one frame of the timing run (single process; the machine's other load
   shows in the spread).
4. Per-frame weather KNN (shipped model): accuracy on unseen seeds of its training
   scenarios and on other scenarios.

``--strip-epw``: the held-out runs as a single-return driver publishes them (the strongest return of each beam,
no EPW / echo fields: weather_filter.points.single_return), the single-return model (retrained from its stored
command unless --no-train) against DROR, DSOR and LIOR (without its EPW term), and the single-return model
with the intensity scaled x0.25 and x4.
"""

from __future__ import annotations

import argparse
import shlex
import subprocess
import sys
from pathlib import Path

import numpy as np

from weather_filter.evaluate import Accumulator
from weather_filter.filter_methods import make_filter
from weather_filter.learned.filter import DEFAULT_MODEL, SINGLE_RETURN_MODEL
from weather_filter.points.single_return import single_return_cloud
from weather_filter.simdata import HELDOUT_SPECS, TRAIN_SPECS, SimSpec, default_cache_dir, frames_of, simulate

TIMING_SPEC = "wf_heldout_mixed:102:6:os1_128_2048"


def _without_epw_term(points: np.ndarray) -> np.ndarray:
    """``points`` with an EPW field of 0 m: LIOR's EPW condition always holds (LIOR on intensity alone)."""
    from numpy.lib import recfunctions

    return recfunctions.append_fields(points, "epw", np.zeros(len(points), np.float32), usemask=False)


def evaluate_runs(method: str, specs, model: Path | None = None, strip: float | None = None) -> tuple[dict, dict]:
    """Micro-averaged result over ``specs`` (filter state reset per run) and per-run F1. ``strip``: each cloud
    as a single-return (strongest) driver publishes it, the intensity times ``strip``."""
    filt = make_filter(method, **({"model_path": str(model)} if model and method == "learned" else {}))
    total, per_run = Accumulator(method), {}
    for spec in specs:
        acc = Accumulator(method)
        filt.reset()
        for points in frames_of(simulate(spec)):
            if strip is not None:
                points = single_return_cloud(points, "strongest", strip)
                if method == "lior":
                    points = _without_epw_term(points)
            result = filt(points)
            total.add(points, result.remove, result.elapsed_s)
            acc.add(points, result.remove, result.elapsed_s)
        per_run[spec] = acc.result()
    return total.result(), per_run


def retrain(packaged: Path = DEFAULT_MODEL) -> tuple[Path, bool]:
    import joblib

    shipped = joblib.load(packaged)
    out = default_cache_dir() / "models" / packaged.name
    argv = shlex.split(shipped["command"])[1:] + ["--out", str(out)]
    print("retraining:", shipped["command"], flush=True)
    subprocess.run([sys.executable, "-m", "weather_filter.cli", *argv], check=True)
    return out, out.read_bytes() == packaged.read_bytes()


def stripped_main(args) -> int:
    """--strip-epw: the held-out runs without EPW and later echoes (see the module's doc)."""
    profiles = args.profiles.split(",")
    specs = [s for s in HELDOUT_SPECS if (SimSpec.parse(s).profile or "scala4") in profiles]
    for spec in specs:
        simulate(spec)
    model = SINGLE_RETURN_MODEL
    if not args.no_train:
        model, identical = retrain(SINGLE_RETURN_MODEL)
        print(f"retrained model byte-identical to the shipped {SINGLE_RETURN_MODEL.name}: {identical}")
    methods = [m for m in args.methods.split(",") if m != "echo"]  # echo needs the echoes stripped here
    groups: dict[str, list[str]] = {}
    for spec in specs:
        groups.setdefault(SimSpec.parse(spec).profile or "scala4", []).append(spec)
    print("\nheld-out runs, strongest return only, no EPW / echo fields: weather F1 / object recall (micro-averaged per "
          "profile; lior without its EPW term; learned = the single-return model)")  # fmt: skip
    cases = [(m, 1.0) for m in methods] + ([("learned", 0.25), ("learned", 4.0)] if "learned" in methods else [])
    names = [m if scale == 1.0 else f"{m} x{scale:g}" for m, scale in cases]
    print("| profile | " + " | ".join(names) + " | ms/frame (learned) |")
    print("|---" * (len(names) + 2) + "|")
    for profile, group in groups.items():
        cells, ms = [], ""
        for method, scale in cases:
            r, _ = evaluate_runs(method, group, model if method == "learned" else None, strip=scale)
            cells.append(f"{r['weather_f1']:.3f} / {r['object_recall']:.4f}")
            if method == "learned" and scale == 1.0:
                ms = f"{r['ms_per_frame_mean']:.1f}"
        print(f"| {profile} | " + " | ".join(cells) + f" | {ms} |", flush=True)
    return 0


def repeat_timing(methods, model: Path | None, repeats: int = 20) -> None:
    """Each filter on one frame of TIMING_SPEC, ``repeats`` times: min / median / p95 ms (machine load shows)."""
    frames = list(frames_of(simulate(TIMING_SPEC)))
    first, points = frames[0], frames[1]
    import os

    load = ", ".join(f"{v:.1f}" for v in os.getloadavg())
    print(f"\nrepeated timing on one {len(points)}-point frame of {TIMING_SPEC} ({repeats}x, load average {load} "
          f"on {os.cpu_count()} cores): min / median / p95 ms")  # fmt: skip
    for method in methods:
        filt = make_filter(method, **({"model_path": str(model)} if model and method == "learned" else {}))
        filt(first)
        times = []
        for _ in range(repeats):
            times.append(filt(points).elapsed_s * 1e3)
        print(f"  {method:8s} {np.min(times):7.2f} {np.median(times):7.2f} {np.percentile(times, 95):7.2f}")


def knn_accuracy() -> None:
    from weather_filter.weather_class import (
        KNN_TEST_SCENARIO_SPECS,
        KNN_TEST_SEEDS_SPECS,
        FrameWeatherClassifier,
        run_features,  # fmt: skip
    )

    knn = FrameWeatherClassifier.load()
    for title, specs in (("unseen seeds", KNN_TEST_SEEDS_SPECS), ("other scenarios", KNN_TEST_SCENARIO_SPECS)):
        x, y, names = run_features(specs)
        pred = knn.model.predict(x)
        conf = knn.model.predict_proba(x).max(axis=1)
        y, names = np.array(y), np.array(names)
        print(f"\nKNN per-frame weather, {title}: accuracy {np.mean(pred == y):.4f} over {len(y)} frames, "
              f"mean confidence {conf.mean():.3f}")  # fmt: skip
        for spec in specs:
            m = names == spec
            wrong = dict(zip(*np.unique(pred[m][pred[m] != y[m]], return_counts=True)))
            print(f"  {spec:42s} {y[m][0]:6s} {np.mean(pred[m] == y[m]):.3f}" + (f"  wrong: {wrong}" if wrong else ""))


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--no-train", action="store_true", help="use the shipped model, do not retrain")
    parser.add_argument("--methods", default="dror,dsor,lior,echo,learned")
    parser.add_argument("--knn-only", action="store_true", help="only the per-frame weather KNN's accuracy (part 4)")
    parser.add_argument("--strip-epw", action="store_true", help="the held-out runs without EPW and later echoes "
                        "(strongest return): the single-return model against dror, dsor and lior, and intensity x0.25 / x4")  # fmt: skip
    parser.add_argument("--profiles", default="os1_128_1024,os1_128_2048,vlp16,vlp32c,hdl64e",
                        help="--strip-epw: the profiles whose held-out runs are evaluated (scala4 too if named)")  # fmt: skip
    args = parser.parse_args()
    if args.strip_epw:
        if args.methods == parser.get_default("methods"):
            args.methods = "dror,dsor,lior,learned"
        return stripped_main(args)
    if args.knn_only:
        knn_accuracy()
        return 0
    methods = args.methods.split(",")
    for spec in (*TRAIN_SPECS, *HELDOUT_SPECS, TIMING_SPEC):
        simulate(spec)
    model = None
    if not args.no_train:
        model, identical = retrain()
        print(f"retrained model byte-identical to the shipped {DEFAULT_MODEL.name}: {identical}")
    groups: dict[str, list[str]] = {}
    for spec in HELDOUT_SPECS:
        groups.setdefault(f"{SimSpec.parse(spec).profile or 'scala4'} held-out", []).append(spec)
    header = f"{'method':8s} {'weather_f1':>10s} {'precision':>9s} {'recall':>7s} {'object_recall':>13s} {'obj_roi':>8s} {'ms_mean':>8s} {'ms_p95':>7s}"
    per_run_all = {}
    for group, specs in groups.items():
        points = sum(len(p) for s in specs for p in frames_of(simulate(s))) / sum(1 for s in specs for _ in frames_of(simulate(s)))
        print(f"\n{group} ({', '.join(specs)}; {points:.0f} points/frame)\n{header}")
        for method in methods:
            r, per_run = evaluate_runs(method, specs, model)
            per_run_all.setdefault(method, {}).update(per_run)
            print(f"{method:8s} {r['weather_f1']:10.4f} {r['weather_precision']:9.4f} {r['weather_recall']:7.4f} "
                  f"{r['object_recall']:13.4f} {r['object_recall_roi']:8.4f} {r['ms_per_frame_mean']:8.2f} {r['ms_per_frame_p95']:7.2f}")  # fmt: skip
    print("\nper run: weather_f1 / object_recall")
    specs = [s for g in groups.values() for s in g]
    print(f"{'run':42s} " + " ".join(f"{m:>15s}" for m in methods))
    for spec in specs:
        print(f"{spec:42s} " + " ".join(f"{per_run_all[m][spec]['weather_f1']:7.4f}/{per_run_all[m][spec]['object_recall']:.4f}" for m in methods))
    repeat_timing(methods, model)
    knn_accuracy()
    return 0


if __name__ == "__main__":
    sys.exit(main())
