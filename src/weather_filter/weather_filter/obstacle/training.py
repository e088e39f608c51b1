"""Training of the obstacle classifier on labelled frame sequences (``weather-filter train --preset
augmentation[-v2|-v3|-v4|-wide]``; runs: :mod:`weather_filter.obstacle.runs`). Defaults: the paper's (its 15
features, its hidden units and class weights, threshold 0.5: the v1 model); the later models' choices and why:
``models/obstacle_point_hgb_v4.md``."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Iterable

import numpy as np

from lidar_weather_sim.augment.boxes import augmentation_table
from lidar_weather_sim.core.points import Label
from weather_filter.obstacle.features import PAPER_FEATURES, ObstacleFeatures
from weather_filter.obstacle.scores import obstacle_scores

#: The v2 and v3 models' hidden layer (the paper's 10 units underfit their runs).
V2_HIDDEN = (32,)
#: The v4 model's classifier: scikit-learn's HistGradientBoostingClassifier with these settings (not tuned), the
#: paper's class weights as sample weights.
V4_TREES = {"max_iter": 300, "learning_rate": 0.1, "max_leaf_nodes": 63}


def class_weights() -> tuple[float, float]:
    """(no box, box) error weights of the paper."""
    c = augmentation_table()["classifier"]
    return float(c["weight_no_box"]), float(c["weight_box"])


def training_arrays(sequences: Iterable[Iterable[np.ndarray]],
                    names: tuple[str, ...] = PAPER_FEATURES) -> tuple[np.ndarray, np.ndarray, int]:
    """(X, y, frames) of labelled frame sequences; y = 1 for label 3 (obstacle), 0 else; region only."""
    xs, ys, frames = [], [], 0
    for sequence in sequences:
        features = ObstacleFeatures(names)
        for points in sequence:
            mask, x = features(points)
            xs.append(x)
            ys.append((points["label"][mask] == Label.OBSTACLE).astype(np.int8))
            frames += 1
    if not xs:
        raise ValueError("no labelled frames to train on")
    return np.concatenate(xs), np.concatenate(ys), frames


@dataclass(frozen=True)
class ObstacleTrainingReport:
    frames: int
    points: int
    box_points: int
    scores: dict
    output: Path
    threshold: float = 0.5
    validation_scores: dict | None = None


def best_threshold(truth: np.ndarray, probability: np.ndarray) -> tuple[float, dict]:
    """The probability threshold (grid 0.05, 0.06, ..., 0.95) of the best box F-score on labelled points, ties
    to the one nearest 0.5; (threshold, :func:`obstacle_scores` at it)."""
    grid = np.round(np.arange(5, 96) / 100.0, 2)
    f = [obstacle_scores(truth, probability >= t)["obstacle_f1"] for t in grid]
    best = max(range(len(grid)), key=lambda i: (round(f[i], 12), -abs(grid[i] - 0.5)))
    return float(grid[best]), obstacle_scores(truth, probability >= grid[best])


def train_obstacle(sequences, output: str | Path, *, trained_on: str, command: str, seed: int = 0,
                   validation=None, validated_on: str = "", version: int = 1, features: tuple[str, ...] = PAPER_FEATURES,
                   hidden: tuple[int, ...] | None = None, classifier: str = "mlp") -> ObstacleTrainingReport:  # fmt: skip
    """Fit the classifier on labelled frame sequences and write the model bundle to ``output``.

    Defaults: the paper's (its 15 features, its hidden units, threshold 0.5: the v1 model). With ``validation``
    (labelled frame sequences of other runs than the fit's) the threshold is the one of the best box F-score on
    those (:func:`best_threshold`); ``features`` / ``hidden`` other than the paper's (the v2 model);
    ``classifier`` ``"trees"``: gradient-boosted trees (:data:`V4_TREES`, the v4 model) instead of the MLP."""
    import joblib
    import sklearn

    if classifier not in ("mlp", "trees"):
        raise ValueError(f"classifier {classifier!r}: mlp or trees")
    x, y, frames = training_arrays(sequences, features)
    if y.min() == y.max():
        raise ValueError("training data holds only one class (need obstacle and other points)")
    hidden = tuple(hidden) if hidden else (int(augmentation_table()["classifier"]["hidden_units"]),)
    w_nb, w_b = class_weights()
    weight = np.where(y == 1, w_b, w_nb)
    if classifier == "trees":
        from sklearn.ensemble import HistGradientBoostingClassifier

        model = HistGradientBoostingClassifier(**V4_TREES, early_stopping=False, random_state=seed)
        model.fit(x, y, sample_weight=weight)
        hidden = ()
    else:
        from sklearn.neural_network import MLPClassifier
        from sklearn.pipeline import make_pipeline
        from sklearn.preprocessing import StandardScaler

        model = make_pipeline(StandardScaler(), MLPClassifier(hidden_layer_sizes=hidden, max_iter=500,
                                                              early_stopping=True, random_state=seed))  # fmt: skip
        model.fit(x, y, mlpclassifier__sample_weight=weight)
    threshold, extra = 0.5, {}
    if validation is not None:
        xv, yv, frames_v = training_arrays(validation, features)
        threshold, val_scores = best_threshold(yv.astype(bool), model.predict_proba(xv)[:, 1])
        extra = {"threshold_chosen_on": validated_on, "validation_frames": frames_v, "validation_scores": val_scores,
                 "validation_scores_at_0.5": obstacle_scores(yv.astype(bool), model.predict_proba(xv)[:, 1] >= 0.5)}  # fmt: skip
    scores = obstacle_scores(y.astype(bool), model.predict_proba(x)[:, 1] >= threshold)
    output = Path(output)
    output.parent.mkdir(parents=True, exist_ok=True)
    joblib.dump({"model": model, "classifier": classifier, "feature_names": tuple(features), "threshold": threshold,
                 "hidden": list(hidden),
                 "class_weights": {"no_box": w_nb, "box": w_b}, "sklearn_version": sklearn.__version__,
                 "trained_on": trained_on, "command": command, "version": version, **extra}, output, compress=3)  # fmt: skip
    return ObstacleTrainingReport(frames, len(y), int(y.sum()), scores, output, threshold, extra.get("validation_scores"))
