"""Paper 4's obstacle-vs-spray classifier (thesis lines 2770-2819): does a detection belong to a solid
obstacle (label 3, "box") or not (spray, rain, vehicles, road: "no box")? Detections outside the paper's feature
region (:func:`weather_filter.obstacle.features.feature_region_mask`) are never classified as obstacle.

The models (v1-v3: StandardScaler + MLP, run by :class:`weather_filter.learned.fast_mlp.FastMLP`; v4, the
default: gradient-boosted trees, run by :class:`weather_filter.obstacle.fast_trees.FastTrees`), their features,
runs and thresholds: ``models/obstacle_point_hgb_v4.md``.
"""

from __future__ import annotations

from pathlib import Path
from typing import Iterable

import numpy as np

from lidar_weather_sim.core.points import Label
from weather_filter.learned.fast_mlp import FastMLP
from weather_filter.obstacle.fast_trees import FastTrees
from weather_filter.obstacle.features import ObstacleFeatures, feature_region_mask
from weather_filter.obstacle.scores import obstacle_scores

MODELS_DIR = Path(__file__).resolve().parents[1] / "models"
#: The shipped model: v4 (gradient-boosted trees).
DEFAULT_OBSTACLE_MODEL = MODELS_DIR / "obstacle_point_hgb_v4.joblib"
#: The earlier models (MLPs), kept: load them with ``--obstacle-model`` / ``--model``.
OBSTACLE_MODEL_V3 = MODELS_DIR / "obstacle_point_mlp_v3.joblib"
OBSTACLE_MODEL_V2 = MODELS_DIR / "obstacle_point_mlp_v2.joblib"
OBSTACLE_MODEL_V1 = MODELS_DIR / "obstacle_point_mlp_v1.joblib"


class ObstacleClassifier:
    """The shipped (or a given) obstacle model; call :meth:`predict` frame after frame of one sequence."""

    def __init__(self, bundle: dict) -> None:
        self.features = ObstacleFeatures(tuple(bundle["feature_names"]))  # v1: PAPER_FEATURES; v2: V2_FEATURES
        trees = bundle.get("classifier", "mlp") == "trees"  # v1-v3: MLP pipelines; v4: trees
        model = bundle["model"]
        if (model if trees else model[0]).n_features_in_ != len(self.features.names):
            raise ValueError("obstacle model's input size differs from its feature_names")
        self.bundle = bundle
        self._trees = FastTrees(model) if trees else None
        self._fast = None if trees else FastMLP(model)
        self._logit_threshold = float(np.log(bundle["threshold"] / (1.0 - bundle["threshold"])))

    @classmethod
    def load(cls, path: str | Path | None = None) -> "ObstacleClassifier":
        import joblib

        path = Path(path) if path else DEFAULT_OBSTACLE_MODEL
        if not path.is_file():
            raise ValueError(f"obstacle model {path} not found")
        return cls(joblib.load(path))

    def reset(self) -> None:
        self.features.reset()

    def predict(self, points: np.ndarray) -> np.ndarray:
        """(N,) bool: the detection is an obstacle's (False outside the feature region)."""
        mask, x = self.features(points)
        out = np.zeros(len(points), bool)
        if len(x):
            if self._fast is not None:
                out[mask] = self._fast.logit(x) >= self._logit_threshold
            else:
                out[mask] = self._trees.above(x, self._logit_threshold)
        return out


def evaluate_obstacles(frames: Iterable[np.ndarray], model: str | Path | None = None) -> dict | None:
    """:func:`obstacle_scores` of the classifier over a sequence of labelled frames, in the feature region
    (micro-averaged over its detections), plus ``obstacle_model``; None when no frame has a label-3 point."""
    classifier = ObstacleClassifier.load(model)
    truth, pred, any_obstacle = [], [], False
    for points in frames:
        if "label" not in (points.dtype.names or ()):
            return None
        mask = feature_region_mask(points)
        is_obstacle = points["label"] == Label.OBSTACLE
        any_obstacle |= bool(is_obstacle.any())
        truth.append(is_obstacle[mask])
        pred.append(classifier.predict(points)[mask])
    if not any_obstacle:
        return None
    scores = obstacle_scores(np.concatenate(truth), np.concatenate(pred))
    return {**scores, "obstacle_model": str(Path(model) if model else DEFAULT_OBSTACLE_MODEL)}
