"""Foxglove messages of clouds, transforms and actors (io.foxglove_messages), read back from their protobuf bytes."""

import struct
from types import SimpleNamespace as NS

import numpy as np
import pytest

from lidar_weather_sim.core.points import empty_points, point_dtype
from lidar_weather_sim.io.foxglove_messages import (
    DEFAULT_ACTOR_SIZE_M,
    actor_ids,
    actor_scene,
    frame_transforms,
    point_cloud,
    timestamp,
)
from lidar_weather_sim.testing.foxglove_wire import decode_point_cloud, message_data, protobuf_fields


def _cloud(n, ground_truth=True, seed=0):
    rng = np.random.default_rng(seed)
    points = empty_points(n, ground_truth)
    for name in points.dtype.names:
        kind = points.dtype.fields[name][0]
        points[name] = rng.uniform(-80, 80, n) if kind.kind == "f" else rng.integers(0, np.iinfo(kind).max, n, dtype=kind)
    return points


@pytest.mark.parametrize("ground_truth", [True, False])
def test_point_cloud_sends_the_project_layout_as_it_is(ground_truth):
    points = _cloud(1000, ground_truth)
    decoded = decode_point_cloud(point_cloud(points, 12_345_678_901, "lidar").encode())
    assert decoded.frame_id == "lidar" and decoded.stamp_ns == 12_345_678_901
    assert decoded.point_stride == point_dtype(ground_truth).itemsize == (44 if ground_truth else 40)
    assert list(decoded.fields) == list(points.dtype.names)
    assert decoded.fields["x"] == (0, 7) and decoded.fields["y"] == (4, 7) and decoded.fields["z"] == (8, 7)  # float32
    assert decoded.fields["channel"] == (14, 3) and decoded.fields["intensity"] == (12, 1)  # uint16, uint8
    assert len(decoded.points) == 1000
    for name in points.dtype.names:
        np.testing.assert_array_equal(decoded.points[name], points[name])


def test_point_cloud_of_a_foreign_layout_keeps_the_fields_foxglove_can_describe():
    dtype = np.dtype([("t", "<i8"), ("x", ">f4"), ("y", "<f8"), ("z", "<f4"), ("ok", "?"), ("ring", "<u2")])
    points = np.zeros(7, dtype)
    points["x"], points["y"], points["z"], points["ring"] = np.arange(7) * 1.5, -np.arange(7), 2.0, np.arange(7) + 100
    decoded = decode_point_cloud(point_cloud(points[::2], 0, "velodyne").encode())  # strided view, big-endian x
    assert list(decoded.fields) == ["x", "y", "z", "ring"]  # int64 and bool left out
    assert decoded.point_stride == 4 + 8 + 4 + 2
    np.testing.assert_array_equal(decoded.points["x"], [0.0, 3.0, 6.0, 9.0])
    np.testing.assert_array_equal(decoded.points["y"], [0.0, -2.0, -4.0, -6.0])
    np.testing.assert_array_equal(decoded.points["ring"], [100, 102, 104, 106])


def test_point_cloud_of_nothing_and_refusals():
    empty = decode_point_cloud(point_cloud(empty_points(0), 5, "lidar").encode())
    assert len(empty.points) == 0 and empty.stamp_ns == 5 and "x" in empty.fields
    with pytest.raises(ValueError, match="lacks numeric field"):
        point_cloud(np.zeros(3, [("x", "<f4"), ("y", "<f4")]), 0, "lidar")
    with pytest.raises(ValueError, match="lacks numeric field.* z"):
        point_cloud(np.zeros(3, [("x", "<f4"), ("y", "<f4"), ("z", "<i8")]), 0, "lidar")
    with pytest.raises(ValueError, match="structured array"):
        point_cloud(np.zeros((3, 3), np.float32), 0, "lidar")
    with pytest.raises(ValueError, match="before 0"):
        timestamp(-1)


def _ts(parent, child, sec, nanosec, t, q):
    return NS(header=NS(frame_id=parent, stamp=NS(sec=sec, nanosec=nanosec)), child_frame_id=child,
              transform=NS(translation=NS(x=t[0], y=t[1], z=t[2]), rotation=NS(x=q[0], y=q[1], z=q[2], w=q[3])))  # fmt: skip


def _double(raw: bytes) -> float:
    return struct.unpack("<d", raw)[0]


def test_frame_transforms_keep_good_transforms_and_name_the_bad_ones():
    msg = NS(transforms=[
        _ts("map", "base_link", 3, 500, (1.0, 2.0, 0.5), (0.0, 0.0, 0.0, 2.0)),  # normalised to identity
        _ts("map", "actor_7", 3, 400, (float("nan"), 0.0, 0.0), (0, 0, 0, 1)),
        _ts("base_link", "lidar", 3, 600, (1.2, 0.0, 1.8), (0.0, 0.0, 0.0, 0.0)),
        _ts("/map", "/actor_2", 3, 700, (10.0, -3.5, 0.0), (0.0, 0.0, 0.6, 0.8)),
    ])  # fmt: skip
    tfs, latest_ns, rejected = frame_transforms(msg)
    assert latest_ns == 3_000_000_700
    assert len(rejected) == 2 and "actor_7" in rejected[0] and "zero quaternion" in rejected[1]
    items = [protobuf_fields(raw) for raw in protobuf_fields(tfs.encode())[1]]
    assert [(i[2][0], i[3][0]) for i in items] == [(b"map", b"base_link"), (b"map", b"actor_2")]
    stamp = protobuf_fields(items[1][1][0])
    assert (stamp[1][0], stamp[2][0]) == (3, 700)
    translation = protobuf_fields(items[1][4][0])
    assert [_double(translation[k][0]) for k in (1, 2)] == [10.0, -3.5] and 3 not in translation  # z = 0 not sent
    rotation = protobuf_fields(items[0][5][0])
    assert _double(rotation[4][0]) == 1.0 and not ({1, 2, 3} & set(rotation))  # w = 1 after normalising
    assert actor_ids(msg) == [7, 2]


def test_actor_scene_boxes_stand_in_their_actor_frames():
    update = protobuf_fields(actor_scene([3, 1], 2_000_000_000, {1: (12.0, 2.5, 3.8)}, lifetime_s=2.5).encode())
    entities = [protobuf_fields(raw) for raw in update[2]]
    assert [e[2][0] for e in entities] == [b"actor_3", b"actor_1"]  # frame_id
    assert [e[3][0] for e in entities] == [b"actor_3", b"actor_1"]  # id
    for entity, (length, width, height) in zip(entities, [DEFAULT_ACTOR_SIZE_M, (12.0, 2.5, 3.8)]):
        assert entity[5] == [1] and entity[13]  # frame_locked, a text
        lifetime = protobuf_fields(entity[4][0])
        assert (lifetime[1][0], lifetime[2][0]) == (2, 500_000_000)
        cube = protobuf_fields(entity[8][0])  # SceneEntity.cubes
        size = protobuf_fields(cube[2][0])
        assert [_double(size[k][0]) for k in (1, 2, 3)] == [length, width, height]
        centre = protobuf_fields(protobuf_fields(cube[1][0])[1][0])
        assert _double(centre[3][0]) == pytest.approx(0.5 * height)  # on the road: half its height up


def test_message_data_frames():
    frame = bytes([1]) + struct.pack("<IQ", 9, 1_234_567_890_123) + b"payload"
    assert message_data(frame) == (9, 1_234_567_890_123, b"payload")
    with pytest.raises(ValueError, match="not a Message Data frame"):
        message_data(bytes([2]) + frame[1:])
