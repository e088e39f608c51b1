"""Paper 4's obstacle-vs-spray classifier (thesis lines 2770-2819): does a detection belong to a solid
obstacle (label 3, "box") or not (spray, rain, vehicles, road: "no box")?

Features: the paper's 15 per-detection parameters (:data:`PAPER_FEATURES`: x, y, echo, layer, EPW, the
counts of the detection's cell in the radial 1 deg, 10x10 cm, 20 cm x 2 m, 4 m x 10 cm and 50x50 cm
bird's-eye histograms, the radial count's change from the previous frame, and the 10 cm histogram
convolved with the horizontal, corner, rotated corner and impulse matrices), computed by the learned
weather filter's extractor (:class:`weather_filter.features.PointFeatures`) on the detections of the
paper's feature region only (``feature_region_m``: x 0-20 m, |y| <= 6 m, sensor frame); detections
outside it are never classified as obstacle. Classifier: StandardScaler + MLP fitted with the paper's class
weights (``weight_no_box``, ``weight_box``). Every paper value is read from ``thesis_tables.yaml``
(``augmentation``). The paper trained with scaled conjugate gradient; scikit-learn has none, so Adam (its
default) is used.

Four models: v1 (``models/obstacle_point_mlp_v1.joblib``) is the paper's: its 15 features,
``classifier.hidden_units`` hidden units, "box" at probability >= 0.5. v2 (``models/obstacle_point_mlp_v2.joblib``)
DEVIATES from the paper, each choice made on a validation split of training scenarios
(:data:`AUGMENT_VALIDATION_RUNS_V2`, :data:`SIM_BOXES_VALIDATION_V2`), never on a held-out list: all extractor
columns (:data:`V2_FEATURES`), :data:`V2_HIDDEN` hidden units, and the threshold of the best box F-score on the
validation data (:func:`best_threshold`), stored in the model. v3 (``models/obstacle_point_mlp_v3.joblib``) is v2
plus training runs with the car ahead in the ego lane (paper 4's Fig. 9d weak spot, where v2 took the car's rear for
a box) and the extents of each detection's bird's-eye cluster (:data:`V3_FEATURES`), chosen on validation runs of its
training scenarios. v4 (the default, ``models/obstacle_point_hgb_v4.joblib``) is v3's data with the occupancy
history of each detection's cell (:data:`V4_FEATURES`; the car ahead holds its place, an obstacle does not) and
gradient-boosted trees instead of the MLP (:data:`V4_TREES`), its threshold chosen on validation runs that include
the spent held-out lists (:data:`AUGMENT_VALIDATION_RUNS_V4`).

Training data (``weather-filter train --preset augmentation`` / ``augmentation-v2``): simulated spray runs
augmented with ``lidar-weather-sim augment``'s boxes (v2: also boxes raycast by the simulator), the lists
below each fixed before its model's first training.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Iterable

import numpy as np

from lidar_weather_sim.core.points import Label
from lidar_weather_sim.augment.boxes import augmentation_table
from weather_filter.features import FEATURE_NAMES, PointFeatures
from weather_filter.obstacle_clusters import CLUSTER_FEATURES, cluster_extents
from weather_filter.obstacle_history import HISTORY_FEATURES, CellHistory

MODELS_DIR = Path(__file__).resolve().parent / "models"
#: The shipped model: v4 (gradient-boosted trees on V4_FEATURES, trained on AUGMENT_TRAIN_RUNS_V4, threshold chosen
#: on AUGMENT_VALIDATION_RUNS_V4).
DEFAULT_OBSTACLE_MODEL = MODELS_DIR / "obstacle_point_hgb_v4.joblib"
#: The third model (MLP, AUGMENT_TRAIN_RUNS_V3), kept: load it with ``--obstacle-model`` / ``--model``.
OBSTACLE_MODEL_V3 = MODELS_DIR / "obstacle_point_mlp_v3.joblib"
#: The second model (AUGMENT_TRAIN_RUNS_V2), kept: load it with ``--obstacle-model`` / ``--model``.
OBSTACLE_MODEL_V2 = MODELS_DIR / "obstacle_point_mlp_v2.joblib"
#: The first model (AUGMENT_TRAIN_RUNS, threshold 0.5), kept: load it with ``--obstacle-model`` / ``--model``.
OBSTACLE_MODEL_V1 = MODELS_DIR / "obstacle_point_mlp_v1.joblib"
PAPER_FEATURES = ("x", "y", "echo", "channel", "epw", "n_radial", "n_small", "n_rear", "n_side", "n_middle",
                  "d_radial", "conv_horizontal", "conv_corner", "conv_corner_rot90", "conv_impulse")  # fmt: skip
#: The v2 model's features (a deviation from the paper, chosen on AUGMENT_VALIDATION_RUNS_V2): every column of the
#: learned filter's extractor - the paper's 15 plus z, intensity, range, the range-image features ``ri_*`` and the
#: heights in the 50 cm cell ``dz_min`` / ``dz_max`` (weather_filter.features).
V2_FEATURES = tuple(FEATURE_NAMES)
#: The v2 model's hidden layer (a deviation: the paper's 10 units underfit the v2 runs, train box F 0.80).
V2_HIDDEN = (32,)
#: The v3 model's features: v2's plus the extents of each detection's bird's-eye cluster
#: (weather_filter.obstacle_clusters), aimed at the car ahead's rear that v2 takes for a box; its hidden layer: v2's.
V3_FEATURES = V2_FEATURES + CLUSTER_FEATURES
#: The v4 model's features: v3's plus the occupancy history of each detection's cell
#: (weather_filter.obstacle_history), aimed at the car ahead's rear, which holds its place frame after frame.
V4_FEATURES = V3_FEATURES + HISTORY_FEATURES
#: The v4 model's classifier (a deviation: gradient-boosted trees, scikit-learn's HistGradientBoostingClassifier,
#: with the paper's class weights as sample weights). Chosen on the v4 validation data over v3's MLP (32 units) on the
#: same features: box F 0.987 against 0.963, no-box F 0.9995 against 0.9984 (AUGMENT_TEST_RUNS_V3). Not tuned.
V4_TREES = {"max_iter": 300, "learning_rate": 0.1, "max_leaf_nodes": 63}

#: Training runs: ``SCENARIO:SEED:FRAMES[:PROFILE]@AUGMENT_SEED`` - a simulated spray run (weather_filter.simdata
#: spec) and the seed of ``lidar-weather-sim augment`` (1 box per frame, the paper's ranges). Fixed before training.
AUGMENT_TRAIN_RUNS = (
    "highway_spray:11:40@11", "highway_spray:12:40@12", "wf_train_rain_spray:11:40@13", "wf_train_clear_spray:11:40@14",
    "wf_train_crosswind_spray:11:40@15", "proving_ground_39:11:40@16", "proving_ground_48:11:40@17",
    "highway_spray_crosswind:11:40@18",
)  # fmt: skip
#: An experiment, not the shipped model's runs (``train --preset augmentation-wide --out FILE``): the training runs
#: plus other weather and roads (snow on the curved road, fog, fog + rain, clear highway) and more spray seeds.
#: Chosen after the shipped model's held-out figures were known (it missed most on wf_heldout_mixed: curved road,
#: snow, fog), so its figures on those held-out runs are not a clean held-out measure.
AUGMENT_TRAIN_RUNS_WIDE = AUGMENT_TRAIN_RUNS + (
    "wf_train_snow:21:40@21", "wf_train_fog:21:40@22", "wf_train_fog_rain:21:40@23", "highway_clear:21:40@24",
    "highway_spray:22:40@25", "wf_train_rain_spray:22:40@26", "wf_train_crosswind_spray:22:40@27",
    "proving_ground_39:22:40@28", "wf_train_snow:23:40@29", "wf_train_fog:23:40@30",
)  # fmt: skip
#: v2 model's training runs (chosen after AUGMENT_TEST_RUNS_V2 was committed, never looking at
#: its figures): every simulation run of AUGMENT_TRAIN_RUNS_WIDE but the validation ones below, plus curved_clear
#: (curved road, guard rail, car ahead in the ego lane), the wf_knn_highway* runs (dirt on the cover) and more
#: snow / crosswind seeds; each simulation run augmented twice, once keeping the sensor model's EPW (``@SEED``,
#: the v1 runs' own bags) and once with the paper's EPW matching to the car ahead (``@SEED:lead``).
AUGMENT_TRAIN_RUNS_V2 = (
    "highway_spray:11:40@11", "highway_spray:12:40@12", "wf_train_rain_spray:11:40@13", "wf_train_clear_spray:11:40@14",
    "wf_train_crosswind_spray:11:40@15", "proving_ground_39:11:40@16", "proving_ground_48:11:40@17",
    "highway_spray_crosswind:11:40@18", "wf_train_snow:21:40@21", "wf_train_fog:21:40@22",
    "wf_train_fog_rain:21:40@23", "highway_clear:21:40@24", "wf_train_rain_spray:22:40@26",
    "wf_train_crosswind_spray:22:40@27", "curved_clear:31:40@71", "wf_knn_highway:31:40@72",
    "wf_knn_highway_dirt:31:40@73", "wf_knn_highway_heavy_dirt:31:40@74", "wf_train_snow:31:40@75",
    "highway_spray_crosswind:31:40@76",
    "highway_spray:11:40@41:lead", "highway_spray:12:40@42:lead", "wf_train_rain_spray:11:40@43:lead",
    "wf_train_clear_spray:11:40@44:lead", "wf_train_crosswind_spray:11:40@45:lead", "proving_ground_39:11:40@46:lead",
    "proving_ground_48:11:40@47:lead", "highway_spray_crosswind:11:40@48:lead", "wf_train_snow:21:40@49:lead",
    "wf_train_fog:21:40@50:lead", "wf_train_fog_rain:21:40@51:lead", "highway_clear:21:40@52:lead",
    "wf_train_rain_spray:22:40@54:lead", "wf_train_crosswind_spray:22:40@55:lead", "curved_clear:31:40@59:lead",
    "wf_knn_highway:31:40@60:lead", "wf_knn_highway_dirt:31:40@61:lead", "wf_knn_highway_heavy_dirt:31:40@62:lead",
    "wf_train_snow:31:40@63:lead", "highway_spray_crosswind:31:40@64:lead",
)  # fmt: skip
#: v2 model's validation runs: simulation runs of the training scenarios (4 of AUGMENT_TRAIN_RUNS_WIDE's, both
#: augmentations), kept out of the fit; the decision threshold (and nothing else) is chosen on them - never on a
#: held-out list. A deviation from the paper (its threshold: 0.5).
AUGMENT_VALIDATION_RUNS_V2 = (
    "highway_spray:22:40@25", "proving_ground_39:22:40@28", "wf_train_snow:23:40@29", "wf_train_fog:23:40@30",
    "highway_spray:22:40@53:lead", "proving_ground_39:22:40@56:lead", "wf_train_snow:23:40@57:lead",
    "wf_train_fog:23:40@58:lead",
)  # fmt: skip
#: v2 model's simulator-raycast boxes (``obstacle_data.simulated_box_bag(i, seed=SEED)``, i < COUNT: highway_spray
#: with one box actor, 3 frames each): (SEED, COUNT) of the fit's and of the validation's. The augmented boxes
#: alone left a gap to the simulator's own boxes (validation box F 0.76-0.83 on them vs 0.91-0.94 on augmented
#: runs): these teach the physics' boxes. Other seeds than the benchmark's (500): that one stays held out.
SIM_BOXES_TRAIN_V2 = (700, 40)
SIM_BOXES_VALIDATION_V2 = (900, 20)
#: v3 model's training runs: v2's plus two training scenarios with the car ahead in the ego lane
#: (wf_train_lead_ahead_rain: straight highway in rain; wf_train_lead_ahead_curved: the curved road), each at two
#: simulation seeds, augmented with the sensor's EPW and with EPW matched to the car ahead. Chosen after the v2
#: list's figures were known (v2's false obstacles there: the rear of the car ahead in the ego lane); measured on
#: AUGMENT_TEST_RUNS_V3, committed before any of them was trained on.
AUGMENT_TRAIN_RUNS_V3 = AUGMENT_TRAIN_RUNS_V2 + (
    "wf_train_lead_ahead_rain:41:40@81", "wf_train_lead_ahead_rain:42:40@82", "wf_train_lead_ahead_curved:41:40@83",
    "wf_train_lead_ahead_curved:42:40@84", "wf_train_lead_ahead_rain:41:40@85:lead",
    "wf_train_lead_ahead_rain:42:40@86:lead", "wf_train_lead_ahead_curved:41:40@87:lead",
    "wf_train_lead_ahead_curved:42:40@88:lead",
)  # fmt: skip
#: v3 model's validation runs: v2's plus a third seed of each new scenario; the threshold, and the choice of
#: V3_FEATURES over V2_FEATURES (box F 0.9276 against 0.9225 here), were made on them.
AUGMENT_VALIDATION_RUNS_V3 = AUGMENT_VALIDATION_RUNS_V2 + (
    "wf_train_lead_ahead_rain:43:40@89:lead", "wf_train_lead_ahead_curved:43:40@90:lead",
)  # fmt: skip


def sim_boxes_text(seed_count: tuple[int, int]) -> str:
    seed, count = seed_count
    return f"simulated boxes 0-{count - 1} seed {seed}"


#: Held-out runs: other simulation seeds, other augmentation seeds, and scenarios in no training run
#: (proving_ground_55 / 60, wf_heldout_mixed).
AUGMENT_TEST_RUNS = (
    "highway_spray:111:40@111", "proving_ground_55:111:40@112", "proving_ground_60:111:40@113",
    "wf_heldout_mixed:111:40@114", "highway_spray_crosswind:111:40@115",
)  # fmt: skip
#: Second held-out list, fixed and committed BEFORE any model was trained on the v2 model's
#: data, never used to choose anything: new simulation seeds (211) and augmentation seeds (211-217) of the same
#: held-out scenarios, plus two scenarios in no training run: wf_knn_spray_mist (highway spray in rain, the car
#: 16 m ahead-left) and wf_knn_curved_dirt (curved road, snow, dirt on the cover, a car 15 m ahead in the ego
#: lane: the v1 model's weak spot). Boxes with the paper's EPW matching to the car ahead's rear (``:lead``,
#: augment's default) - the v1 list keeps the sensor model's EPW (``none``).
AUGMENT_TEST_RUNS_V2 = (
    "highway_spray:211:40@211:lead", "proving_ground_55:211:40@212:lead", "proving_ground_60:211:40@213:lead",
    "wf_heldout_mixed:211:40@214:lead", "highway_spray_crosswind:211:40@215:lead",
    "wf_knn_spray_mist:211:40@216:lead", "wf_knn_curved_dirt:211:40@217:lead",
)  # fmt: skip
#: Third held-out list, fixed and committed BEFORE the v3 model (cluster extents) was trained (its
#: feature code written, never run), never used to choose anything: the v2 list's scenarios at new simulation
#: seeds (311) and augmentation seeds (311-317). The v2 list's figures (and its false obstacles: the car ahead in the ego lane of
#: wf_heldout_mixed) were known when v3 was designed, so for v3 the v2 list is validation, not held out.
AUGMENT_TEST_RUNS_V3 = (
    "highway_spray:311:40@311:lead", "proving_ground_55:311:40@312:lead", "proving_ground_60:311:40@313:lead",
    "wf_heldout_mixed:311:40@314:lead", "highway_spray_crosswind:311:40@315:lead",
    "wf_knn_spray_mist:311:40@316:lead", "wf_knn_curved_dirt:311:40@317:lead",
)  # fmt: skip
#: Fourth held-out list, fixed and committed BEFORE any v4 experiment was run, never used to choose
#: anything: the same held-out scenarios at new simulation seeds (411) and augmentation seeds (411-417). The v2 and
#: v3 lists' figures are known (v3 was measured on them), so for a v4 model both are validation, not held out.
AUGMENT_TEST_RUNS_V4 = (
    "highway_spray:411:40@411:lead", "proving_ground_55:411:40@412:lead", "proving_ground_60:411:40@413:lead",
    "wf_heldout_mixed:411:40@414:lead", "highway_spray_crosswind:411:40@415:lead",
    "wf_knn_spray_mist:411:40@416:lead", "wf_knn_curved_dirt:411:40@417:lead",
)  # fmt: skip
#: v4 model's training runs: v3's (the v4 model changes features and classifier, not data).
AUGMENT_TRAIN_RUNS_V4 = AUGMENT_TRAIN_RUNS_V3
#: v4 model's validation runs: v3's plus the second and third held-out lists, spent (measured on v2 and v3): runs of
#: the held-out scenarios at other seeds than AUGMENT_TEST_RUNS_V4's. The classifier, the features and the threshold
#: were chosen on them. Threshold chosen on v3's validation runs alone: 0.05, too low for scenarios never trained on
#: (the trees learn the training scenarios almost perfectly); with these: 0.9.
AUGMENT_VALIDATION_RUNS_V4 = AUGMENT_VALIDATION_RUNS_V3 + AUGMENT_TEST_RUNS_V2 + AUGMENT_TEST_RUNS_V3
#: Scenarios of the held-out lists never to be trained on (any training list).
HELDOUT_ONLY_SCENARIOS = ("proving_ground_55", "proving_ground_60", "wf_heldout_mixed", "wf_knn_spray_mist",
                          "wf_knn_curved_dirt")  # fmt: skip


def parse_run(text: str) -> tuple[str, int]:
    """``SPEC@SEED[:EPW_MATCH[:KINDS]]`` -> (simulation spec, augmentation seed)."""
    spec, seed, _, _ = parse_run_options(text)
    return spec, seed


#: ``SPEC@SEED`` alone: the shipped v1 model's augmentation (``--epw-match none``, boxes only).
RUN_DEFAULT_EPW_MATCH = "none"
RUN_DEFAULT_KINDS = ("box",)


def parse_run_options(text: str) -> tuple[str, int, str, tuple[str, ...]]:
    """``SCENARIO:SEED:FRAMES[:PROFILE]@AUGMENT_SEED[:EPW_MATCH[:KINDS]]`` -> (simulation spec, augmentation
    seed, ``augment --epw-match`` (``none`` or ``lead``; default none), ``augment --kinds`` (default box))."""
    spec, sep, tail = text.rpartition("@")
    seed, _, options = tail.partition(":")
    epw, _, kinds = options.partition(":")
    if not sep or not spec or not seed.isdigit() or (options and epw not in ("none", "lead")):
        raise ValueError(f"augmented run {text!r}: expected SCENARIO:SEED:FRAMES[:PROFILE]@AUGMENT_SEED"
                         "[:none|lead[:KIND,...]]")  # fmt: skip
    kinds_t = tuple(k for k in kinds.split(",") if k) or RUN_DEFAULT_KINDS
    return spec, int(seed), epw or RUN_DEFAULT_EPW_MATCH, kinds_t


def feature_region_mask(points: np.ndarray) -> np.ndarray:
    """Detections inside the paper's feature region (sensor frame, m)."""
    region = augmentation_table()["feature_region_m"]
    x, y = points["x"], points["y"]
    return (x >= region["x"][0]) & (x <= region["x"][1]) & (y >= region["y"][0]) & (y <= region["y"][1])


class ObstacleFeatures:
    """The features ``names`` (default: the paper's) of the feature region's detections, frame after frame of one
    sequence."""

    def __init__(self, names: tuple[str, ...] = PAPER_FEATURES) -> None:
        region = augmentation_table()["feature_region_m"]
        extent = max(abs(v) for v in (*region["x"], *region["y"]))
        self._extractor = PointFeatures(extent_m=extent, radial_bin_deg=augmentation_table()["histogram_cells_m"]["radial_deg"])
        known = FEATURE_NAMES + CLUSTER_FEATURES + HISTORY_FEATURES
        unknown = [n for n in names if n not in known]
        if unknown:
            raise ValueError(f"unknown obstacle features {unknown} (weather_filter.features.FEATURE_NAMES, "
                             "weather_filter.obstacle_clusters.CLUSTER_FEATURES, "
                             "weather_filter.obstacle_history.HISTORY_FEATURES)")  # fmt: skip
        self.names = tuple(names)
        self._columns = [known.index(n) for n in names]
        self._clusters = any(n in CLUSTER_FEATURES for n in names)
        self._history = CellHistory(region["x"], region["y"]) if any(n in HISTORY_FEATURES for n in names) else None

    def reset(self) -> None:
        self._extractor.reset()
        if self._history is not None:
            self._history.reset()

    def __call__(self, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(mask of the region's detections, (M, len(names)) float32 features of those)."""
        mask = feature_region_mask(points)
        columns = self._extractor(points[mask])
        x, y, z, dz_min = (columns[:, FEATURE_NAMES.index(n)] for n in ("x", "y", "z", "dz_min"))
        extra = [cluster_extents(x, y, z, dz_min) if self._clusters else np.zeros((len(x), len(CLUSTER_FEATURES)), np.float32)]
        if self._history is not None:
            extra.append(self._history(x, y, dz_min))
        columns = np.concatenate([columns, *extra], axis=1)
        return mask, np.ascontiguousarray(columns[:, self._columns])


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


class ObstacleClassifier:
    """The shipped (or a given) obstacle model; call :meth:`predict` frame after frame of one sequence."""

    def __init__(self, bundle: dict) -> None:
        from weather_filter.fast_trees import FastTrees
        from weather_filter.learned import FastMLP

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
