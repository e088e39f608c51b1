"""Paper 4's obstacle-vs-spray classifier: shared features, the paper's settings, eval on augmented bags."""

from __future__ import annotations

import json

import numpy as np
import pytest

from lidar_weather_sim.cli import main as sim_main
from lidar_weather_sim.gap.obstacle_boxes import augmentation_table
from weather_filter.cli import main as wf_main
from weather_filter.features import FEATURE_NAMES, PointFeatures
from weather_filter.obstacle import (
    AUGMENT_TEST_RUNS,
    AUGMENT_TEST_RUNS_V2,
    AUGMENT_TRAIN_RUNS,
    AUGMENT_TRAIN_RUNS_WIDE,
    HELDOUT_ONLY_SCENARIOS,
    PAPER_FEATURES,
    ObstacleClassifier,
    ObstacleFeatures,
    feature_region_mask,
    obstacle_scores,
    parse_run,
    parse_run_options,
)
from weather_filter.obstacle_data import simulated_box_bag, simulated_box_spec
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


def test_shipped_model_has_the_papers_settings():
    c = ObstacleClassifier.load()
    table = augmentation_table()["classifier"]
    assert c.bundle["model"][-1].hidden_layer_sizes == (table["hidden_units"],)
    assert c.bundle["class_weights"] == {"no_box": table["weight_no_box"], "box": table["weight_box"]}
    assert c.bundle["trained_on"] == ", ".join(AUGMENT_TRAIN_RUNS)


def test_run_lists_are_disjoint_and_parse():
    train = {parse_run(r) for r in AUGMENT_TRAIN_RUNS}
    test = {parse_run(r) for r in AUGMENT_TEST_RUNS}
    assert not {s for s, _ in train} & {s for s, _ in test}
    assert not {a for _, a in train} & {a for _, a in test}
    with pytest.raises(ValueError):
        parse_run("highway_spray:1:4")


TRAIN_LISTS = (AUGMENT_TRAIN_RUNS, AUGMENT_TRAIN_RUNS_WIDE)


def test_v2_heldout_runs_are_in_no_training_list():
    test = [parse_run_options(r) for r in AUGMENT_TEST_RUNS_V2]
    old = {parse_run(r) for r in AUGMENT_TEST_RUNS}
    for runs in TRAIN_LISTS:
        train = [parse_run_options(r) for r in runs]
        assert not {t[0] for t in train} & {t[0] for t in test}  # simulation runs
        assert not {t[1] for t in train} & {t[1] for t in test}  # augmentation seeds
        assert not {t[0].split(":")[0] for t in train} & set(HELDOUT_ONLY_SCENARIOS)
    assert not {t[0] for t in test} & {s for s, _ in old} and not {t[1] for t in test} & {a for _, a in old}
    assert {t[0].split(":")[0] for t in test} >= set(HELDOUT_ONLY_SCENARIOS)
    assert all(t[2] == "lead" and t[3] == ("box",) for t in test)


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
