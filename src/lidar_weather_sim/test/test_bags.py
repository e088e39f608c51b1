"""Bags: write -> read round trips, info, errors, signal-safe closing and recovery after SIGKILL."""

from __future__ import annotations

import array
import dataclasses
import importlib.util
import os
import shutil
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np
import pytest
from mcap.reader import make_reader

from lidar_weather_sim.core.names import FRAME_LIDAR, TOPIC_POINTS, TOPIC_TF
from lidar_weather_sim.core.points import POINT_DTYPE, empty_points
from lidar_weather_sim.io.bags import (
    BagError,
    BagWriter,
    bag_info,
    format_info,
    message_types,
    read_clouds,
    read_messages,
    recover,
    typestore,
)
from lidar_weather_sim.io.cloud_codec import MessageTypes, build_message, fields_from_dtype

CHILD = Path(__file__).with_name("bag_writer_child.py")
TOPIC_CHATTER = "/chatter"
T0 = 1_700_000_000_000_000_000


def _load_child():
    spec = importlib.util.spec_from_file_location("bag_writer_child", CHILD)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def random_points(rng: np.random.Generator, n: int) -> np.ndarray:
    points = empty_points(n)
    for name in POINT_DTYPE.names:
        kind = POINT_DTYPE[name]
        if kind.kind == "f":
            points[name] = rng.uniform(-100, 100, n)
        else:
            points[name] = rng.integers(0, np.iinfo(kind).max, n, dtype=kind, endpoint=True)
    return points


def _types():
    return typestore().types


def tf_message(i: int):
    t = _types()
    transform = t["geometry_msgs/msg/TransformStamped"](
        header=t["std_msgs/msg/Header"](stamp=t["builtin_interfaces/msg/Time"](sec=i, nanosec=7), frame_id="base_link"),
        child_frame_id=FRAME_LIDAR,
        transform=t["geometry_msgs/msg/Transform"](
            translation=t["geometry_msgs/msg/Vector3"](x=1.5 + i, y=0.0, z=2.0),
            rotation=t["geometry_msgs/msg/Quaternion"](x=0.0, y=0.0, z=0.0, w=1.0),
        ),
    )
    return t["tf2_msgs/msg/TFMessage"](transforms=[transform])


def string_message(text: str):
    return _types()["std_msgs/msg/String"](data=text)


def write_sample_bag(path: Path, storage: str = "mcap", seed: int = 0) -> list[tuple[int, int, np.ndarray]]:
    """3 clouds (one empty), 2 TF and 2 String messages, interleaved; returns (log, stamp, points) of clouds."""
    rng = np.random.default_rng(seed)
    clouds = []
    with BagWriter(path, storage=storage) as writer:
        for i, n in enumerate((100, 0, 257)):
            log = T0 + i * 100_000_000
            stamp = log - 3_000_123
            points = random_points(rng, n)
            assert writer.write_cloud(TOPIC_POINTS, points, stamp, FRAME_LIDAR, log_time_ns=log) == 0
            clouds.append((log, stamp, points))
            if i < 2:
                writer.write(TOPIC_TF, tf_message(i), log + 10)
                writer.write(TOPIC_CHATTER, string_message(f"hello {i}"), log + 20)
    return clouds


def assert_points_equal(got: np.ndarray, want: np.ndarray) -> None:
    assert got.dtype == POINT_DTYPE
    assert len(got) == len(want)
    for name in POINT_DTYPE.names:
        np.testing.assert_array_equal(got[name], want[name], err_msg=name)


@pytest.mark.parametrize("storage", ["mcap", "sqlite3"])
def test_write_read_round_trip(tmp_path, storage):
    bag = tmp_path / "bag"
    clouds = write_sample_bag(bag, storage)
    assert (bag / "metadata.yaml").exists()

    frames = list(read_clouds(bag))
    assert [(f.log_time_ns, f.stamp_ns, f.frame_id) for f in frames] == [(c[0], c[1], FRAME_LIDAR) for c in clouds]
    for frame, (_, _, points) in zip(frames, clouds):
        assert_points_equal(frame.points, points)
        assert frame.dropped_nonfinite == 0

    messages = list(read_messages(bag))
    assert [m.log_time_ns for m in messages] == sorted(m.log_time_ns for m in messages)
    assert [m.topic for m in messages].count(TOPIC_POINTS) == 3
    tf = [m for m in messages if m.topic == TOPIC_TF]
    assert [m.msgtype for m in tf] == ["tf2_msgs/msg/TFMessage"] * 2
    assert [m.msg.transforms[0].transform.translation.x for m in tf] == [1.5, 2.5]
    assert [m.msg.transforms[0].child_frame_id for m in tf] == [FRAME_LIDAR] * 2
    assert [m.log_time_ns for m in tf] == [T0 + 10, T0 + 100_000_010]
    chatter = list(read_messages(bag, topics=[TOPIC_CHATTER]))
    assert [(m.msg.data, m.log_time_ns) for m in chatter] == [("hello 0", T0 + 20), ("hello 1", T0 + 100_000_020)]


def test_write_cloud_drops_nonfinite_and_defaults_log_time_to_stamp(tmp_path):
    points = random_points(np.random.default_rng(1), 10)
    points["x"][[2, 5]] = np.nan
    with BagWriter(tmp_path / "bag") as writer:
        assert writer.write_cloud(TOPIC_POINTS, points, T0, FRAME_LIDAR) == 2
    (frame,) = read_clouds(tmp_path / "bag")
    assert frame.log_time_ns == frame.stamp_ns == T0
    assert_points_equal(frame.points, np.delete(points, [2, 5]))


def test_bare_mcap_file_is_accepted(tmp_path):
    clouds = write_sample_bag(tmp_path / "bag")
    bare = tmp_path / "copy.mcap"
    shutil.copy(tmp_path / "bag" / "bag.mcap", bare)
    for path in (bare, tmp_path / "bag" / "bag.mcap"):
        info = bag_info(path)
        assert (info.storage, info.message_count, info.damaged) == ("mcap", 7, False)
        assert len(list(read_messages(path))) == 7
        assert_points_equal(list(read_clouds(path))[2].points, clouds[2][2])


@pytest.mark.parametrize("storage", ["mcap", "sqlite3"])
def test_bag_info_and_format_info(tmp_path, storage):
    clouds = write_sample_bag(tmp_path / "bag", storage)
    info = bag_info(tmp_path / "bag")
    assert (info.storage, info.message_count, info.damaged) == (storage, 7, False)
    assert (info.start_ns, info.end_ns) == (T0, clouds[-1][0])
    assert info.duration_s == pytest.approx(0.2)
    topics = {t.name: t for t in info.topics}
    assert {n: (t.msgtype, t.count) for n, t in topics.items()} == {
        TOPIC_POINTS: ("sensor_msgs/msg/PointCloud2", 3),
        TOPIC_TF: ("tf2_msgs/msg/TFMessage", 2),
        TOPIC_CHATTER: ("std_msgs/msg/String", 2),
    }
    expected = [(f.name, f.offset, f.datatype, f.count) for f in fields_from_dtype(POINT_DTYPE)]
    assert topics[TOPIC_POINTS].pointcloud_fields == expected
    assert topics[TOPIC_TF].pointcloud_fields is None

    text = format_info(info)
    for needle in (TOPIC_POINTS, TOPIC_TF, TOPIC_CHATTER, "object_id", "label", "uint32", "3 messages", "0.200 s"):
        assert needle in text


def test_unknown_or_non_cloud_topic_lists_existing_topics(tmp_path):
    write_sample_bag(tmp_path / "bag")
    for topic in ("/nope", TOPIC_CHATTER):
        with pytest.raises(BagError) as err:
            read_clouds(tmp_path / "bag", topic=topic)
        for needle in (str(tmp_path / "bag"), topic, TOPIC_POINTS, TOPIC_TF, TOPIC_CHATTER):
            assert needle in str(err.value)


def test_missing_path_and_existing_output(tmp_path):
    missing = tmp_path / "missing"
    for call in (bag_info, read_messages, read_clouds, recover):
        with pytest.raises(BagError, match=str(missing)):
            call(missing)
    write_sample_bag(tmp_path / "bag")
    with pytest.raises(BagError, match=str(tmp_path / "bag")):
        BagWriter(tmp_path / "bag")
    assert bag_info(tmp_path / "bag").message_count == 7
    with BagWriter(tmp_path / "bag", overwrite=True) as writer:
        writer.write(TOPIC_CHATTER, string_message("new"), T0)
    assert [m.msg.data for m in read_messages(tmp_path / "bag")] == ["new"]
    (tmp_path / "notabag").mkdir()
    (tmp_path / "notabag" / "keep.txt").write_text("x")
    with pytest.raises(BagError, match="not a bag"):
        BagWriter(tmp_path / "notabag", overwrite=True)
    assert (tmp_path / "notabag" / "keep.txt").exists()


def test_malformed_cloud_names_topic_index_and_reason(tmp_path):
    points = random_points(np.random.default_rng(2), 4)
    types = dataclasses.replace(message_types(), data=lambda body: np.frombuffer(body[:-3], np.uint8))
    bad, _ = build_message(points, stamp_ns=T0, frame_id=FRAME_LIDAR, types=types)
    with BagWriter(tmp_path / "bag") as writer:
        writer.write_cloud(TOPIC_POINTS, points, T0, FRAME_LIDAR)
        writer.write(TOPIC_POINTS, bad, T0 + 1)
    frames = read_clouds(tmp_path / "bag")
    assert len(next(frames).points) == 4
    with pytest.raises(BagError) as err:
        next(frames)
    for needle in (str(tmp_path / "bag"), TOPIC_POINTS, "message 1", "data length"):
        assert needle in str(err.value)


def test_close_is_idempotent_and_signal_chains_to_previous_handler(tmp_path):
    calls = []
    previous = signal.signal(signal.SIGTERM, lambda signum, frame: calls.append(signum))
    try:
        writer = BagWriter(tmp_path / "bag")
        writer.write(TOPIC_CHATTER, string_message("a"), T0)
        os.kill(os.getpid(), signal.SIGTERM)
        assert calls == [signal.SIGTERM]
        assert (tmp_path / "bag" / "metadata.yaml").exists()
        assert signal.getsignal(signal.SIGTERM) is not None and signal.getsignal(signal.SIGTERM) != writer._on_signal
        writer.close()
        with pytest.raises(BagError, match="closed"):
            writer.write(TOPIC_CHATTER, string_message("b"), T0 + 1)
    finally:
        signal.signal(signal.SIGTERM, previous)
    assert [m.msg.data for m in read_messages(tmp_path / "bag")] == ["a"]


def test_signal_waits_for_a_write_in_another_thread(tmp_path):
    calls, outcome, written = [], [], []
    previous = signal.signal(signal.SIGTERM, lambda signum, frame: calls.append(signum))
    points = random_points(np.random.default_rng(4), 5000)
    msg, _ = build_message(points, stamp_ns=T0, frame_id=FRAME_LIDAR, types=message_types())
    data = typestore().serialize_cdr(msg, msg.__msgtype__)

    def record(writer: BagWriter) -> None:
        try:
            while True:  # nearly all time is spent inside the writer, where the signal must wait
                writer.write_serialized(TOPIC_POINTS, msg.__msgtype__, data, T0 + len(written))
                written.append(1)
        except BagError as err:
            outcome.append(str(err))

    try:
        writer = BagWriter(tmp_path / "bag")
        worker = threading.Thread(target=record, args=(writer,))
        worker.start()
        while len(written) < 20:
            time.sleep(0.001)
        os.kill(os.getpid(), signal.SIGTERM)
        worker.join(timeout=10)
    finally:
        signal.signal(signal.SIGTERM, previous)
    assert calls == [signal.SIGTERM] and len(outcome) == 1 and "closed" in outcome[0]
    assert bag_info(tmp_path / "bag").message_count == len(written) >= 20


def test_exit_without_close_finishes_bag(tmp_path):
    out = tmp_path / "bag"
    subprocess.run([sys.executable, str(CHILD), str(out), "mcap", "5"], check=True, timeout=60)
    info = bag_info(out)
    assert (info.message_count, info.damaged) == (5, False)
    assert (out / "metadata.yaml").exists()


def _start_child(processes, out: Path, storage: str):
    proc = processes.start(sys.executable, str(CHILD), str(out), storage)
    deadline = time.monotonic() + 20
    while "ready" not in processes.output(proc):
        assert proc.poll() is None, processes.output(proc)
        assert time.monotonic() < deadline, "child never became ready"
        time.sleep(0.05)
    return proc


@pytest.mark.parametrize("storage", ["mcap", "sqlite3"])
@pytest.mark.parametrize("signum", [signal.SIGTERM, signal.SIGINT])
def test_signal_closes_bag(tmp_path, processes, storage, signum):
    out = tmp_path / "bag"
    proc = _start_child(processes, out, storage)
    proc.send_signal(signum)
    proc.wait(timeout=20)
    expected = {signal.SIGTERM: (143,), signal.SIGINT: (-signal.SIGINT, 128 + signal.SIGINT)}[signum]
    assert proc.returncode in expected, processes.output(proc)
    assert (out / "metadata.yaml").exists()
    info = bag_info(out)
    assert not info.damaged and info.message_count >= 4
    child = _load_child()
    frames = list(read_clouds(out))
    assert len(frames) == info.message_count
    for i, frame in enumerate(frames):
        assert frame.log_time_ns == child.log_time_ns(i)
    assert_points_equal(frames[-1].points, child.make_points(len(frames) - 1))


def test_sigkill_then_recover(tmp_path, processes):
    out = tmp_path / "bag"
    mcap_file = out / "bag.mcap"
    proc = _start_child(processes, out, "mcap")
    deadline = time.monotonic() + 20
    while mcap_file.stat().st_size < 3 * 2**20:  # at least two 1 MiB chunks flushed
        assert time.monotonic() < deadline, "child wrote too little"
        time.sleep(0.02)
    proc.send_signal(signal.SIGKILL)
    proc.wait(timeout=10)
    assert not (out / "metadata.yaml").exists()
    damaged_bytes = mcap_file.read_bytes()

    damaged_info = bag_info(out)  # read transparently, without recovering
    assert damaged_info.damaged and damaged_info.message_count > 0
    assert "recover" in format_info(damaged_info)

    report = recover(out)
    assert report.messages_recovered == damaged_info.message_count > 0
    assert report.topics == [TOPIC_POINTS] and report.output == out
    assert report.damaged_copy == tmp_path / "bag.damaged"
    assert (tmp_path / "bag.damaged" / "bag.mcap").read_bytes() == damaged_bytes
    assert (out / "metadata.yaml").exists()
    with mcap_file.open("rb") as stream:
        summary = make_reader(stream).get_summary()
    assert summary is not None and summary.statistics.message_count == report.messages_recovered
    assert not bag_info(out).damaged

    child = _load_child()
    frames = list(read_clouds(out))
    assert len(frames) == report.messages_recovered
    for i, frame in enumerate(frames):
        assert (frame.log_time_ns, frame.stamp_ns) == (child.log_time_ns(i), child.log_time_ns(i) - child.STAMP_LAG_NS)
        assert_points_equal(frame.points, child.make_points(i))
    assert recover(out).damaged_copy is None  # an intact bag is left alone


def test_truncated_bare_mcap_is_read_and_recovered(tmp_path):
    write_sample_bag(tmp_path / "bag")
    data = (tmp_path / "bag" / "bag.mcap").read_bytes()
    bare = tmp_path / "cut.mcap"
    bare.write_bytes(data[:-50])  # loses the footer and part of the summary
    assert bag_info(bare).damaged
    assert len(list(read_messages(bare))) == 7
    report = recover(bare)
    assert report.messages_recovered == 7 and report.output == bare
    assert (tmp_path / "cut.mcap.damaged").read_bytes() == data[:-50]
    assert not bag_info(bare).damaged and len(list(read_clouds(bare))) == 3


def test_rclpy_serialized_bytes_read_back_equal(tmp_path):
    try:
        from builtin_interfaces.msg import Time
        from rclpy.serialization import serialize_message
        from sensor_msgs.msg import PointCloud2, PointField
        from std_msgs.msg import Header
    except ImportError as err:
        pytest.skip(f"rclpy / ROS message packages unavailable: {err}")
    types = MessageTypes(PointCloud2, PointField, Header, Time, lambda b: array.array("B", b))
    points = random_points(np.random.default_rng(3), 64)
    msg, _ = build_message(points, stamp_ns=T0 + 42, frame_id=FRAME_LIDAR, types=types)
    data = serialize_message(msg)
    with BagWriter(tmp_path / "bag") as writer:
        writer.write_serialized(TOPIC_POINTS, "sensor_msgs/msg/PointCloud2", data, T0 + 50)
    (frame,) = read_clouds(tmp_path / "bag")
    assert (frame.log_time_ns, frame.stamp_ns, frame.frame_id) == (T0 + 50, T0 + 42, FRAME_LIDAR)
    assert_points_equal(frame.points, points)
    (message,) = read_messages(tmp_path / "bag")
    got = message.msg  # CDR padding bytes may differ between serialisers, so compare fields
    assert (got.height, got.width, got.point_step, got.row_step, got.is_dense) == (
        msg.height, msg.width, msg.point_step, msg.row_step, msg.is_dense,
    )
    assert bytes(got.data) == bytes(msg.data)
