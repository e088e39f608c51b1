"""Bad input never crashes a filter or changes a result silently (weather_filter.points.cloud_check).

The reported cases one by one (a negative INT32 channel that made the learned filter write out of
bounds, a channel of 2e7 that sized a 1.5 GB image, x = 1e300 that overflowed the KD-tree's
workers, array and float fields, half a cloud at the origin), then seeded property-based fuzzing:
garbage points appended to a labelled highway frame never change the decision for a good point of
any method, and corrupted fields either filter or are refused with a message naming the field.
``FUZZ_CASES=N`` sets the number of cases per property.
"""

from __future__ import annotations

import os

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from lidar_weather_sim.io.bags import message_types
from lidar_weather_sim.io.cloud_codec import CloudFormatError, build_message, decode_message
from weather_filter.filter_methods import METHODS, make_filter
from weather_filter.points.base import MissingFieldsError
from weather_filter.points.cloud_check import MAX_CHANNELS, CloudFieldError, usable_points
from weather_filter.synthetic import highway_frame

#: Cases per property (CI: 60 each, ~30 s); FUZZ_CASES=N runs any number.
CASES = int(os.environ.get("FUZZ_CASES", "60"))


@pytest.fixture(scope="module")
def frame() -> np.ndarray:
    return highway_frame("rain", seed=3)


@pytest.fixture(scope="module")
def filters():
    return {method: make_filter(method) for method in METHODS}


@pytest.fixture(scope="module")
def small_frame(frame) -> np.ndarray:
    """Every third point of the frame (~2500): the fuzzed clouds, three times faster per case."""
    return frame[::3].copy()


@pytest.fixture(scope="module")
def clean_masks(small_frame, filters):
    """Each method's decisions on the clean small frame (every filter is deterministic after reset)."""
    return {method: _decide(filt, small_frame).remove for method, filt in filters.items()}


def _decide(filt, points):
    filt.reset()
    return filt(points)


def with_field(points: np.ndarray, name: str, dtype) -> np.ndarray:
    """``points`` with field ``name`` retyped to ``dtype`` (values cast)."""
    descr = [(n, dtype if n == name else points.dtype.fields[n][0]) for n in points.dtype.names]
    out = np.zeros(len(points), descr)
    for n in points.dtype.names:
        if n == name and np.dtype(dtype).shape:
            out[n] = np.repeat(points[n][:, None], np.dtype(dtype).shape[0], axis=1)
        else:
            out[n] = points[n]
    return out


@pytest.mark.parametrize("method", ["echo", "learned"])
@pytest.mark.parametrize("value, shown", [(-2_000_000_000, "-2000000000"), (-1, "-1"), (20_000_000, "20000000"),
                                          (MAX_CHANNELS, str(MAX_CHANNELS))])  # fmt: skip
def test_a_channel_outside_the_rings_is_refused_naming_it(frame, filters, method, value, shown):
    pts = with_field(frame, "channel", np.int32)
    pts["channel"][7] = value
    with pytest.raises(CloudFieldError, match=rf"field 'channel': value {shown} outside 0\.\.{MAX_CHANNELS - 1}"):
        _decide(filters[method], pts)


@pytest.mark.parametrize("name, dtype, match", [
    ("channel", np.float32, "field 'channel' is float32; a filter needs integers"),
    ("echo", np.float64, "field 'echo' is float64; a filter needs integers"),
    ("intensity", (np.float32, 4), "field 'intensity' holds 4 values per point; a filter reads one"),
    ("epw", (np.float32, 2), "field 'epw' holds 2 values per point"),
])  # fmt: skip
def test_fields_a_filter_cannot_read_are_refused_naming_them(frame, filters, name, dtype, match):
    pts = with_field(frame, name, dtype)
    for method in ("lior", "echo", "learned"):
        if name in filters[method].required_fields:
            with pytest.raises(CloudFieldError, match=match):
                _decide(filters[method], pts)
    assert len(_decide(filters["dror"], pts).remove) == len(pts)  # geometry only: the field is not read


@pytest.mark.parametrize("method", METHODS)
def test_far_non_finite_and_placeholder_points_are_set_aside_and_change_nothing(frame, filters, method):
    """x = 1e300 in a FLOAT64 field (overflowed the KD-tree workers), NaN and inf coordinates, and as many
    (0, 0, 0) placeholders as real points: removed, counted, and every other decision as without them."""
    frame = with_field(with_field(with_field(frame, "x", np.float64), "y", np.float64), "z", np.float64)
    clean = _decide(filters[method], frame).remove
    junk = np.repeat(frame[:1], len(frame) + 4)
    junk["x"][:4], junk["y"][:4], junk["z"][:4] = [1e300, np.nan, np.inf, 2e4], 0.0, [0.0, 1.0, -np.inf, 3.0]
    junk["x"][4:] = junk["y"][4:] = junk["z"][4:] = 0.0
    order = np.random.default_rng(5).permutation(len(frame) + len(junk))
    mixed = np.concatenate([frame, junk])[order]
    result = _decide(filters[method], mixed)
    is_junk = order >= len(frame)
    assert result.set_aside == len(junk) and result.remove[is_junk].all()
    np.testing.assert_array_equal(result.remove[~is_junk], clean[order[~is_junk]])


def test_usable_points_counts_each_cause():
    pts = np.zeros(6, [("x", "f4"), ("y", "f4"), ("z", "f4")])
    pts["x"] = [1.0, np.nan, 1e5, 0.0, 2.0, -np.inf]
    _, usable = usable_points(pts, frozenset({"x", "y", "z"}))
    assert usable.keep.tolist() == [True, False, False, False, True, False]
    assert (usable.non_finite, usable.out_of_reach, usable.at_origin) == (2, 1, 1)


_coordinate = st.one_of(st.floats(allow_nan=True, allow_infinity=True, width=32), st.sampled_from([0.0, 1e30, -1e30]))


@settings(max_examples=CASES, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(garbage=st.lists(st.tuples(_coordinate, _coordinate, _coordinate), min_size=1, max_size=40),
       at=st.integers(0, 10**6))  # fmt: skip
def test_fuzz_garbage_points_never_change_a_good_points_decision(small_frame, filters, clean_masks, garbage, at):
    """Any points with a non-finite, out-of-reach or all-zero position, inserted anywhere: each method
    decides every good point as on the clean frame."""
    xyz = np.array(garbage, dtype=np.float64)
    with np.errstate(invalid="ignore", over="ignore"):
        xyz32 = xyz.astype(np.float32)
    bad = ~np.isfinite(xyz32).all(axis=1) | (np.abs(xyz32) > 1e4).any(axis=1) | (xyz32 == 0).all(axis=1)
    if not bad.any():
        return
    junk = np.repeat(small_frame[:1], int(bad.sum()))
    junk["x"], junk["y"], junk["z"] = xyz32[bad].T
    k = at % (len(small_frame) + 1)
    mixed = np.concatenate([small_frame[:k], junk, small_frame[k:]])
    is_junk = np.zeros(len(mixed), bool)
    is_junk[k : k + len(junk)] = True
    for method, filt in filters.items():
        result = _decide(filt, mixed)
        assert result.remove[is_junk].all() and result.set_aside == len(junk), method
        np.testing.assert_array_equal(result.remove[~is_junk], clean_masks[method], err_msg=method)


_FIELDS = ("x", "y", "z", "intensity", "channel", "echo", "epw")
_DTYPES = ("i1", "u1", "i2", "u2", "i4", "u4", "i8", "f4", "f8", ("f4", 3), ("i4", 2))


@settings(max_examples=CASES, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(name=st.sampled_from(_FIELDS), dtype=st.sampled_from(_DTYPES), seed=st.integers(0, 2**32 - 1),
       share=st.floats(0.0, 1.0))  # fmt: skip
def test_fuzz_corrupted_fields_filter_or_are_refused_naming_the_field(small_frame, filters, name, dtype, seed, share):
    """A field retyped and a share of its values replaced by random bits of that type, sent through the
    PointCloud2 encoder and decoder the node uses (where the type has a PointField datatype): every method
    either filters (a mask per point) or raises CloudFieldError / MissingFieldsError naming a field."""
    pts = with_field(small_frame, name, dtype)
    rng = np.random.default_rng(seed)
    hit = rng.random(len(pts)) < share
    raw = rng.integers(0, 256, (int(hit.sum()), pts.dtype.fields[name][0].itemsize), dtype=np.uint8)
    pts[name][hit] = raw.view(pts.dtype.fields[name][0].base).reshape(pts[name][hit].shape)
    if pts.dtype.fields[name][0].base.itemsize < 8 or pts.dtype.fields[name][0].base.kind == "f":  # no INT64 datatype
        try:
            msg, _ = build_message(pts, stamp_ns=0, frame_id="lidar", types=message_types())
            pts = decode_message(msg).points
        except CloudFormatError as exc:
            assert f"'{name}'" in str(exc) or "field" in str(exc), str(exc)
            return
    for method, filt in filters.items():
        try:
            with np.errstate(all="ignore"):
                result = _decide(filt, pts)
        except (CloudFieldError, MissingFieldsError) as exc:
            assert f"field '{name}'" in str(exc), (method, str(exc))
            continue
        assert result.remove.shape == (len(pts),) and result.remove.dtype == bool, method


@pytest.mark.slow
def test_eval_refuses_a_bag_with_an_unusable_field_in_one_line(tmp_path, frame):
    """``weather-filter eval`` on a bag whose second cloud has a negative INT32 channel: exit 2, one line
    naming the bag, the frame and the field, no result written."""
    import subprocess
    import sys

    from lidar_weather_sim.io.bags import BagWriter

    pts = with_field(frame, "channel", np.int32)
    bad = pts.copy()
    bad["channel"][3] = -5
    bag = tmp_path / "bag"
    with BagWriter(bag) as writer:
        for i, cloud in enumerate((pts, bad)):
            writer.write_cloud("/lidar/points", cloud, stamp_ns=i * 40_000_000, frame_id="lidar")
    out = tmp_path / "r.json"
    proc = subprocess.run([sys.executable, "-m", "weather_filter.cli", "eval", str(bag), "--method", "learned",
                           "--out", str(out)], capture_output=True, text=True, timeout=300)  # fmt: skip
    assert proc.returncode == 2, proc.stderr
    assert proc.stderr.strip().splitlines() == [
        f"weather-filter eval: error: {bag}: frame 1: field 'channel': value -5 outside 0..{MAX_CHANNELS - 1}"]
    assert not out.exists()


@pytest.mark.parametrize("dtype, match", [((np.uint8, 2), "field 'label' holds 2 values per point"),
                                          (np.float32, "field 'label' is float32; a filter needs integers")])
def test_eval_refuses_a_label_it_cannot_score_by(frame, dtype, match):
    """The label is what eval scores by: an array or float label is named, not scored into nonsense."""
    from weather_filter.evaluate import evaluate_frames

    with pytest.raises(CloudFieldError, match=rf"frame 1: {match}"):
        evaluate_frames(make_filter("dror"), [frame, with_field(frame, "label", dtype)])
