"""Learned filter, paper-4 features, evaluation metrics and the weather-filter CLI (no ROS)."""

import json
import sys

import numpy as np
import pytest

from lidar_weather_sim.core.points import Label
from weather_filter.evaluate import evaluate_frames
from weather_filter.filter_methods import make_filter
from weather_filter.learned.features import FEATURE_NAMES, PointFeatures
from weather_filter.learned.filter import DEFAULT_MODEL, LearnedFilter
from weather_filter.points.base import PointFilter
from weather_filter.synthetic import highway_frame


def test_features_shape_and_counts():
    pts = highway_frame("rain", seed=1)
    feats = PointFeatures()
    out = feats(pts)
    assert out.shape == (len(pts), len(FEATURE_NAMES))
    assert np.isfinite(out).all()
    i = FEATURE_NAMES.index
    assert (out[:, i("n_small")] >= 1).all() and (out[:, i("n_middle")] >= out[:, i("n_small")]).all()
    assert (out[:, i("d_radial")] == 0).all()  # first frame: no previous frame
    assert (feats(highway_frame("rain", seed=1, frame=1))[:, i("d_radial")] >= 0).all()


def test_packaged_model_is_versioned_and_loads():
    assert DEFAULT_MODEL.name == "weather_point_mlp_v4.joblib" and DEFAULT_MODEL.exists()
    filt = make_filter("learned").epw  # the EPW model (the single-return one: test_single_return.py)
    assert isinstance(filt, LearnedFilter)
    assert filt.bundle["command"].startswith("weather-filter train --sim ")
    assert filt.bundle["trained_on"].startswith("sim:")


def test_fast_forward_pass_equals_the_pipeline():
    filt = make_filter("learned").epw
    feats = PointFeatures()(highway_frame("rain", seed=5))
    proba = filt.model.predict_proba(feats)[:, 1]
    fast = 1 / (1 + np.exp(-filt._fast.logit(feats).astype(float)))
    assert np.allclose(fast, proba, atol=1e-4)


class _RemoveWeatherAndOneSolid(PointFilter):
    name = "oracle"

    def remove_mask(self, points):
        remove = points["label"] >= 10
        remove[np.flatnonzero(points["label"] == Label.VEHICLE)[:1]] = True
        return remove


def test_evaluation_keys_and_definitions():
    pts = highway_frame("rain", seed=2)
    pts["label"][:5] = Label.UNKNOWN  # label 0 counts neither way
    result = evaluate_frames(_RemoveWeatherAndOneSolid(), [pts, pts])
    assert list(result) == ["method", "frames", "weather_precision", "weather_recall", "weather_f1", "object_recall",
                            "object_recall_roi", "per_label", "ms_per_frame_mean", "ms_per_frame_p95"]
    n_weather = int((pts["label"] >= 10).sum()) * 2
    n_solid = int(np.isin(pts["label"], [1, 2, 3]).sum()) * 2
    assert result["frames"] == 2
    assert result["weather_recall"] == 1.0
    assert result["weather_precision"] == pytest.approx(n_weather / (n_weather + 2))
    assert result["object_recall"] == pytest.approx(1 - 2 / n_solid)
    assert 0 <= result["weather_f1"] <= 1
    assert result["per_label"]["11"] == {"name": "rain", "points": int((pts["label"] == 11).sum()) * 2,
                                         "removed": int((pts["label"] == 11).sum()) * 2, "removed_fraction": 1.0}
    assert result["per_label"]["0"]["removed"] == 0


def test_object_recall_roi_uses_the_corridor():
    pts = highway_frame(None, seed=2, spray=False)
    pts["label"][:] = Label.VEHICLE
    pts["x"][:3], pts["y"][:3] = [10.0, 4.0, 10.0], [0.0, 0.0, 2.0]  # inside, too close, too wide

    class RemoveFirstThree(PointFilter):
        name = "first3"

        def remove_mask(self, points):
            m = np.zeros(len(points), bool)
            m[:3] = True
            return m

    result = evaluate_frames(RemoveFirstThree(), [pts])
    roi = (np.abs(pts["y"]) <= 1.75) & (pts["x"] >= 5) & (pts["x"] <= 60)
    assert result["object_recall_roi"] == pytest.approx(1 - 1 / roi.sum())


def test_unlabelled_frames_report_removed_fraction():
    from lidar_weather_sim.core.points import strip_ground_truth

    pts = strip_ground_truth(highway_frame("rain", seed=3))
    result = evaluate_frames(make_filter("dror"), [pts])
    assert "weather_precision" not in result and 0 <= result["removed_fraction"] <= 1


def test_eval_cli_on_a_labelled_bag(tmp_path):
    import subprocess

    from lidar_weather_sim.io.bags import BagWriter

    bag = tmp_path / "bag"
    with BagWriter(bag) as writer:
        for i in range(3):
            writer.write_cloud("/lidar/points", highway_frame("snow", frame=i, seed=8), stamp_ns=i * 40_000_000, frame_id="lidar")
    out = tmp_path / "r.json"
    proc = subprocess.run([sys.executable, "-m", "weather_filter.cli", "eval", str(bag), "--method", "echo", "--out", str(out)],
                          capture_output=True, text=True, timeout=120)  # fmt: skip
    assert proc.returncode == 0, proc.stderr
    result = json.loads(out.read_text())
    assert result["method"] == "echo" and result["frames"] == 3
    assert result["object_recall"] == 1.0 and result["weather_precision"] == 1.0
    bad = subprocess.run([sys.executable, "-m", "weather_filter.cli", "eval", str(tmp_path / "nope")], capture_output=True, text=True)
    assert bad.returncode == 2 and "bag not found" in bad.stderr


@pytest.mark.parametrize(
    "method, param, reason",
    [("dror", "multiplier=abc", "filter 'dror': key 'multiplier': value 'abc': Input should be a valid number"),
     ("dror", "max_range_m=none", "key 'max_range_m': value 'none': Input should be a valid number"),
     ("dror", "min_neighbours=-1", "key 'min_neighbours': value -1: Input should be greater than or equal to 0"),
     ("dror", "min_neighbours=2.5", "key 'min_neighbours': value 2.5: Input should be a valid integer"),
     ("dror", "radius=1", "has no parameter(s) radius (its parameters: angular_resolution_deg, multiplier,"),
     ("dsor", "neighbours=0", "key 'neighbours': value 0: Input should be greater than or equal to 1"),
     ("echo", 'lior={"epw_threshold_m": "x"}', "filter 'echo': key 'lior.epw_threshold_m': value 'x': Input should be a valid number"),
     ("learned", "foo=1", "filter 'learned' has no parameter(s) foo (its parameters: model_path, single_return_model_path, threshold)"),
     ("learned", "threshold=2", "threshold must be a probability between 0 and 1, got 2")],
)  # fmt: skip
def test_filter_parameters_are_checked_with_a_reason_naming_them(method, param, reason):
    """These crashed with numpy/pickle tracebacks (rc 1) or ran with nonsense values (rc 0)."""
    from weather_filter.cli import _parse_params

    with pytest.raises(ValueError) as err:
        make_filter(method, **_parse_params([param]))
    assert reason in str(err.value)
    assert make_filter("dror", max_range_m=None, multiplier=2).params.multiplier == 2  # valid values still pass


def test_a_file_that_is_not_a_model_is_named(tmp_path):
    not_a_model = tmp_path / "model.joblib"
    not_a_model.write_text("hello")
    with pytest.raises(ValueError, match=f"{not_a_model}: not a weather-filter model"):
        LearnedFilter.load(not_a_model)


@pytest.mark.slow
def test_training_refuses_to_overwrite_the_packaged_model_and_impossible_settings(tmp_path):
    import subprocess

    before = DEFAULT_MODEL.read_bytes()
    for argv, reason in ((["train", "--synthetic-frames", "4"], "give --out FILE.joblib"),
                         (["train", "--preset", "shipped", "--synthetic-frames", "4"], "give --out FILE.joblib"),
                         (["train-weather", "--sim", "wf_train_snow:9:3"], "give --out FILE.joblib"),
                         (["train", "--threshold", "5", "--out", "m.joblib"], "--threshold: must lie in (0, 1), got 5"),
                         (["train", "--object-recall", "2", "--out", "m.joblib"], "must lie in (0, 1], got 2"),
                         (["train-weather", "--k", "0", "--out", "m.joblib"], "--k: must be at least 1, got 0")):  # fmt: skip
        proc = subprocess.run([sys.executable, "-m", "weather_filter.cli", *argv], cwd=tmp_path, capture_output=True,
                              text=True, timeout=120)  # fmt: skip
        assert proc.returncode == 2 and reason in proc.stderr.strip().splitlines()[-1], proc.stderr
    assert DEFAULT_MODEL.read_bytes() == before and not list(tmp_path.iterdir())


def test_loading_the_filter_compiles_every_kernel_of_a_frame():
    """The first cloud used to compile _median_gap and the network (3 s with a cold numba cache): a node's
    first frame and `eval`'s timing paid for it. After loading, every kernel a frame runs has a signature."""
    import subprocess

    code = """
from numba.core.registry import CPUDispatcher
import weather_filter.learned.azimuth, weather_filter.learned.fast_mlp, weather_filter.learned.features, weather_filter.learned.log10f
from weather_filter.learned.filter import LearnedFilter
LearnedFilter.load()
mods = (weather_filter.learned.azimuth, weather_filter.learned.features, weather_filter.learned.fast_mlp,
        weather_filter.learned.log10f)
kernels = [(m.__name__, n, len(o.signatures)) for m in mods for n, o in vars(m).items()
           if isinstance(o, CPUDispatcher) and o.__module__ == m.__name__ and o.targetoptions.get("inline") != "always"]
print(kernels)
assert len(kernels) >= 7 and all(count >= 1 for _, _, count in kernels), kernels
"""
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300)  # a fresh process
    assert proc.returncode == 0, proc.stdout + proc.stderr
