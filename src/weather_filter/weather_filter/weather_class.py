"""Per-frame weather classification (clear / rain / fog / snow) with KNN, as in paper 2.

The 12 per-frame features of paper 2 (Fig. 4) come from the shared extractor
``lidar_weather_sim.core.frame_parameters.frame_features``, applied to the detections of the
atmosphere region (horizontal distance x along the sensor's axis within
[0, 5) m, as the paper's region), and again to the region's isotropic part
(:class:`RegionFeatures`): 24 values per frame. Empty-region NaNs become fixed
values (distances: the region's far end; EPW: 0) so that a clear frame without
near detections is a point in feature space too. The classifier is a
scikit-learn KNN (paper: KNN) on standardised features whose confidence is the
share of the k neighbours voting for the chosen class. The counts enter as
log(1 + n) (:func:`log_counts`): between light and heavy weather they span an
order of magnitude, and in linear units one dense frame (spray mist, heavy dirt)
outweighs every other feature in the distance.

Scenarios never trained on, share of frames named right: v1 (the 12 parameters,
linear counts, three base scenarios) 0.58; v2 (log counts, heavy dirt and spray
mist in the runs) 0.86; v3 (with the isotropic part) 0.93
(``python benchmarks/validation/weather_filter_eval.py --knn-only``).

The shipped model ``models/weather_knn_v<N>.joblib`` is trained on labelled
simulation runs (:mod:`weather_filter.simdata`) whose class is the scenario's
weather (:func:`spec_weather_class`: rain or snow when it
precipitates, else fog below 1 km visual range, else clear; spray and cover dirt
do not change it); ``weather-filter train-weather --sim ...`` (the ``command``
stored in the model) reproduces it.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Callable, Iterable

import numpy as np

CLASSES = ("clear", "rain", "fog", "snow")
KNN_VERSION = 3
DEFAULT_KNN_MODEL = Path(__file__).resolve().parent / "models" / f"weather_knn_v{KNN_VERSION}.joblib"
#: Training runs of the shipped KNN (scala4, 20 frames each): five base scenarios (weather_filter/scenarios/wf_knn_*.yaml:
#: clean cover, light, medium and heavy dirt, the ego driving into spray mist) under a grid of each class'
#: intensity, and two dry scenarios without an atmosphere region; classes from the runs' weather. The nuisances
#: (dirt, spray) are there so that the class is learned across them: v1, without the heavy dirt and the spray
#: mist and with rain at 1 / 3 / 8 mm/h only, named fog and snow runs with heavier dirt rain and fog.
KNN_WEATHERS = ("clear", "rain1", "rain2", "rain3", "rain5", "rain8", "rain3+fog400", "snow0.5", "snow1", "snow2",
                "snow3", "snow1+fog500", "fog100", "fog250", "fog400", "fog700")  # fmt: skip
#: the runs per base: clear is one grid point against 4-6 of each other class, so it gets three seeds (with one,
#: the neighbourhood of a clear frame through dirt or spray is mostly fog)
KNN_WEATHER_RUNS = (*KNN_WEATHERS, "clear", "clear")
KNN_BASES = ("wf_knn_highway", "wf_knn_curved_dirt", "wf_knn_highway_dirt", "wf_knn_highway_heavy_dirt",
             "wf_knn_spray_mist")  # fmt: skip
KNN_TRAIN_SPECS = (*(f"{s}:{31 + i}:20::{w}" for s in KNN_BASES for i, w in enumerate(KNN_WEATHER_RUNS)),
                   "curved_clear:31:20", "proving_ground_48:31:20")  # fmt: skip
#: Unseen seeds of the training scenarios, and scenarios never trained on (benchmarks/validation/weather_filter_eval.py).
KNN_TEST_SEEDS_SPECS = (*(f"{s}:{61 + i}:10::{w}" for s in KNN_BASES for i, w in enumerate(KNN_WEATHER_RUNS)),
                        "curved_clear:61:10", "proving_ground_48:61:10")  # fmt: skip
KNN_TEST_SCENARIO_SPECS = ("highway_spray:100:40", "proving_ground_60:100:40", "wf_heldout_mixed:100:40",
                           "wf_train_rain_spray:1:40", "wf_train_fog:1:40", "wf_train_snow:1:40",
                           "wf_train_clear_spray:1:40", "wf_train_fog_rain:1:40", "highway_clear:41:20")  # fmt: skip


#: the count features that :func:`log_counts` compresses
COUNT_FEATURES = ("n_peak", "n_total", "n_dd", "n_e1", "n_e2", "n_e3")


def _count_columns(width: int) -> list[int]:
    """Columns of the count features in feature vectors of ``width`` (12 or 24 values, FEATURES order)."""
    from lidar_weather_sim.core.frame_parameters import FEATURES

    return [FEATURES.index(name) + offset for offset in range(0, width, len(FEATURES)) for name in COUNT_FEATURES]


def log_counts(features: np.ndarray) -> np.ndarray:
    """Feature vectors (n, 12 or 24; :class:`RegionFeatures`) with the counts as log(1 + n): the classifier's
    first stage."""
    out = np.array(features, float, copy=True)
    columns = _count_columns(out.shape[1])
    out[:, columns] = np.log1p(out[:, columns])
    return out


def frame_feature_extractor() -> Callable[[np.ndarray], np.ndarray]:
    """The shared extractor on the atmosphere region of a cloud (:class:`RegionFeatures`)."""
    return RegionFeatures()


class RegionFeatures:
    """points -> 24 values, NaN-free: the 12 paper-2 parameters (``lidar_weather_sim.core.frame_parameters.FEATURES`` order)
    of the detections with lo_m <= x < hi_m (x: horizontal distance along the sensor axis, sensor frame), then
    the same 12 of the region's isotropic part.

    The isotropic part: weather's near-field detections are spread over the whole field of view (thesis line
    742), whereas spray from a car ahead, a guard rail beside the ego or a dirt patch on the cover crowd a few
    directions. The frame's azimuth span (that of all its points) is cut into ``sectors`` equal sectors; a
    sector whose count of region detections exceeds the median sector's by more than 3 Poisson sigma (+ 3) is
    left out, and the counts of the others are scaled up to the whole span.
    """

    def __init__(self, lo_m: float = 0.0, hi_m: float = 5.0, sectors: int = 8) -> None:
        self.lo_m, self.hi_m, self.sectors = float(lo_m), float(hi_m), int(sectors)

    def __call__(self, points: np.ndarray) -> np.ndarray:
        x = points["x"]
        region = np.flatnonzero((x >= self.lo_m) & (x < self.hi_m))
        isotropic, scale = self._isotropic_part(points, region)
        iso = self._parameters(points, isotropic)
        columns = _count_columns(len(iso))
        iso[columns] *= scale
        return np.concatenate([self._parameters(points, region), iso])

    def _isotropic_part(self, points: np.ndarray, region: np.ndarray) -> tuple[np.ndarray, float]:
        """(indices of the region detections in the sectors without excess, whole span / their span)."""
        azimuth = np.arctan2(points["y"], points["x"])
        span = float(np.ptp(azimuth)) if len(azimuth) else 0.0
        if len(region) == 0 or span <= 0.0:
            return region, 1.0
        sector = np.minimum(((azimuth[region] - azimuth.min()) / span * self.sectors).astype(int), self.sectors - 1)
        counts = np.bincount(sector, minlength=self.sectors)
        median = float(np.median(counts))
        kept = counts <= median + 3.0 * np.sqrt(median) + 3.0
        return region[kept[sector]], self.sectors / int(kept.sum())

    def _parameters(self, points: np.ndarray, index: np.ndarray) -> np.ndarray:
        from lidar_weather_sim.core.frame_parameters import FEATURES, frame_features

        values = frame_features(points["x"][index], points["echo"][index], points["epw"][index], self.lo_m, self.hi_m)
        fill = {"x_max": self.hi_m, "x_mean": self.hi_m, "x_sigma": 0.0, "x_90": self.hi_m, "n_dd": 0.0,
                "epw_mean": 0.0, "epw_std": 0.0}  # fmt: skip
        return np.array([fill.get(k, 0.0) if not np.isfinite(values[k]) else values[k] for k in FEATURES], float)


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
        from sklearn.preprocessing import FunctionTransformer, StandardScaler

        labels = list(labels)
        unknown = set(labels) - set(CLASSES)
        if unknown:
            raise ValueError(f"unknown weather class(es) {sorted(unknown)}; use {CLASSES}")
        model = make_pipeline(FunctionTransformer(log_counts), StandardScaler(),
                              KNeighborsClassifier(n_neighbors=min(k, len(labels))))  # fmt: skip
        model.fit(np.asarray(features, float), labels)
        return cls(model, extractor)

    def classify_features(self, feature_vector: np.ndarray) -> WeatherEstimate:
        proba = self.model.predict_proba(np.asarray(feature_vector, float).reshape(1, -1))[0]
        best = int(np.argmax(proba))
        return WeatherEstimate(str(self.model.classes_[best]), float(proba[best]))

    def classify(self, points: np.ndarray) -> WeatherEstimate:
        extractor = self._extractor or frame_feature_extractor()
        return self.classify_features(extractor(points))

    @classmethod
    def load(cls, path: str | Path | None = None) -> "FrameWeatherClassifier":
        import joblib

        path = Path(path) if path else DEFAULT_KNN_MODEL
        if not path.exists():
            raise FileNotFoundError(f"weather classifier not found: {path} (train one with 'weather-filter train-weather')")
        bundle = joblib.load(path)
        return cls(bundle["model"], RegionFeatures(**bundle.get("region", {})))


#: Fog: visibility below 1 km (WMO).
FOG_VISUAL_RANGE_LIMIT_M = 1000.0


def spec_weather_class(spec) -> str:
    """The weather class of a run's weather block: its precipitation (rain, snow), else fog below
    :data:`FOG_VISUAL_RANGE_LIMIT_M` of visual range, else clear."""
    weather = spec.load_scenario().weather
    if weather.precipitation.type in ("rain", "snow"):
        return weather.precipitation.type
    return "fog" if weather.fog.visual_range_m < FOG_VISUAL_RANGE_LIMIT_M else "clear"


def run_features(specs: Iterable[str], cache_dir=None, topic: str | None = None, extractor=None):
    """(features (n, 12), labels, spec per frame) of simulated runs, labelled by their scenario's weather."""
    from lidar_weather_sim.core.names import TOPIC_POINTS
    from weather_filter.simdata import SimSpec, frames_of, simulate

    extractor = extractor or RegionFeatures()
    xs, ys, names = [], [], []
    for spec in map(SimSpec.parse, specs):
        label = spec_weather_class(spec)
        for points in frames_of(simulate(spec, cache_dir), topic or TOPIC_POINTS):
            xs.append(extractor(points))
            ys.append(label)
            names.append(str(spec))
    return np.array(xs), ys, names


@dataclass(frozen=True)
class KnnReport:
    frames: int
    per_class: dict
    output: Path


def train_knn(specs: Iterable[str], output: str | Path, *, command: str, k: int = 5, cache_dir=None,
              topic: str | None = None) -> KnnReport:  # fmt: skip
    """Fit :class:`FrameWeatherClassifier` on simulated runs and write ``{model, region, classes, ...}``."""
    import joblib
    import sklearn

    specs = list(specs)
    region = RegionFeatures()
    x, y, _ = run_features(specs, cache_dir, topic, region)
    clf = FrameWeatherClassifier.fit(x, y, k=k)
    output = Path(output)
    output.parent.mkdir(parents=True, exist_ok=True)
    bundle = {"model": clf.model, "region": {"lo_m": region.lo_m, "hi_m": region.hi_m, "sectors": region.sectors},
              "classes": CLASSES, "k": k, "sklearn_version": sklearn.__version__, "version": KNN_VERSION,
              "trained_on": ", ".join(f"sim:{s}" for s in specs), "command": command}  # fmt: skip
    joblib.dump(bundle, output, compress=3)
    labels, counts = np.unique(y, return_counts=True)
    return KnnReport(len(y), dict(zip(labels.tolist(), counts.tolist())), output)
