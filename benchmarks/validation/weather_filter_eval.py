"""The weather filters on labelled simulation never used in training, and the per-frame KNN.

    python benchmarks/validation/weather_filter_eval.py [--no-train] [--methods dror,dsor,lior,echo,learned]

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
from weather_filter.learned.filter import DEFAULT_MODEL
from weather_filter.simdata import HELDOUT_SPECS, TRAIN_SPECS, SimSpec, default_cache_dir, frames_of, simulate

TIMING_SPEC = "wf_heldout_mixed:102:6:os1_128_2048"


def evaluate_runs(method: str, specs, model: Path | None = None) -> tuple[dict, dict]:
    """Micro-averaged result over ``specs`` (filter state reset per run) and per-run F1."""
    filt = make_filter(method, **({"model_path": str(model)} if model and method == "learned" else {}))
    total, per_run = Accumulator(method), {}
    for spec in specs:
        acc = Accumulator(method)
        filt.reset()
        for points in frames_of(simulate(spec)):
            result = filt(points)
            total.add(points, result.remove, result.elapsed_s)
            acc.add(points, result.remove, result.elapsed_s)
        per_run[spec] = acc.result()
    return total.result(), per_run


def retrain() -> tuple[Path, bool]:
    import joblib

    shipped = joblib.load(DEFAULT_MODEL)
    out = default_cache_dir() / "models" / DEFAULT_MODEL.name
    argv = shlex.split(shipped["command"])[1:] + ["--out", str(out)]
    print("retraining:", shipped["command"], flush=True)
    subprocess.run([sys.executable, "-m", "weather_filter.cli", *argv], check=True)
    return out, out.read_bytes() == DEFAULT_MODEL.read_bytes()


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
    args = parser.parse_args()
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
