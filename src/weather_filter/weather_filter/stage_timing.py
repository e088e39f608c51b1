"""Stage times of the learned filter on one frame (budget: <= 20 ms per ~131k-point frame).

    python -m weather_filter.stage_timing [--spec wf_heldout_mixed:102:6:os1_128_2048] [--repeats 40] [--single-return]

Runs the filter on the run's first frame (the frame-difference state), then times each stage on its second
frame ``repeats`` times, the stages interleaved so that they share the machine's load: CPU time
(``time.process_time``) and wall time, min and median, in ms. The stages are the calls
:class:`~weather_filter.learned.features.PointFeatures` makes, run on the same arrays.
"""

from __future__ import annotations

import argparse
import os
import time

import numpy as np

from weather_filter.learned import features as F
from weather_filter.learned.azimuth import approx_azimuth
from weather_filter.learned.filter import LearnedFilter, SingleReturnLearnedFilter
from weather_filter.simdata import frames_of, simulate

#: benchmarks/validation/weather_filter_eval.py's timing run (os1_128_2048, ~120k points per frame).
TIMING_SPEC = "wf_heldout_mixed:102:6:os1_128_2048"
FIELDS = ("x", "y", "z", "echo", "channel", "epw", "intensity")


def stages(filt: LearnedFilter, points: np.ndarray) -> dict:
    """name -> callable running that stage of ``filt`` on ``points`` (the feature passes on scratch arrays)."""
    fe = filt.features
    out = np.empty((len(F.FEATURE_NAMES), len(points)), np.float32).T
    azimuth = np.empty(len(points))
    previous = np.zeros(fe._n_radial, np.int64)
    channel = points["channel"]
    n_channels = int(channel.max()) + 1

    def copy_fields():
        for k, name in enumerate(FIELDS):
            out[:, k] = points[name]

    def point_features():
        F._point_features(out, fe._grids, fe._n_radial, 1.0 / fe.radial_bin_deg, previous, True, fe._taps,
                          fe._tap_start, azimuth)  # fmt: skip

    def range_image():
        F._range_image_features(out, azimuth, fe.last_step_rad, n_channels, F.RI_ECHOES, fe.ri_columns,
                                fe.ri_channels, np.float32(F.RI_CLOSE))  # fmt: skip

    feats = fe(points)
    return {
        "copy fields": copy_fields,
        "approx azimuth": lambda: approx_azimuth(out[:, 0], out[:, 1], azimuth),
        "point features": point_features,
        "azimuth step": lambda: F.azimuth_step(out[:, 0], out[:, 1], channel, points["echo"], n_channels),
        "range image": range_image,
        "features (all)": lambda: fe(points),
        "mlp": lambda: filt._fast.logit(feats),
        "filter call": lambda: filt(points),
    }


def single_return_stages(filt: SingleReturnLearnedFilter, points: np.ndarray) -> dict:
    """The single-return model's stages: the EPW model's feature passes (``PointFeatures``), its own features
    on top, the network and the whole filter call."""
    fe = filt.features
    feats = fe(points)
    return {
        "base features": lambda: fe.base(points),
        "features (all)": lambda: fe(points),
        "mlp": lambda: filt._fast.logit(feats),
        "filter call": lambda: filt(points),
    }


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--spec", default=TIMING_SPEC)
    parser.add_argument("--repeats", type=int, default=40)
    parser.add_argument("--single-return", action="store_true", help="the single-return model on the frames "
                        "stripped to their strongest returns without EPW / echo (weather_filter.points.single_return)")  # fmt: skip
    args = parser.parse_args()
    first, points = list(frames_of(simulate(args.spec)))[:2]
    if args.single_return:
        from weather_filter.points.single_return import single_return_cloud

        first, points = single_return_cloud(first), single_return_cloud(points)
        filt = SingleReturnLearnedFilter.load()
        filt(first)
        run = single_return_stages(filt, points)
    else:
        filt = LearnedFilter.load()
        filt(first)
        run = stages(filt, points)
    for fn in run.values():  # state and caches as in a running filter
        fn()
    times = {name: ([], []) for name in run}
    for _ in range(args.repeats):
        for name, fn in run.items():
            w, c = time.perf_counter(), time.process_time()
            fn()
            times[name][0].append(time.process_time() - c)
            times[name][1].append(time.perf_counter() - w)
    load = ", ".join(f"{v:.1f}" for v in os.getloadavg())
    print(f"{len(points)}-point frame of {args.spec}, {args.repeats}x, load average {load} on {os.cpu_count()} cores")
    print(f"{'stage':16s} {'cpu min':>8s} {'median':>7s} {'wall min':>9s} {'median':>7s}  (ms)")
    for name, (cpu, wall) in times.items():
        cpu, wall = 1e3 * np.array(cpu), 1e3 * np.array(wall)
        print(f"{name:16s} {cpu.min():8.2f} {np.median(cpu):7.2f} {wall.min():9.2f} {np.median(wall):7.2f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
