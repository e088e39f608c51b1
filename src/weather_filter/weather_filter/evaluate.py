"""Evaluation of a filter on a bag (``weather-filter eval``).

Definitions: points to remove are labels 10-15, points to keep
labels 1-3 (label 0 counts in neither). Weather precision = removed weather /
all removed points with a label in 1-3 or 10-15; recall = removed weather / weather;
F1 their harmonic mean; ``object_recall`` = kept / points with labels 1-3;
``object_recall_roi`` over labels 2-3 with |y| <= 1.75 m and 5 <= x <= 60 m
(sensor frame). All micro-averaged over the points of all frames, as fractions
in [0, 1]. A value whose denominator is zero is vacuously 1.0 (no points removed:
nothing removed wrongly; no weather or no ROI object points: nothing missed), so
every value stays a number. A bag without ``label`` reports ``removed_fraction`` instead.
Clouds lacking the method's fields (EPW, echo...) are filtered by the geometry-only
fallback with a warning; the result then names it under ``fallback``.
"""

from __future__ import annotations

from typing import Iterable

import numpy as np

from lidar_weather_sim.core.points import SOLID_LABELS, WEATHER_LABELS, Label
from weather_filter.points.base import PointFilter
from weather_filter.points.cloud_check import CloudFieldError, field_problem
from weather_filter.points.fallback import FallbackFilter

ROI_HALF_WIDTH_M = 1.75
ROI_X_M = (5.0, 60.0)
_WEATHER = np.array(sorted(WEATHER_LABELS))
_SOLID = np.array(sorted(SOLID_LABELS))


def _label_name(code: int) -> str:
    try:
        return Label(code).name.lower()
    except ValueError:
        return f"label_{code}"


def _fraction(num: int, den: int) -> float:
    """num / den; 1.0 when there is nothing to count (den == 0), e.g. no ROI points in the bag."""
    return float(num) / den if den else 1.0


class Accumulator:
    """Counts over frames; ``result()`` gives the JSON dictionary."""

    def __init__(self, method: str) -> None:
        self.method = method
        self.frames = 0
        self.times_ms: list[float] = []
        self.labelled = True
        self.points = self.removed = 0
        self.tp = self.fp = self.weather = 0
        self.solid = self.solid_kept = self.roi = self.roi_kept = 0
        self.per_label: dict[int, list[int]] = {}

    def add(self, points: np.ndarray, remove: np.ndarray, elapsed_s: float) -> None:
        self.frames += 1
        self.times_ms.append(elapsed_s * 1e3)
        self.points += len(points)
        self.removed += int(remove.sum())
        if "label" not in (points.dtype.names or ()):
            self.labelled = False
            return
        problem = field_problem(points, "label")
        if problem:
            raise CloudFieldError(problem)
        label = points["label"]
        weather = np.isin(label, _WEATHER)
        solid = np.isin(label, _SOLID)
        self.tp += int((remove & weather).sum())
        self.fp += int((remove & solid).sum())
        self.weather += int(weather.sum())
        self.solid += int(solid.sum())
        self.solid_kept += int((solid & ~remove).sum())
        x, y = points["x"], points["y"]
        roi = np.isin(label, (Label.VEHICLE, Label.OBSTACLE)) & (np.abs(y) <= ROI_HALF_WIDTH_M) & (x >= ROI_X_M[0]) & (x <= ROI_X_M[1])
        self.roi += int(roi.sum())
        self.roi_kept += int((roi & ~remove).sum())
        codes, counts = np.unique(label, return_counts=True)
        removed_codes, removed_counts = np.unique(label[remove], return_counts=True)
        removed_by = dict(zip(removed_codes.tolist(), removed_counts.tolist()))
        for code, count in zip(codes.tolist(), counts.tolist()):
            entry = self.per_label.setdefault(code, [0, 0])
            entry[0] += count
            entry[1] += removed_by.get(code, 0)

    def result(self) -> dict:
        times = np.asarray(self.times_ms) if self.times_ms else np.zeros(1)
        out: dict = {"method": self.method, "frames": self.frames}
        if self.labelled and self.frames:
            precision = _fraction(self.tp, self.tp + self.fp)
            recall = _fraction(self.tp, self.weather)
            out.update(
                weather_precision=precision,
                weather_recall=recall,
                weather_f1=2 * precision * recall / (precision + recall) if precision + recall else 0.0,
                object_recall=_fraction(self.solid_kept, self.solid),
                object_recall_roi=_fraction(self.roi_kept, self.roi),
                per_label={
                    str(code): {"name": _label_name(code), "points": n, "removed": r, "removed_fraction": _fraction(r, n)}
                    for code, (n, r) in sorted(self.per_label.items())
                },
            )
        else:
            out["removed_fraction"] = _fraction(self.removed, self.points)
        out["ms_per_frame_mean"] = float(times.mean())
        out["ms_per_frame_p95"] = float(np.percentile(times, 95))
        return out


def evaluate_frames(filt: PointFilter, frames: Iterable[np.ndarray], method: str | None = None) -> dict:
    """Run ``filt`` over ``frames`` (structured point arrays) and return the evaluation dictionary."""
    acc = Accumulator(method or filt.name)
    filt.reset()
    fallback_frames = 0
    for k, points in enumerate(frames):
        try:
            result = filt(points)
            acc.add(points, result.remove, result.elapsed_s)
        except CloudFieldError as exc:
            raise CloudFieldError(f"frame {k}: {exc}") from None
        fallback_frames += isinstance(filt, FallbackFilter) and filt.last_used == filt.fallback.name
    out = acc.result()
    if fallback_frames:
        out["fallback"] = {"method": filt.fallback.name, "frames": fallback_frames}
    return out


def evaluate_bag(bag: str, method: str, topic: str | None, fallback: str = "dror", **filter_params) -> dict:
    """Clouds lacking the fields of ``method`` are filtered by the geometry-only ``fallback`` (warning, and a
    ``fallback`` entry in the result naming it and how many frames it filtered)."""
    from lidar_weather_sim.io.bags import read_clouds
    from weather_filter.filter_methods import make_filter_with_fallback

    filt = make_filter_with_fallback(method, fallback, **filter_params)
    try:
        return evaluate_frames(filt, (frame.points for frame in read_clouds(bag, topic)), method)
    except CloudFieldError as exc:
        raise CloudFieldError(f"{bag}: {exc}") from None
