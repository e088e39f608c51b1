"""PointCloud2 body encoding/decoding: round trips, foreign layouts, and named rejections."""

from types import SimpleNamespace

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from lidar_weather_sim.core.points import empty_points, point_dtype
from lidar_weather_sim.io.cloud_codec import (
    DATATYPE_TO_DTYPE,
    FLOAT32,
    UINT16,
    CloudFormatError,
    decode,
    encode,
)


def _decode_body(body, **overrides):
    kwargs = dict(
        fields=body.fields,
        width=body.width,
        height=1,
        point_step=body.point_step,
        row_step=body.row_step,
        data=body.data,
        is_bigendian=False,
    )
    kwargs.update(overrides)
    return decode(**kwargs)


def _random_points(n, ground_truth, seed=0):
    rng = np.random.default_rng(seed)
    points = empty_points(n, ground_truth)
    for name in points.dtype.names:
        kind = points.dtype.fields[name][0]
        if kind.kind == "f":
            points[name] = rng.normal(0, 50, n)
        else:
            points[name] = rng.integers(0, np.iinfo(kind).max, n, endpoint=True, dtype=kind)
    return points


@pytest.mark.parametrize("ground_truth", [True, False])
def test_every_field_round_trips(ground_truth):
    points = _random_points(1000, ground_truth)
    body = encode(points)
    assert body.point_step == (44 if ground_truth else 40)
    assert len(body.data) == 1000 * body.point_step
    decoded = _decode_body(body)
    assert decoded.dropped_nonfinite == 0
    assert decoded.points.dtype == point_dtype(ground_truth)
    for name in points.dtype.names:
        np.testing.assert_array_equal(decoded.points[name], points[name], err_msg=name)


def test_the_same_points_give_the_same_bytes_whatever_their_padding_held():
    """The bytes between fields (2 per point of the ground-truth layout) are written as 0, not as whatever memory
    an ``np.empty`` array or a structured ``astype`` left there; the caller's field values are untouched."""
    points = _random_points(500, True)
    dirty = np.frombuffer(np.random.default_rng(3).bytes(points.nbytes), points.dtype).copy()
    for name in points.dtype.names:
        dirty[name] = points[name]
    clean = np.zeros(len(points), points.dtype)
    for name in points.dtype.names:
        clean[name] = points[name]
    assert dirty.tobytes() != clean.tobytes()
    assert encode(dirty).data == encode(clean).data == clean.tobytes()
    read_only = dirty.copy()
    read_only.flags.writeable = False
    assert encode(read_only).data == clean.tobytes()


def test_nonfinite_points_are_dropped_and_counted_on_encode_and_decode():
    points = _random_points(10, True)
    points["x"][2] = np.nan
    points["z"][7] = np.inf
    body = encode(points)
    assert (body.width, body.dropped_nonfinite) == (8, 2)
    kept = encode(points, drop_nonfinite=False)
    decoded = _decode_body(kept)
    assert (len(decoded.points), decoded.dropped_nonfinite) == (8, 2)
    assert len(_decode_body(kept, nan_policy="keep").points) == 10
    with pytest.raises(CloudFormatError, match="2 points with non-finite"):
        _decode_body(kept, nan_policy="reject")


def test_reads_a_velodyne_style_organised_cloud_with_padding():
    # velodyne_pointcloud's XYZIRT: x y z, 4 pad, intensity f32 at 16, ring u16 at 20, time f32 at 24, step 32;
    # organised 2 x 3 with 8 bytes of padding at the end of each row.
    fields = [
        SimpleNamespace(name="x", offset=0, datatype=FLOAT32, count=1),
        SimpleNamespace(name="y", offset=4, datatype=FLOAT32, count=1),
        SimpleNamespace(name="z", offset=8, datatype=FLOAT32, count=1),
        SimpleNamespace(name="intensity", offset=16, datatype=FLOAT32, count=1),
        SimpleNamespace(name="ring", offset=20, datatype=UINT16, count=1),
        SimpleNamespace(name="time", offset=24, datatype=FLOAT32, count=1),
    ]
    width, height, step, row_step = 3, 2, 32, 3 * 32 + 8
    raw = bytearray(row_step * height)
    for row in range(height):
        for col in range(width):
            i = row * width + col
            base = row * row_step + col * step
            raw[base : base + 12] = np.array([i, -i, 0.5 * i], "<f4").tobytes()
            raw[base + 16 : base + 20] = np.array([10.0 * i], "<f4").tobytes()
            raw[base + 20 : base + 22] = np.array([row], "<u2").tobytes()
            raw[base + 24 : base + 28] = np.array([1e-3 * i], "<f4").tobytes()
    cloud = decode(fields=fields, width=width, height=height, point_step=step, row_step=row_step, data=bytes(raw))
    np.testing.assert_array_equal(cloud.points["x"], np.arange(6, dtype=np.float32))
    np.testing.assert_array_equal(cloud.points["y"], -np.arange(6, dtype=np.float32))
    np.testing.assert_array_equal(cloud.points["ring"], [0, 0, 0, 1, 1, 1])
    np.testing.assert_allclose(cloud.points["time"], 1e-3 * np.arange(6), rtol=1e-6)


def _field(name, offset, datatype=FLOAT32, count=1):
    return SimpleNamespace(name=name, offset=offset, datatype=datatype, count=count)


XYZ = [_field("x", 0), _field("y", 4), _field("z", 8)]


@pytest.mark.parametrize(
    "fields, point_step, kwargs, reason",
    [
        (XYZ[:2], 12, {}, "missing field 'z'"),
        (XYZ + [_field("rgb", 12, datatype=9)], 16, {}, "field 'rgb': unknown PointField datatype 9"),
        (XYZ + [_field("t", 12, datatype=7, count=2)], 16, {}, "field 't' spans bytes 12-20, beyond point_step 16"),
        (XYZ + [_field("x", 12)], 16, {}, "field 'x' appears twice"),
        ([_field("x", 0), _field("y", 2), _field("z", 8)], 12, {}, "fields 'x' and 'y' overlap (bytes 2-4)"),
        (XYZ + [_field("t", 10, datatype=7)], 16, {}, "fields 'z' and 't' overlap (bytes 10-12)"),
        (XYZ, 12, {"is_bigendian": True}, "big-endian"),
        (XYZ, 12, {"data": bytes(12 * 4 - 1)}, "data length 47 != row_step 48"),
        (XYZ, 12, {"row_step": 40}, "row_step 40 is smaller than width 4 * point_step 12"),
        (XYZ, 0, {}, "point_step 0 must be positive"),
    ],
)
def test_malformed_clouds_are_rejected_with_the_reason(fields, point_step, kwargs, reason):
    args = dict(fields=fields, width=4, height=1, point_step=point_step, row_step=4 * point_step,
                data=bytes(4 * point_step))  # fmt: skip
    args.update(kwargs)
    with pytest.raises(CloudFormatError) as err:
        decode(**args)
    assert reason in str(err.value)


# Property-based: any little-endian layout a driver may produce decodes to the values written.
_datatypes = st.sampled_from(sorted(DATATYPE_TO_DTYPE))


@st.composite
def _layouts(draw):
    extra = draw(st.lists(st.tuples(_datatypes, st.integers(1, 3)), max_size=5))
    specs = [(name, FLOAT32, 1) for name in ("x", "y", "z")] + [(f"f{i}", dt, c) for i, (dt, c) in enumerate(extra)]
    order = draw(st.permutations(specs))
    offset, fields = 0, []
    for name, datatype, count in order:
        offset += draw(st.integers(0, 4))  # padding before the field
        fields.append(_field(name, offset, datatype, count))
        offset += DATATYPE_TO_DTYPE[datatype].itemsize * count
    point_step = offset + draw(st.integers(0, 8))
    return fields, point_step


@settings(max_examples=200, deadline=None)
@given(layout=_layouts(), width=st.integers(0, 20), height=st.integers(1, 3), row_pad=st.integers(0, 16),
       seed=st.integers(0, 2**32 - 1))  # fmt: skip
def test_any_layout_decodes_the_values_written(layout, width, height, row_pad, seed):
    fields, point_step = layout
    rng = np.random.default_rng(seed)
    row_step = width * point_step + row_pad
    raw = bytearray(rng.integers(0, 256, row_step * height, dtype=np.uint8).tobytes())
    expected = {}
    for f in fields:
        dt = DATATYPE_TO_DTYPE[f.datatype]
        values = rng.uniform(-100, 100, (height, width, f.count)) if dt.kind == "f" else \
            rng.integers(np.iinfo(dt).min, np.iinfo(dt).max, (height, width, f.count), endpoint=True)  # fmt: skip
        values = values.astype(dt)
        expected[f.name] = values.reshape(-1, f.count)
        for r in range(height):
            for c in range(width):
                base = r * row_step + c * point_step + f.offset
                raw[base : base + dt.itemsize * f.count] = values[r, c].tobytes()
    cloud = decode(fields=fields, width=width, height=height, point_step=point_step, row_step=row_step,
                   data=bytes(raw), nan_policy="keep")  # fmt: skip
    assert len(cloud.points) == width * height
    for name, values in expected.items():
        got = cloud.points[name].reshape(values.shape)
        np.testing.assert_array_equal(got, values, err_msg=name)


@settings(max_examples=200, deadline=None)
@given(layout=_layouts(), cut=st.integers(1, 64))
def test_truncated_data_is_always_rejected_by_length(layout, cut):
    fields, point_step = layout
    data = bytes(max(0, 5 * point_step - cut))
    with pytest.raises(CloudFormatError, match="data length"):
        decode(fields=fields, width=5, height=1, point_step=point_step, row_step=5 * point_step, data=data)
