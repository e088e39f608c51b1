"""Paper 4's obstacle-vs-spray classifier: shared features, the paper's settings, eval on augmented bags."""

from __future__ import annotations

import json

import numpy as np
import pytest

from lidar_weather_sim.cli import main as sim_main
from lidar_weather_sim.augment.boxes import augmentation_table
from weather_filter.cli import main as wf_main
from weather_filter.learned.features import FEATURE_NAMES, PointFeatures
from weather_filter.obstacle.classifier import (
    DEFAULT_OBSTACLE_MODEL,
    OBSTACLE_MODEL_V1,
    OBSTACLE_MODEL_V2,
    OBSTACLE_MODEL_V3,
    ObstacleClassifier,
)
from weather_filter.obstacle.data import augmented_bag, simulated_box_bag, simulated_box_spec
from weather_filter.obstacle.features import (
    PAPER_FEATURES,
    V2_FEATURES,
    V3_FEATURES,
    V4_FEATURES,
    ObstacleFeatures,
    feature_region_mask,
)
from weather_filter.obstacle.runs import (
    AUGMENT_TEST_RUNS,
    AUGMENT_TEST_RUNS_V2,
    AUGMENT_TEST_RUNS_V3,
    AUGMENT_TEST_RUNS_V4,
    AUGMENT_TRAIN_RUNS,
    AUGMENT_TRAIN_RUNS_V2,
    AUGMENT_TRAIN_RUNS_V3,
    AUGMENT_TRAIN_RUNS_V4,
    AUGMENT_TRAIN_RUNS_WIDE,
    AUGMENT_VALIDATION_RUNS_V2,
    AUGMENT_VALIDATION_RUNS_V3,
    AUGMENT_VALIDATION_RUNS_V4,
    HELDOUT_ONLY_SCENARIOS,
    SIM_BOXES_TRAIN_V2,
    SIM_BOXES_VALIDATION_V2,
    parse_run,
    parse_run_options,
    sim_boxes_text,
)
from weather_filter.obstacle.scores import obstacle_scores
from weather_filter.obstacle.training import V2_HIDDEN, V4_TREES, best_threshold, train_obstacle
from weather_filter.simdata import frames_of


def test_scores_with_numbers():
    truth = np.array([1, 1, 1, 0, 0, 0, 0, 0], bool)
    pred = np.array([1, 1, 0, 1, 0, 0, 0, 0], bool)
    s = obstacle_scores(truth, pred)
    assert s["obstacle_precision"] == pytest.approx(2 / 3) and s["obstacle_recall"] == pytest.approx(2 / 3)
    assert s["obstacle_f1"] == pytest.approx(2 / 3)
    assert s["no_obstacle_f1"] == pytest.approx(2 * 4 / (2 * 4 + 1 + 1))
    assert obstacle_scores(np.zeros(3, bool), np.zeros(3, bool))["obstacle_f1"] == 1.0


def test_features_are_the_learned_filters_in_the_feature_region():
    rng = np.random.default_rng(0)
    from lidar_weather_sim.core.points import empty_points, fill_polar

    p = empty_points(500)
    p["x"], p["y"], p["z"] = rng.uniform(-5, 25, 500), rng.uniform(-9, 9, 500), rng.uniform(-1, 1, 500)
    p["echo"], p["channel"], p["epw"] = 1, rng.integers(0, 4, 500), rng.uniform(0.5, 2, 500)
    fill_polar(p)
    mask, x = ObstacleFeatures()(p)
    region = augmentation_table()["feature_region_m"]
    assert mask.sum() == np.sum((p["x"] >= region["x"][0]) & (p["x"] <= 20) & (np.abs(p["y"]) <= region["y"][1]))
    reference = PointFeatures(extent_m=20.0)(p[mask])[:, [FEATURE_NAMES.index(n) for n in PAPER_FEATURES]]
    np.testing.assert_array_equal(x, reference)
    assert len(PAPER_FEATURES) == 15


def test_shipped_model_settings():
    c = ObstacleClassifier.load()
    table = augmentation_table()["classifier"]
    # the paper's class weights; deviations (README): gradient-boosted trees, the 27 extractor features, the cluster
    # extents and the cell history, validated threshold
    assert c.bundle["class_weights"] == {"no_box": table["weight_no_box"], "box": table["weight_box"]}
    assert c.bundle["classifier"] == "trees" and tuple(c.bundle["feature_names"]) == V4_FEATURES
    assert {k: c.bundle["model"].get_params()[k] for k in V4_TREES} == V4_TREES
    assert set(PAPER_FEATURES) < set(V2_FEATURES) < set(V3_FEATURES) < set(V4_FEATURES) and len(V2_FEATURES) == 27
    assert DEFAULT_OBSTACLE_MODEL.name == "obstacle_point_hgb_v4.joblib" and c.bundle["version"] == 4
    assert c.bundle["trained_on"] == ", ".join(AUGMENT_TRAIN_RUNS_V4) + ", " + sim_boxes_text(SIM_BOXES_TRAIN_V2)
    # the threshold chosen on validation runs and other box seeds, never on the v4 held-out list
    assert c.bundle["threshold_chosen_on"] == ", ".join(AUGMENT_VALIDATION_RUNS_V4) + ", " + sim_boxes_text(
        SIM_BOXES_VALIDATION_V2)
    assert 0.05 <= c.bundle["threshold"] <= 0.95
    assert c.bundle["command"] == "weather-filter train --preset augmentation-v4 --seed 0"


def test_third_model_stays_loadable_by_path():
    c = ObstacleClassifier.load(OBSTACLE_MODEL_V3)
    assert c.bundle["version"] == 3 and tuple(c.bundle["feature_names"]) == V3_FEATURES
    assert c.bundle["model"][-1].hidden_layer_sizes == V2_HIDDEN
    assert c.bundle["trained_on"] == ", ".join(AUGMENT_TRAIN_RUNS_V3) + ", " + sim_boxes_text(SIM_BOXES_TRAIN_V2)


def test_second_model_stays_loadable_by_path():
    c = ObstacleClassifier.load(OBSTACLE_MODEL_V2)
    assert c.bundle["version"] == 2 and tuple(c.bundle["feature_names"]) == V2_FEATURES
    assert c.bundle["trained_on"] == ", ".join(AUGMENT_TRAIN_RUNS_V2) + ", " + sim_boxes_text(SIM_BOXES_TRAIN_V2)


def test_first_model_stays_loadable_by_path():
    c = ObstacleClassifier.load(OBSTACLE_MODEL_V1)
    table = augmentation_table()["classifier"]
    assert c.bundle["version"] == 1 and c.bundle["threshold"] == 0.5
    assert c.bundle["model"][-1].hidden_layer_sizes == (table["hidden_units"],)
    assert tuple(c.bundle["feature_names"]) == PAPER_FEATURES and c.features.names == PAPER_FEATURES
    assert c.bundle["trained_on"] == ", ".join(AUGMENT_TRAIN_RUNS)


def test_simulated_box_seeds_are_apart():
    bench = set(range(500, 550))  # benchmarks/validation/obstacle_classifier.py: 50 boxes of seed 500 (run seeds 500 + i)
    train = set(range(SIM_BOXES_TRAIN_V2[0], sum(SIM_BOXES_TRAIN_V2)))
    val = set(range(SIM_BOXES_VALIDATION_V2[0], sum(SIM_BOXES_VALIDATION_V2)))
    assert not bench & train and not bench & val and not train & val


def test_best_threshold_with_numbers():
    truth = np.array([1, 1, 1, 0, 0, 0, 0, 0], bool)
    prob = np.array([0.9, 0.35, 0.3, 0.2, 0.1, 0.1, 0.05, 0.05])
    t, s = best_threshold(truth, prob)
    assert t == 0.3 and s["obstacle_f1"] == 1.0  # every threshold in (0.2, 0.3] is perfect: the nearest to 0.5
    t, s = best_threshold(np.array([1, 0, 1, 0], bool), np.array([0.8, 0.6, 0.55, 0.1]))
    assert t == 0.5 and s["obstacle_f1"] == pytest.approx(0.8)  # (0.1, 0.55]: P 2/3 R 1, the best; nearest 0.5


def test_run_lists_are_disjoint_and_parse():
    train = {parse_run(r) for r in AUGMENT_TRAIN_RUNS}
    test = {parse_run(r) for r in AUGMENT_TEST_RUNS}
    assert not {s for s, _ in train} & {s for s, _ in test}
    assert not {a for _, a in train} & {a for _, a in test}
    with pytest.raises(ValueError):
        parse_run("highway_spray:1:4")


TRAIN_LISTS = (AUGMENT_TRAIN_RUNS, AUGMENT_TRAIN_RUNS_WIDE, AUGMENT_TRAIN_RUNS_V2, AUGMENT_VALIDATION_RUNS_V2,
               AUGMENT_TRAIN_RUNS_V3, AUGMENT_VALIDATION_RUNS_V3)


@pytest.mark.parametrize("test_runs, earlier", [(AUGMENT_TEST_RUNS_V2, AUGMENT_TEST_RUNS),
                                                (AUGMENT_TEST_RUNS_V3, AUGMENT_TEST_RUNS + AUGMENT_TEST_RUNS_V2),
                                                (AUGMENT_TEST_RUNS_V4,
                                                 AUGMENT_TEST_RUNS + AUGMENT_TEST_RUNS_V2 + AUGMENT_TEST_RUNS_V3)])
def test_heldout_runs_are_in_no_training_list_nor_an_earlier_heldout_list(test_runs, earlier):
    test = [parse_run_options(r) for r in test_runs]
    old = {parse_run(r) for r in earlier}
    for runs in TRAIN_LISTS:
        train = [parse_run_options(r) for r in runs]
        assert not {t[0] for t in train} & {t[0] for t in test}  # simulation runs
        assert not {t[1] for t in train} & {t[1] for t in test}  # augmentation seeds
        assert not {t[0].split(":")[0] for t in train} & set(HELDOUT_ONLY_SCENARIOS)
    assert not {t[0] for t in test} & {s for s, _ in old} and not {t[1] for t in test} & {a for _, a in old}
    assert {t[0].split(":")[0] for t in test} >= set(HELDOUT_ONLY_SCENARIOS)
    assert all(t[2] == "lead" and t[3] == ("box",) for t in test)


@pytest.mark.parametrize("train_runs, validation_runs", [(AUGMENT_TRAIN_RUNS_V2, AUGMENT_VALIDATION_RUNS_V2),
                                                          (AUGMENT_TRAIN_RUNS_V3, AUGMENT_VALIDATION_RUNS_V3),
                                                          (AUGMENT_TRAIN_RUNS_V4, AUGMENT_VALIDATION_RUNS_V4)])
def test_validation_runs_are_not_fitted_on(train_runs, validation_runs):
    train = {parse_run_options(r)[0] for r in train_runs}
    val = {parse_run_options(r)[0] for r in validation_runs}
    assert not train & val
    seeds = [parse_run_options(r)[1] for r in train_runs + validation_runs]
    assert len(seeds) == len(set(seeds))


def test_v4_validation_holds_no_run_of_the_v4_heldout_list():
    test = [parse_run_options(r) for r in AUGMENT_TEST_RUNS_V4]
    val = [parse_run_options(r) for r in AUGMENT_VALIDATION_RUNS_V4]
    assert not {t[0] for t in test} & {v[0] for v in val} and not {t[1] for t in test} & {v[1] for v in val}
    assert set(AUGMENT_TEST_RUNS_V2 + AUGMENT_TEST_RUNS_V3) < set(AUGMENT_VALIDATION_RUNS_V4)


def test_train_with_validation_threshold_is_reproducible(tmp_path):
    runs, val = ("highway_spray:9:3@9:lead", "wf_train_snow:9:3@10"), ("highway_spray:8:3@8:lead",)
    bags = {r: augmented_bag(r, tmp_path) for r in runs + val}
    reports = []
    for name in ("a", "b"):
        reports.append(train_obstacle([frames_of(bags[r]) for r in runs], tmp_path / f"{name}.joblib", trained_on="t",
                                      command="c", seed=3, validation=[frames_of(bags[r]) for r in val],
                                      validated_on="v", version=2, features=V2_FEATURES, hidden=(4,)))  # fmt: skip
    assert (tmp_path / "a.joblib").read_bytes() == (tmp_path / "b.joblib").read_bytes()
    assert 0.05 <= reports[0].threshold <= 0.95 and reports[0].validation_scores["obstacle_points"] > 0
    bundle = ObstacleClassifier.load(tmp_path / "a.joblib").bundle
    assert bundle["threshold"] == reports[0].threshold and bundle["threshold_chosen_on"] == "v"
    assert tuple(bundle["feature_names"]) == V2_FEATURES and bundle["hidden"] == [4]


@pytest.mark.slow
def test_trees_train_reproducibly_and_predict_at_their_threshold(tmp_path):
    runs, val = ("highway_spray:9:3@9:lead", "wf_train_snow:9:3@10"), ("highway_spray:8:3@8:lead",)
    bags = {r: augmented_bag(r, tmp_path) for r in runs + val}
    for name in ("a", "b"):
        report = train_obstacle([frames_of(bags[r]) for r in runs], tmp_path / f"{name}.joblib", trained_on="t",
                                command="c", seed=3, validation=[frames_of(bags[r]) for r in val], validated_on="v",
                                version=4, features=V4_FEATURES, classifier="trees")  # fmt: skip
    assert (tmp_path / "a.joblib").read_bytes() == (tmp_path / "b.joblib").read_bytes()
    c = ObstacleClassifier.load(tmp_path / "a.joblib")
    assert c.bundle["classifier"] == "trees" and c.bundle["threshold"] == report.threshold
    # predict() is the trees' score at the stored threshold (as a logit), on the feature region only
    frames = list(frames_of(bags[val[0]]))
    features = ObstacleFeatures(V4_FEATURES)
    for points in frames:
        mask, x = features(points)
        expected = c.bundle["model"].decision_function(x) >= np.log(report.threshold / (1 - report.threshold))
        got = c.predict(points)
        assert not got[~mask].any() and np.array_equal(got[mask], expected)
    with pytest.raises(ValueError, match="mlp or trees"):
        train_obstacle([frames_of(bags[runs[0]])], tmp_path / "c.joblib", trained_on="t", command="c", classifier="svm")


def test_run_options_parse():
    assert parse_run_options("highway_spray:1:4@7") == ("highway_spray:1:4", 7, "none", ("box",))
    assert parse_run_options("highway_spray:1:4:scala4@7:lead") == ("highway_spray:1:4:scala4", 7, "lead", ("box",))
    assert parse_run_options("a:1:4@7:none:box,vehicle") == ("a:1:4", 7, "none", ("box", "vehicle"))
    with pytest.raises(ValueError):
        parse_run("highway_spray:1:4@7:maybe")


def test_simulated_boxes_are_inside_the_roi_and_found(tmp_path):
    roi = augmentation_table()["roi"]
    truth, pred = [], []
    classifier = ObstacleClassifier.load()
    for i in range(4):
        scenario, _ = simulated_box_spec(i)
        box = scenario.actors[-1]
        assert roi["x_min_m"] <= box.lead_gap_m and box.lead_gap_m + box.size.length_m <= roi["x_max_m"]
        classifier.reset()
        for points in frames_of(simulated_box_bag(i, tmp_path)):
            mask = feature_region_mask(points)
            truth.append(points["label"][mask] == 3)
            pred.append(classifier.predict(points)[mask])
    s = obstacle_scores(np.concatenate(truth), np.concatenate(pred))
    assert s["obstacle_points"] > 50
    assert s["obstacle_f1"] > 0.8 and s["no_obstacle_f1"] > 0.98


def test_eval_reports_obstacle_scores_only_with_label_3(tmp_path, capsys):
    bag, aug = tmp_path / "spray", tmp_path / "aug"
    assert sim_main(["run", "highway_spray", "--frames", "6", "--seed", "3", "--out", str(bag)]) == 0
    assert sim_main(["augment", str(bag), "--seed", "5", "--out", str(aug)]) == 0
    capsys.readouterr()
    assert wf_main(["eval", str(aug)]) == 0
    result = json.loads(capsys.readouterr().out)
    for key in ("obstacle_precision", "obstacle_recall", "obstacle_f1"):
        assert 0.0 <= result[key] <= 1.0
    assert result["obstacle_points"] > 0 and "weather_f1" in result
    assert wf_main(["eval", str(bag)]) == 0
    assert "obstacle_f1" not in json.loads(capsys.readouterr().out)
    assert wf_main(["eval", str(aug), "--obstacle-model", str(tmp_path / "none.joblib")]) == 2


def test_cluster_extents_measure_the_object_a_detection_belongs_to():
    """A 1.8 m wide, 1.4 m tall car rear at 14 m and a 0.4 m post at 8 m, on a road seen as rings: each detection
    above the road gets its own object's size and count; road detections (their cell's floor) get zeros."""
    from weather_filter.obstacle.clusters import cluster_extents

    ys = np.arange(-0.9, 0.91, 0.1)
    zs = np.linspace(-0.4, 1.0, 8)
    rear = np.array([(14.0, y, z) for y in ys for z in zs])
    post = np.array([(8.0, 3.0 + dy, z) for dy in (0.0, 0.2, 0.4) for z in (-0.5, 0.0, 0.3)])
    road = np.array([(x, y, -0.5) for x in (6.0, 10.0, 18.0) for y in np.arange(-5.0, 5.01, 0.1)])
    xyz = np.concatenate([rear, post, road])
    # dz_min as the extractor computes it: height above the lowest detection of the 50 cm cell
    cell = np.floor(xyz[:, :2] / 0.5).astype(np.int64)
    _, inverse = np.unique(cell, axis=0, return_inverse=True)
    floor = np.full(inverse.max() + 1, np.inf)
    np.minimum.at(floor, inverse, xyz[:, 2])
    out = cluster_extents(xyz[:, 0], xyz[:, 1], xyz[:, 2], xyz[:, 2] - floor[inverse])
    on_rear = out[: len(rear)][np.any(out[: len(rear)] > 0, axis=1)]
    assert np.allclose(on_rear[:, 2], 1.8, atol=1e-6) and np.allclose(on_rear[:, 3], 1.4, atol=1e-6)  # width, height
    assert np.allclose(on_rear[:, 1], 0.0) and on_rear[0, 0] == len(on_rear) == len(rear) - len(ys)
    on_post = out[len(rear) : len(rear) + len(post)]
    assert np.allclose(on_post[on_post[:, 0] > 0][:, 2:], [0.4, 0.8], atol=1e-6)  # on the road: 0.8 m above it
    assert not out[len(rear) + len(post) :].any()  # the road


def test_cell_history_tells_what_holds_its_place_from_what_is_new():
    """A car rear 14 m ahead holds its cells frame after frame; a box that appears at frame 5 has no history; road
    detections (at their cell's floor) never mark a cell; reset forgets."""
    from weather_filter.obstacle.history import HISTORY_FEATURES, CellHistory

    history = CellHistory((0.0, 20.0), (-6.0, 6.0))
    rear = (np.full(5, 14.0), np.linspace(-0.8, 0.8, 5), np.full(5, 0.6))  # x, y, dz_min
    road = (np.full(5, 8.0), np.linspace(-2.0, 2.0, 5), np.zeros(5))
    for _ in range(5):
        assert not history(*(np.concatenate(v) for v in zip(rear, road)))[5:].any()  # nothing stood on the road
    box = (np.array([6.0, 6.2]), np.array([-3.0, -3.0]), np.array([0.4, 0.9]))
    near_rear = (np.array([14.4]), np.array([1.2]), np.array([0.3]))  # the next cell over: the 8-neighbourhood
    out = history(*(np.concatenate(v) for v in zip(rear, box, near_rear, road)))
    assert HISTORY_FEATURES == ("hist_recent", "hist_old")
    np.testing.assert_array_equal(out[:5], [[2, 3]] * 5)  # frames t-1, t-2 and t-3..t-5
    np.testing.assert_array_equal(out[5:7], 0)
    np.testing.assert_array_equal(out[7], [2, 3])
    np.testing.assert_array_equal(out[8:], 0)  # the road was never occupied above its floor
    out = history(*box)
    np.testing.assert_array_equal(out, [[1, 0]] * 2)  # the box itself, one frame back
    history.reset()
    assert not history(*rear).any()
