"""Scores of the obstacle classifier on labelled detections."""

from __future__ import annotations

import numpy as np


def obstacle_scores(truth: np.ndarray, pred: np.ndarray) -> dict:
    """Precision, recall, F1 of the obstacle ("box") class and F1 of the rest ("no box"), fractions;
    a zero denominator counts as 1.0 (nothing to get wrong)."""
    truth, pred = np.asarray(truth, bool), np.asarray(pred, bool)
    tp, fp, fn = int((truth & pred).sum()), int((~truth & pred).sum()), int((truth & ~pred).sum())
    tn = int((~truth & ~pred).sum())

    def f1(tp, fp, fn):
        return 2 * tp / (2 * tp + fp + fn) if (2 * tp + fp + fn) else 1.0

    return {"obstacle_precision": tp / (tp + fp) if tp + fp else 1.0, "obstacle_recall": tp / (tp + fn) if tp + fn else 1.0,
            "obstacle_f1": f1(tp, fp, fn), "no_obstacle_f1": f1(tn, fn, fp), "obstacle_points": tp + fn,
            "other_points": tn + fp}  # fmt: skip
