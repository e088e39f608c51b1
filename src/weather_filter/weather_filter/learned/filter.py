"""Learned per-point weather filter: paper-4 features plus range-image and cell-height features
(:mod:`weather_filter.learned.features`) and a scikit-learn MLP with one hidden layer (the paper: 10 units; the
shipped model: 16, which keeps more of the spray at the same object recall on held-out runs).

The shipped model is ``models/weather_point_mlp_v<N>.joblib`` (a dict: ``model``,
``feature_names``, ``threshold``, ``sklearn_version``, ``trained_on``,
``command``, ``version``), written by :func:`weather_filter.learned.training.train`.

Inference does not call scikit-learn: :class:`weather_filter.learned.fast_mlp.FastMLP`.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from weather_filter.learned.fast_mlp import FastMLP
from weather_filter.learned.features import FEATURE_NAMES, REQUIRED_FIELDS, PointFeatures
from weather_filter.learned.single_return import (
    MAX_RANGE_M,
    RANGE_COLUMN,
    SINGLE_RETURN_FEATURE_NAMES,
    SingleReturnFeatures,
)
from weather_filter.learned.single_return import REQUIRED_FIELDS as SINGLE_RETURN_FIELDS
from weather_filter.points.base import PointFilter

MODEL_VERSION = 4
MODELS_DIR = Path(__file__).resolve().parents[1] / "models"
DEFAULT_MODEL = MODELS_DIR / f"weather_point_mlp_v{MODEL_VERSION}.joblib"
#: The single-return model (clouds without EPW or later echoes): its own version, changed with its features.
SINGLE_RETURN_MODEL_VERSION = 1
SINGLE_RETURN_MODEL = MODELS_DIR / f"weather_point_mlp_single_v{SINGLE_RETURN_MODEL_VERSION}.joblib"
#: Fields whose presence selects the EPW model (:class:`LearnedByFields`).
EPW_MODEL_FIELDS = frozenset({"epw", "echo"})


def _logit_threshold(p: float) -> float:
    p = min(max(p, 1e-7), 1 - 1e-7)
    return float(np.log(p / (1 - p)))


class LearnedFilter(PointFilter):
    """Removes points whose predicted weather probability is at least the model's threshold (the EPW model:
    echo, EPW, intensity and neighbourhood features)."""

    name = "learned"
    required_fields = REQUIRED_FIELDS
    feature_names = FEATURE_NAMES
    extractor = PointFeatures
    default_model = None  # DEFAULT_MODEL, set below

    def __init__(self, bundle: dict, threshold: float | None = None) -> None:
        if tuple(bundle["feature_names"]) != self.feature_names:
            raise ValueError(f"model features differ from those of {type(self).__name__} "
                             f"({self.extractor.__module__}): retrain it")  # fmt: skip
        self.bundle = bundle
        self.model = bundle["model"]
        self.threshold = float(bundle.get("threshold", 0.5) if threshold is None else threshold)
        self.features = self.extractor(**bundle.get("feature_params", {}))
        self._fast = FastMLP(self.model)
        self._logit_threshold = _logit_threshold(self.threshold)
        self._warm_up()

    def _warm_up(self) -> None:
        """Compile the numba feature passes and the network now, not on the first frame: a two-channel scan with
        second echoes takes every branch that compiles (the azimuth step needs >= 10 first echoes a channel)."""
        from lidar_weather_sim.core.points import empty_points

        n = 64
        pts = empty_points(n)
        azimuth = np.radians(0.5 * (np.arange(n) // 2))
        pts["x"], pts["y"] = 10.0 * np.cos(azimuth), 10.0 * np.sin(azimuth)
        pts["channel"] = np.arange(n) % 2
        pts["echo"] = np.where(np.arange(n) % 8 == 7, 2, 1)
        pts["epw"] = 1.0
        self.features(pts)
        self._fast.logit(self.features(pts))  # the pass that carries the previous frame's radial histogram
        self.features.reset()

    @classmethod
    def load(cls, model_path: str | Path | None = None, threshold: float | None = None) -> "LearnedFilter":
        import joblib

        path = Path(model_path) if model_path else cls.default_model
        if not path.exists():
            raise FileNotFoundError(f"model file not found: {path} (train one with 'weather-filter train')")
        if threshold is not None and (isinstance(threshold, bool) or not isinstance(threshold, (int, float))
                                      or not 0.0 < threshold < 1.0):  # fmt: skip
            raise ValueError(f"filter 'learned': threshold must be a probability between 0 and 1, got {threshold!r}")
        try:
            bundle = joblib.load(path)
        except Exception as exc:  # joblib/pickle raise many types for a file that is not a model
            raise ValueError(f"{path}: not a weather-filter model ({type(exc).__name__}: {exc})") from None
        if not isinstance(bundle, dict) or not {"model", "feature_names"} <= set(bundle):
            raise ValueError(f"{path}: not a weather-filter model (no 'model' and 'feature_names' entries)")
        if cls is LearnedFilter and tuple(bundle["feature_names"]) == SINGLE_RETURN_FEATURE_NAMES:
            return SingleReturnLearnedFilter(bundle, threshold)  # a model file names its own kind
        return cls(bundle, threshold)

    def reset(self) -> None:
        self.features.reset()

    def weather_probability(self, points: np.ndarray) -> np.ndarray:
        return 1.0 / (1.0 + np.exp(-self._fast.logit(self.features(points)).astype(np.float64)))

    def remove_mask(self, points: np.ndarray) -> np.ndarray:
        return self._fast.logit(self.features(points)) >= self._logit_threshold


LearnedFilter.default_model = DEFAULT_MODEL


class SingleReturnLearnedFilter(LearnedFilter):
    """The learned filter for clouds without EPW or later echoes (:mod:`weather_filter.learned.single_return`):
    x, y, z, intensity (only relative to the frame and the neighbours: any driver's scale) and channel."""

    name = "learned-single"
    required_fields = SINGLE_RETURN_FIELDS
    feature_names = SINGLE_RETURN_FEATURE_NAMES
    extractor = SingleReturnFeatures
    default_model = SINGLE_RETURN_MODEL

    def __init__(self, bundle: dict, threshold: float | None = None) -> None:
        super().__init__(bundle, threshold)
        #: nothing beyond this horizontal range (m) is removed (:data:`single_return.MAX_RANGE_M`)
        self.max_range_m = np.float32(bundle.get("max_range_m", MAX_RANGE_M))

    def weather_probability(self, points: np.ndarray) -> np.ndarray:
        feats = self.features(points)
        proba = 1.0 / (1.0 + np.exp(-self._fast.logit(feats).astype(np.float64)))
        return np.where(feats[:, RANGE_COLUMN] < self.max_range_m, proba, 0.0)

    def remove_mask(self, points: np.ndarray) -> np.ndarray:
        feats = self.features(points)
        return (self._fast.logit(feats) >= self._logit_threshold) & (feats[:, RANGE_COLUMN] < self.max_range_m)


class LearnedByFields(PointFilter):
    """The learned filter chosen by the cloud's fields: the EPW model (:class:`LearnedFilter`) where the cloud has
    ``epw`` and ``echo``, else the single-return one (:class:`SingleReturnLearnedFilter`), which needs x, y, z,
    intensity and channel (a cloud lacking those goes to the geometry-only fallback of
    ``filter_methods``). ``last_used`` names the model that ran on the latest cloud."""

    name = "learned"
    required_fields = SINGLE_RETURN_FIELDS

    def __init__(self, epw: LearnedFilter, single: SingleReturnLearnedFilter) -> None:
        self.epw, self.single = epw, single
        self.last_used = epw.name

    def missing_fields(self, points: np.ndarray) -> list[str]:
        """As :meth:`PointFilter.missing_fields`, and ``intensity`` for a cloud without EPW whose intensity is 0 at
        every point: the node's reader (``lidar_weather_sim.io.layouts.CloudReader``) writes 0 for a driver that
        gives none, and the single-return model reads the intensity (such a cloud goes to the geometry-only
        fallback)."""
        missing = super().missing_fields(points)
        if not missing and "epw" not in points.dtype.names and len(points) and not points["intensity"].any():
            missing = ["intensity"]
        return missing

    def choose(self, points: np.ndarray) -> LearnedFilter:
        return self.epw if EPW_MODEL_FIELDS <= set(points.dtype.names or ()) else self.single

    def fields_read(self, points: np.ndarray) -> frozenset[str]:
        return self.choose(points).required_fields

    def remove_mask(self, points: np.ndarray) -> np.ndarray:
        filt = self.choose(points)
        self.last_used = filt.name
        return filt.remove_mask(points)

    def weather_probability(self, points: np.ndarray) -> np.ndarray:
        return self.choose(points).weather_probability(points)

    def reset(self) -> None:
        self.epw.reset()
        self.single.reset()
