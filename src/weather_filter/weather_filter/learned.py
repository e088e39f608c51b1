"""Learned per-point weather filter: paper-4 features (:mod:`weather_filter.features`) and a
scikit-learn MLP with one hidden layer of 10 units, as in the paper.

The shipped model is ``models/weather_point_mlp_v<N>.joblib`` (a dict: ``model``,
``feature_names``, ``threshold``, ``sklearn_version``, ``trained_on``,
``command``). Reproduce it with the ``command`` stored in it
(``weather-filter train ...``); scikit-learn is pinned in requirements.txt,
so the pickle loads with the version that wrote it.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Iterable

import numpy as np

from lidar_weather_sim.points import SOLID_LABELS, WEATHER_LABELS

from weather_filter.features import FEATURE_NAMES, REQUIRED_FIELDS, PointFeatures
from weather_filter.filters import PointFilter

MODEL_VERSION = 1
MODELS_DIR = Path(__file__).resolve().parent / "models"
DEFAULT_MODEL = MODELS_DIR / f"weather_point_mlp_v{MODEL_VERSION}.joblib"


class LearnedFilter(PointFilter):
    """Removes points whose predicted weather probability is at least the model's threshold."""

    name = "learned"
    required_fields = REQUIRED_FIELDS

    def __init__(self, bundle: dict, threshold: float | None = None) -> None:
        if tuple(bundle["feature_names"]) != FEATURE_NAMES:
            raise ValueError("model features differ from weather_filter.features.FEATURE_NAMES: retrain it")
        self.bundle = bundle
        self.model = bundle["model"]
        self.threshold = float(bundle.get("threshold", 0.5) if threshold is None else threshold)
        self.features = PointFeatures(**bundle.get("feature_params", {}))

    @classmethod
    def load(cls, model_path: str | Path | None = None, threshold: float | None = None) -> "LearnedFilter":
        import joblib

        path = Path(model_path) if model_path else DEFAULT_MODEL
        if not path.exists():
            raise FileNotFoundError(f"model file not found: {path} (train one with 'weather-filter train')")
        return cls(joblib.load(path), threshold)

    def reset(self) -> None:
        self.features.reset()

    def remove_mask(self, points: np.ndarray) -> np.ndarray:
        proba = self.model.predict_proba(self.features(points))[:, 1]
        return proba >= self.threshold


@dataclass(frozen=True)
class TrainingReport:
    frames: int
    points: int
    weather_points: int
    train_precision: float
    train_recall: float
    output: Path


def training_set(frames: Iterable[np.ndarray], max_points_per_frame: int = 20000, seed: int = 0):
    """(X, y) from labelled frames: weather labels 10-15 -> 1, solid 1-3 -> 0, others skipped.
    Keeps all weather points and subsamples the rest to ``max_points_per_frame`` per frame."""
    rng = np.random.default_rng(seed)
    xs, ys, n_frames = [], [], 0
    for points in frames:
        extractor = PointFeatures()  # each frame stands alone (no frame-difference leak between files)
        feats = extractor(points)
        label = points["label"]
        weather = np.isin(label, list(WEATHER_LABELS))
        solid = np.isin(label, list(SOLID_LABELS))
        keep = np.flatnonzero(solid)
        if len(keep) > max_points_per_frame:
            keep = rng.choice(keep, max_points_per_frame, replace=False)
        idx = np.concatenate([np.flatnonzero(weather), keep])
        xs.append(feats[idx])
        ys.append(weather[idx].astype(np.int8))
        n_frames += 1
    if not xs:
        raise ValueError("no labelled frames to train on")
    return np.concatenate(xs), np.concatenate(ys), n_frames


def train(frames: Iterable[np.ndarray], output: str | Path, *, trained_on: str, command: str,
          threshold: float = 0.5, seed: int = 0) -> TrainingReport:  # fmt: skip
    """Fit StandardScaler + MLP(10) on labelled frames and write the model bundle to ``output``."""
    import joblib
    import sklearn
    from sklearn.neural_network import MLPClassifier
    from sklearn.pipeline import make_pipeline
    from sklearn.preprocessing import StandardScaler

    x, y, n_frames = training_set(frames, seed=seed)
    if y.min() == y.max():
        raise ValueError("training data holds only one class (need both weather and solid points)")
    model = make_pipeline(
        StandardScaler(),
        MLPClassifier(hidden_layer_sizes=(10,), max_iter=300, early_stopping=True, random_state=seed),
    )
    model.fit(x, y)
    pred = model.predict_proba(x)[:, 1] >= threshold
    tp = int((pred & (y == 1)).sum())
    output = Path(output)
    output.parent.mkdir(parents=True, exist_ok=True)
    bundle = {
        "model": model,
        "feature_names": FEATURE_NAMES,
        "feature_params": {},
        "threshold": threshold,
        "sklearn_version": sklearn.__version__,
        "version": MODEL_VERSION,
        "trained_on": trained_on,
        "command": command,
    }
    joblib.dump(bundle, output, compress=3)
    return TrainingReport(n_frames, len(y), int(y.sum()), tp / max(int(pred.sum()), 1), tp / max(int(y.sum()), 1), output)
