"""The filter's targets on labelled simulation: the shipped learned filter and per-frame weather KNN on runs simulated here
with fixed seeds (scenarios and seeds never used in training), the numba feature pass against a direct
numpy/scipy computation, and the reproducibility of ``weather-filter train --sim``.

The shipped models match the simulator they were trained with (commit ce35beb, with the ellipsoidal spray drop
packets of 857575c: fresh runs of the training specs reproduce the training bags). When the simulated weather changes (the atmosphere or spray
regions), these floors may fail: retrain with
``rm -rf .venv/cache/weather_filter && weather-filter train --preset shipped && weather-filter train --preset
shipped-single && weather-filter train-weather --preset shipped`` and re-measure with benchmarks/validation/weather_filter_eval.py."""

import numpy as np
import pytest
from scipy import ndimage

from lidar_weather_sim.core.points import Label
from weather_filter.evaluate import evaluate_frames
from weather_filter.filter_methods import make_filter
from weather_filter.learned.features import (
    CELL_SHAPES,
    CORNER,
    FEATURE_NAMES,
    HORIZONTAL,
    IMPULSE,
    PointFeatures,
    radial_histogram,
)
from weather_filter.simdata import HELDOUT_SPECS, TRAIN_SPECS, SimSpec, frames_of, simulate

pytestmark = pytest.mark.validation  # the shipped filters' figures on held-out simulated runs

# Floors a little below the figures measured on these runs with the shipped model (src/weather_filter/README.md):
# spec -> (weather_f1, object_recall, object_recall_roi); measured with v4 (simulator of ce35beb, spray drop packets)
# wf_heldout_mixed:202:12 0.976 / 0.979 / 0.998 (v3 on the simulator before them: 0.932 / 0.954 / 1.0),
# highway_spray:202:12 0.999 / 1.0 / 1.0. Snow in fog on the curved road (never
# trained on) is the weak case: the road ~10 m ahead, dimmed by the fog, is partly removed, and a few points of the
# vehicle ahead seen through its spray.
HELDOUT_FLOORS = {"wf_heldout_mixed:202:12": (0.95, 0.97, 0.97), "highway_spray:202:12": (0.97, 0.998, 0.998)}


@pytest.fixture(scope="module")
def cache(tmp_path_factory):
    return tmp_path_factory.mktemp("sim")


def _frames(spec, cache):
    return list(frames_of(simulate(spec, cache)))


def test_features_equal_a_direct_computation():
    spec = "wf_heldout_mixed:5:2"
    import tempfile

    with tempfile.TemporaryDirectory() as tmp:
        first, points = _frames(spec, tmp)
    extractor = PointFeatures()
    extractor(first)
    out = extractor(points)
    assert out.shape == (len(points), len(FEATURE_NAMES)) and np.isfinite(out).all()
    x, y, e = points["x"].astype(float), points["y"].astype(float), 30.0
    for col, name in enumerate(("x", "y", "z", "echo", "channel", "epw", "intensity")):
        assert np.allclose(out[:, col], points[name].astype(np.float32)), name
    assert np.allclose(out[:, 7], np.hypot(x, y), atol=1e-4)
    now, idx = radial_histogram(points)
    before, _ = radial_histogram(first)
    assert np.array_equal(out[:, 8], now[idx]) and np.array_equal(out[:, 13], np.abs(now - before)[idx])
    for col, (name, cx, cy) in enumerate(CELL_SHAPES, start=9):
        nx, ny = int(np.ceil(2 * e / cx)), int(np.ceil(2 * e / cy))
        flat = np.clip(((x + e) / cx).astype(int), 0, nx - 1) * ny + np.clip(((y + e) / cy).astype(int), 0, ny - 1)
        counts = np.bincount(flat, minlength=nx * ny)
        assert np.array_equal(out[:, col], counts[flat]), name
        if name == "small":
            grid = counts.reshape(nx, ny).astype(np.float32)
            inside = (np.abs(x) < e) & (np.abs(y) < e)
            for k, kernel in enumerate((HORIZONTAL, CORNER, np.rot90(CORNER), IMPULSE)):
                response = ndimage.correlate(grid, kernel, mode="constant").ravel()
                assert np.allclose(out[:, 14 + k], np.where(inside, response[flat], 0)), k


def _range_image_reference(points, step, columns=2, channels=2, n_echoes=4, close=0.03):
    """The ``ri_*`` and ``dz_*`` columns computed directly (dense arrays, numpy), for the numba pass."""
    x, y, z = (points[n].astype(np.float64) for n in ("x", "y", "z"))
    r = np.sqrt(x * x + y * y + z * z).astype(np.float32)
    ch = points["channel"].astype(np.int64)
    n_ch, n_cols = int(ch.max()) + 1, int(2 * np.pi / step + 0.5)
    b = ((np.arctan2(y, x) + np.pi) / step).astype(np.int64)
    b = np.clip(np.where(b >= n_cols, b - n_cols, b), 0, n_cols - 1)
    grid = np.full((n_ch, n_cols, n_echoes), np.nan, np.float32)
    slot = np.zeros((n_ch, n_cols), np.int64)
    for i in range(len(points)):  # the first n_echoes points of a cell, in point order
        if slot[ch[i], b[i]] < n_echoes:
            grid[ch[i], b[i], slot[ch[i], b[i]]] = r[i]
            slot[ch[i], b[i]] += 1
    inv = np.float32(1) / np.maximum(r, np.float32(0.05))
    own = (grid[ch, b] - r[:, None]) * inv[:, None]
    behind, front = (own > 1e-3).sum(1), (own < -1e-3).sum(1)
    gap = np.minimum(np.nanmin(np.where(own > 1e-3, own, np.nan), 1, initial=1.0), 1.0)
    ring = np.ones(len(r), np.float32)
    cross, n_close, occupied = ring.copy(), np.zeros(len(r)), np.zeros(len(r))
    for dc in range(-channels, channels + 1):
        cc = ch + dc
        inside = (cc >= 0) & (cc < n_ch)
        for db in range(-columns, columns + 1):
            if dc == db == 0:
                continue
            cell = np.where(inside[:, None], grid[np.clip(cc, 0, n_ch - 1), (b + db) % n_cols], np.nan)
            d = np.abs(cell - r[:, None]) * inv[:, None]
            occupied += np.isfinite(cell[:, 0])
            n_close += (d < close).sum(1)
            best = np.fmin(np.nanmin(np.where(np.isfinite(d), d, np.inf), 1), 1.0)
            if dc == 0:
                ring = np.minimum(ring, best)
            elif abs(dc) == 1:
                cross = np.minimum(cross, best)
    cols = {"ri_ring": np.log10(np.maximum(ring, 1e-3)), "ri_cross": np.log10(np.maximum(cross, 1e-3)),
            "ri_close": n_close, "ri_occ": occupied, "ri_behind": behind, "ri_gap_behind": np.log10(np.maximum(gap, 1e-3)),
            "ri_front": front}  # fmt: skip
    e = 30.0
    cell = np.clip(((x + e) / 0.5).astype(int), 0, 119) * 120 + np.clip(((y + e) / 0.5).astype(int), 0, 119)
    lo, hi = np.full(120 * 120, np.inf, np.float32), np.full(120 * 120, -np.inf, np.float32)
    np.minimum.at(lo, cell, points["z"])
    np.maximum.at(hi, cell, points["z"])
    cols["dz_min"], cols["dz_max"] = points["z"] - lo[cell], hi[cell] - points["z"]
    return cols


@pytest.mark.parametrize("spec", ["wf_heldout_mixed:5:2", "wf_heldout_mixed:5:2:os1_128_1024"])
def test_range_image_features_equal_a_direct_computation(spec):
    import tempfile

    from weather_filter.points.scan_geometry import estimate_angular_steps

    with tempfile.TemporaryDirectory() as tmp:
        points = _frames(spec, tmp)[1]
    extractor = PointFeatures()
    out = extractor(points)
    steps = estimate_angular_steps(points)
    assert extractor.last_step_rad == pytest.approx(steps.azimuth_rad, rel=1e-3)  # the scan's column step
    for name, expected in _range_image_reference(points, extractor.last_step_rad).items():
        assert np.allclose(out[:, FEATURE_NAMES.index(name)], expected, atol=1e-5), name


def test_sim_specs_parse_and_name_their_bags():
    spec = SimSpec.parse("wf_knn_highway:3:5::rain2+fog300")
    assert (spec.scenario, spec.seed, spec.frames, spec.profile, spec.weather) == ("wf_knn_highway", 3, 5, None, "rain2+fog300")
    assert str(spec) == "wf_knn_highway:3:5::rain2+fog300"
    weather = spec.load_scenario().weather
    assert weather.precipitation.type == "rain" and weather.precipitation.intensity_mm_h == 2 and weather.fog.visual_range_m == 300
    assert SimSpec.parse("a:1:2:os1_128_1024").bag_name == "a_s1_n2_os1_128_1024"
    for bad in ("a:1", "a:x:2", "a:1:0", "a:1:2::hail3"):
        with pytest.raises(ValueError):
            SimSpec.parse(bad)
    held = {SimSpec.parse(s).scenario for s in HELDOUT_SPECS}
    assert not held & {SimSpec.parse(s).scenario for s in TRAIN_SPECS}


def test_learned_filter_keeps_a_box_standing_inside_a_spray_cloud(cache):
    frames = _frames("wf_test_box_in_spray:7:40", cache)[10:]  # the cloud has formed after 0.4 s
    filt = make_filter("learned")
    filt.reset()
    removed = [(p, filt(p).remove) for p in frames]
    box = np.concatenate([r[p["label"] == Label.OBSTACLE] for p, r in removed])
    spray = np.concatenate([r[p["label"] == Label.SPRAY] for p, r in removed])
    assert len(box) >= 100 and len(spray) >= 100, (len(box), len(spray))
    # measured with v4: 0 of 495 box points removed, 99.5 % of the 13840 spray points (v3 on the simulator before the
    # spray drop packets: 3 of 480 box points, 9.5 % of 516 spray points)
    assert box.mean() <= 0.01, f"box points removed: {box.sum()} of {len(box)}"
    assert spray.mean() >= 0.5, f"spray removed: {spray.mean():.3f}"


@pytest.mark.parametrize("spec", sorted(HELDOUT_FLOORS))
def test_shipped_model_meets_its_floor_on_held_out_runs(spec, cache):
    result = evaluate_frames(make_filter("learned"), _frames(spec, cache))
    f1, objects, roi = HELDOUT_FLOORS[spec]
    assert result["weather_f1"] >= f1, result
    assert result["object_recall"] >= objects, result
    assert result["object_recall_roi"] >= roi, result


# spec -> (class, least share of frames named so); measured 1.0 each, wf_train_fog / wf_train_snow 0.95,
# highway_spray 0.85; wf_heldout_mixed (snow 1.5 mm/h in fog 600 m) 0.85 since the fitted air draws fog with snow per
# class (scaling the snow class by the fog's extinction too, ~4x its near field, gave 1.0). The fog and snow runs through the heavier dirt of the point filter's training scenarios
# (never trained on by the KNN) were named rain and fog/rain in every frame by KNN v1 (linear counts, no heavy dirt
# or spray mist in its runs); the light rain of highway_spray, under the spray mist, was named rain in 0.55 of
# the frames by v2 (no isotropic part: fog and snow in the rest).
KNN_FLOORS = {"wf_knn_highway:203:20::rain3": ("rain", 0.9), "highway_clear:203:20": ("clear", 0.95),
              "wf_heldout_mixed:203:20": ("snow", 0.8), "wf_train_fog:203:20": ("fog", 0.85),
              "wf_train_snow:203:20": ("snow", 0.85), "highway_spray:204:40": ("rain", 0.7)}  # fmt: skip


@pytest.mark.parametrize("spec", sorted(KNN_FLOORS))
def test_shipped_weather_classifier_on_unseen_runs(spec, cache):
    from weather_filter.weather_class import FrameWeatherClassifier

    expected, share = KNN_FLOORS[spec]
    estimates = [FrameWeatherClassifier.load().classify(p) for p in _frames(spec, cache)]
    assert np.mean([e.weather == expected for e in estimates]) >= share, estimates
    assert all(0.0 < e.confidence <= 1.0 for e in estimates) and np.mean([e.confidence for e in estimates]) > 0.7


def test_train_from_simulation_is_reproducible(tmp_path, cache):
    from weather_filter.cli import main

    args = ["train", "--sim", "wf_train_snow:9:3", "--sim", "wf_train_clear_spray:9:3", "--seed", "4", "--cache", str(cache)]
    assert main([*args, "--out", str(tmp_path / "a.joblib")]) == 0
    assert main([*args, "--out", str(tmp_path / "b.joblib")]) == 0
    assert (tmp_path / "a.joblib").read_bytes() == (tmp_path / "b.joblib").read_bytes()
    import joblib

    bundle = joblib.load(tmp_path / "a.joblib")
    assert bundle["command"] == "weather-filter " + " ".join(args[:-4]) + " --hidden 16 --spray-weight 20.0 --solid-weight 3.0 --object-recall 0.99985 --seed 4"
    assert bundle["trained_on"] == "sim:wf_train_snow:9:3, sim:wf_train_clear_spray:9:3"


# spec -> (weather_f1, object_recall) floors of the default filter on profiles beyond scala4; measured with the
# learned v4 retrained with VLP-16 and HDL-64E runs: vlp32c (a scan pattern in no training run; snow in fog, the
# hardest held-out case) 0.965 / 0.9947, vlp16 0.979 / 0.9999. The echo filter, the default before, scored 0.51 on
# the vlp16 run.
DEFAULT_FLOORS = {"wf_heldout_mixed:203:4:vlp32c": (0.94, 0.99), "highway_spray:203:6:vlp16": (0.95, 0.998)}


@pytest.mark.parametrize("spec", sorted(DEFAULT_FLOORS))
def test_eval_without_a_method_gives_the_best_filter_on_other_profiles(spec, cache):
    """What a user who names no method gets (`weather-filter eval BAG`): the learned filter, at least the floor and
    clearly better than the echo filter on the same run."""
    import json
    import subprocess
    import sys

    bag = simulate(spec, cache)
    run = lambda *extra: subprocess.run([sys.executable, "-m", "weather_filter.cli", "eval", str(bag), *extra],  # noqa: E731
                                        capture_output=True, text=True, timeout=600, check=True).stdout  # fmt: skip
    default, echo = json.loads(run()), json.loads(run("--method", "echo"))
    f1, objects = DEFAULT_FLOORS[spec]
    assert default["method"] == "learned" and "fallback" not in default, default
    assert default["weather_f1"] >= f1 and default["object_recall"] >= objects, default
    # clearly better: at most a third of the echo filter's F1 shortfall (vlp16 run with the physical atmosphere:
    # learned 0.9997, echo 0.777; with the removed fitted atmosphere the echo filter scored 0.51)
    assert 1.0 - default["weather_f1"] <= (1.0 - echo["weather_f1"]) / 3.0, (default, echo)
