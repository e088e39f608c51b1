"""Per-frame weather classification (clear / rain / fog / snow) with KNN, as in paper 2.

The 12 per-frame features of paper 2 (Fig. 4) come from the shared extractor
``lidar_weather_sim.features`` (issue 4, atmosphere region); it is imported
lazily so this module loads without it. Until it lands,
:func:`frame_feature_extractor` raises ``ImportError`` and the node publishes
no weather class. The classifier is a scikit-learn KNN (paper: KNN) whose
confidence is the share of the k neighbours voting for the chosen class.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable, Iterable

import numpy as np

CLASSES = ("clear", "rain", "fog", "snow")


def frame_feature_extractor() -> Callable[[np.ndarray], np.ndarray]:
    """The shared 12-parameter extractor (``lidar_weather_sim.features.frame_features``)."""
    from lidar_weather_sim.features import frame_features  # noqa: PLC0415 (owned by the atmosphere issue)

    return frame_features


@dataclass(frozen=True)
class WeatherEstimate:
    weather: str
    confidence: float


class FrameWeatherClassifier:
    """KNN over per-frame feature vectors (standardised)."""

    def __init__(self, model, extractor: Callable[[np.ndarray], np.ndarray] | None = None) -> None:
        self.model = model
        self._extractor = extractor

    @classmethod
    def fit(cls, features: np.ndarray, labels: Iterable[str], k: int = 5,
            extractor: Callable[[np.ndarray], np.ndarray] | None = None) -> "FrameWeatherClassifier":  # fmt: skip
        from sklearn.neighbors import KNeighborsClassifier
        from sklearn.pipeline import make_pipeline
        from sklearn.preprocessing import StandardScaler

        labels = list(labels)
        unknown = set(labels) - set(CLASSES)
        if unknown:
            raise ValueError(f"unknown weather class(es) {sorted(unknown)}; use {CLASSES}")
        model = make_pipeline(StandardScaler(), KNeighborsClassifier(n_neighbors=min(k, len(labels))))
        model.fit(np.asarray(features, float), labels)
        return cls(model, extractor)

    def classify_features(self, feature_vector: np.ndarray) -> WeatherEstimate:
        proba = self.model.predict_proba(np.asarray(feature_vector, float).reshape(1, -1))[0]
        best = int(np.argmax(proba))
        return WeatherEstimate(str(self.model.classes_[best]), float(proba[best]))

    def classify(self, points: np.ndarray) -> WeatherEstimate:
        extractor = self._extractor or frame_feature_extractor()
        return self.classify_features(extractor(points))
