"""Read, write, inspect and recover rosbag2 recordings without ROS (via ``rosbags``).

A BAG is a rosbag2 directory (``metadata.yaml`` plus MCAP or sqlite3 storage)
or a bare ``.mcap`` / ``.db3`` file. Messages are (de)serialised as CDR with the
ROS 2 Kilted typestore, which is byte-compatible with rclpy's serialisation.

Times are integer nanoseconds. The *log time* (``log_time_ns``) is when the
recorder received the message and is what the bag is indexed by; the *header
stamp* (``stamp_ns``) is the time inside the message (``header.stamp``).

Damaged bags: an MCAP whose writer was SIGKILLed has no summary or footer, and
its directory may lack ``metadata.yaml``. The reading functions read such bags
transparently by scanning the MCAP records in file order up to the truncated
tail; :func:`recover` rewrites them as a valid, indexed bag. Our MCAP chunks
hold at most 0.5 s of log time (or 1 MiB) and are flushed when closed, so a
killed writer loses at most the last 0.5 s (:mod:`lidar_weather_sim.io.mcap_checks`).
rosbags' sqlite3 writer commits only on close, so a killed sqlite3 recording
holds no messages.

Checksums: every chunk carries the CRC-32 of its records and the footer that of
the summary; readers check both, and any error reading a bag (a flipped length,
an undecodable string) becomes one BagError naming the file and, where a walk of
its records finds it, the offset of the first broken record.

Messages of the ``/tf``, ``/tf_static`` and ``/clock`` topics (:func:`tf_message`, :func:`clock_message`)
are built here, from the same typestore: transforms are :class:`~lidar_weather_sim.core.geometry.FrameTransform`
(parent, child, translation x, y, z in m, unit quaternion x, y, z, w), stamps integer nanoseconds.

Why one module of ~550 lines: reading, writing and recovering rosbag2 files share the open-bag
helpers and the crash-safety rules above (a recording is never left without its index).
"""

from __future__ import annotations

import atexit
import shutil
import signal
import struct
import threading
from contextlib import contextmanager
from dataclasses import dataclass
from datetime import datetime, timezone
from functools import cache, partial
from pathlib import Path
from typing import Any, Iterable, Iterator

import numpy as np
from mcap.exceptions import EndOfFile, McapError
from mcap.reader import NonSeekingReader
from rosbags.rosbag2 import Reader, ReaderError, StoragePlugin, Writer, WriterError
from rosbags.serde import SerdeError
from rosbags.typesys import Stores, TypesysError, get_typestore

from lidar_weather_sim.core.geometry import FrameTransform
from lidar_weather_sim.core.names import TOPIC_POINTS
from lidar_weather_sim.io.cloud_codec import (
    DATATYPE_TO_DTYPE,
    CloudFormatError,
    MessageTypes,
    NanPolicy,
    build_message,
    decode_message,
)
from lidar_weather_sim.io.layouts import CloudReader
from lidar_weather_sim.io.mcap_checks import check_summary, checksum_chunks, first_damage, seal

POINTCLOUD2 = "sensor_msgs/msg/PointCloud2"
_MCAP_MAGIC = b"\x89MCAP0\r\n"
_FOOTER_SIZE = 37  # footer record (1 + 8 + 20 bytes) + closing magic
_STORAGES = {"mcap": StoragePlugin.MCAP, "sqlite3": StoragePlugin.SQLITE3}


class BagError(ValueError):
    """A bag that cannot be read or written; the message names the bag and the cause."""


@dataclass(frozen=True)
class BagMessage:
    """One message: topic, type, log time (ns) and the deserialised rosbags object."""

    topic: str
    msgtype: str
    log_time_ns: int
    msg: Any


@dataclass(frozen=True)
class CloudFrame:
    """One decoded PointCloud2: log time and header stamp (both ns), frame and points."""

    log_time_ns: int
    stamp_ns: int
    frame_id: str
    points: np.ndarray
    dropped_nonfinite: int


@dataclass(frozen=True)
class TopicInfo:
    """A topic and its message count; PointCloud2 fields (name, offset, datatype, count) of its first message."""

    name: str
    msgtype: str
    count: int
    pointcloud_fields: list[tuple[str, int, int, int]] | None


@dataclass(frozen=True)
class BagInfo:
    """Summary of a bag: first/last log times in ns (0 if empty); ``damaged``: no valid index."""

    storage: str
    path: Path
    start_ns: int
    end_ns: int
    duration_s: float
    message_count: int
    topics: list[TopicInfo]
    damaged: bool = False


@dataclass(frozen=True)
class RecoveryReport:
    """Outcome of :func:`recover`; ``damaged_copy`` is None when the bag was intact."""

    path: Path
    messages_recovered: int
    topics: list[str]
    output: Path
    damaged_copy: Path | None


@cache
def typestore():
    """The ROS 2 Kilted typestore used for all (de)serialisation (shared; do not register types)."""
    return get_typestore(Stores.ROS2_KILTED)


def message_types() -> MessageTypes:
    """The typestore's classes for :func:`cloud_codec.build_message` (``data`` as numpy uint8)."""
    types = typestore().types
    return MessageTypes(
        PointCloud2=types[POINTCLOUD2],
        PointField=types["sensor_msgs/msg/PointField"],
        Header=types["std_msgs/msg/Header"],
        Time=types["builtin_interfaces/msg/Time"],
        data=partial(np.frombuffer, dtype=np.uint8),
    )


def time_message(ns: int):
    """builtin_interfaces/Time of ``ns`` nanoseconds."""
    sec, nanosec = divmod(int(ns), 1_000_000_000)
    return typestore().types["builtin_interfaces/msg/Time"](sec=sec, nanosec=nanosec)


def tf_message(ns: int, transforms: Iterable[FrameTransform]):
    """tf2_msgs/TFMessage of ``transforms``, each stamped ``ns``."""
    t = typestore().types
    stamped = []
    for parent, child, translation, quaternion in transforms:
        x, y, z = (float(v) for v in translation)
        qx, qy, qz, qw = (float(v) for v in quaternion)
        transform = t["geometry_msgs/msg/Transform"](translation=t["geometry_msgs/msg/Vector3"](x=x, y=y, z=z),
                                                    rotation=t["geometry_msgs/msg/Quaternion"](x=qx, y=qy, z=qz, w=qw))  # fmt: skip
        header = t["std_msgs/msg/Header"](stamp=time_message(ns), frame_id=parent)
        stamped.append(t["geometry_msgs/msg/TransformStamped"](header=header, child_frame_id=child, transform=transform))
    return t["tf2_msgs/msg/TFMessage"](transforms=stamped)


def clock_message(ns: int):
    """rosgraph_msgs/Clock at ``ns`` nanoseconds."""
    return typestore().types["rosgraph_msgs/msg/Clock"](clock=time_message(ns))


# --- locating a bag and its raw messages --------------------------------------------------


@dataclass(frozen=True)
class _Bag:
    path: Path
    storage: str
    files: list[Path]  # storage files, in split order
    intact: bool  # has metadata.yaml (directories) and every MCAP has a footer


def _has_footer(file: Path) -> bool:
    with file.open("rb") as stream:
        if stream.seek(0, 2) < 2 * len(_MCAP_MAGIC) + _FOOTER_SIZE:
            return False
        stream.seek(-_FOOTER_SIZE, 2)
        tail = stream.read()
    return tail[0] == 0x02 and tail.endswith(_MCAP_MAGIC)


def _open_bag(path: str | Path) -> _Bag:
    path = Path(path)
    if not path.exists():
        raise BagError(f"bag not found: {path}")
    candidates = [path] if path.is_file() else [*path.glob("*.mcap"), *path.glob("*.db3")]
    files = sorted((f for f in candidates if f.suffix in (".mcap", ".db3")), key=lambda f: (len(f.name), f.name))
    if not files:
        raise BagError(f"{path} is not a bag: no .mcap or .db3 storage file")
    storage = "mcap" if files[0].suffix == ".mcap" else "sqlite3"
    intact = (path.is_file() or (path / "metadata.yaml").exists()) and all(
        _has_footer(f) for f in files if f.suffix == ".mcap"
    )
    for file in files if intact and storage == "mcap" else ():
        problem = check_summary(file)
        if problem:
            raise BagError(f"{file}: {problem}")
    return _Bag(path, storage, files, intact)


def _indexed_raw(source: Path, topics: set[str] | None) -> Iterator[tuple[str, str, int, bytes]]:
    with Reader(source) as reader:
        wanted = [c for c in reader.connections if topics is None or c.topic in topics]
        if wanted:  # rosbags reads every connection when given none
            for conn, log_time, data in reader.messages(wanted):
                yield conn.topic, conn.msgtype, log_time, data


def _scanned_raw(file: Path, topics: set[str] | None) -> Iterator[tuple[str, str, int, bytes]]:
    """Messages of an MCAP in file order, stopping quietly at a truncated tail."""
    with file.open("rb") as stream:
        size = stream.seek(0, 2)
        stream.seek(0)
        records = NonSeekingReader(stream, validate_crcs=True).iter_messages(topics=topics, log_time_order=False)
        try:
            for schema, channel, message in records:
                yield channel.topic, schema.name if schema else "", message.log_time, message.data
        except (EndOfFile, struct.error) as err:
            if stream.tell() < size:  # not the truncated tail: real corruption
                raise BagError(f"{file}: corrupt MCAP record before offset {stream.tell()}: {err!r}") from err


def _raw(bag: _Bag, topics: Iterable[str] | None = None) -> Iterator[tuple[str, str, int, bytes]]:
    """(topic, msgtype, log_time_ns, CDR bytes) of every message, optionally of ``topics`` only."""
    wanted = None if topics is None else set(topics)
    try:
        if bag.intact:
            yield from _indexed_raw(bag.path, wanted)
        else:
            for file in bag.files:
                yield from (_scanned_raw if file.suffix == ".mcap" else _indexed_raw)(file, wanted)
    except BagError:
        raise
    except READ_ERRORS as err:
        raise _damaged(bag, err) from err


#: What reading a damaged file can raise besides BagError (a flipped length can overflow, a flipped
#: string fail to decode): each becomes one BagError naming the bag.
READ_ERRORS = (ReaderError, McapError, OSError, OverflowError, UnicodeDecodeError, struct.error, ValueError,
               MemoryError, KeyError, IndexError)  # fmt: skip


def _damaged(bag: _Bag, err: BaseException) -> BagError:
    """A BagError for ``err`` while reading ``bag``: the file and offset of the first broken record
    when a walk of its MCAP records finds one, else the bag and the reader's reason."""
    for file in bag.files if bag.storage == "mcap" else ():
        problem = first_damage(file)
        if problem:
            return BagError(f"{file}: {problem}")
    return BagError(f"cannot read bag {bag.path}: {type(err).__name__}: {err}")


def _deserialize(bag: _Bag, msgtype: str, data: bytes) -> Any:
    try:
        return typestore().deserialize_cdr(data, msgtype)
    except (KeyError, SerdeError) as err:
        raise BagError(f"{bag.path}: cannot deserialise {msgtype or 'schemaless'} message: {err!r}") from err


# --- reading ------------------------------------------------------------------------------


def read_messages(path: str | Path, topics: Iterable[str] | None = None) -> Iterator[BagMessage]:
    """Deserialised messages of BAG (all topics, or those in ``topics``; unknown ones yield nothing).

    Intact bags are read in log-time order, damaged ones in file order.
    """
    bag = _open_bag(path)
    return (BagMessage(t, m, log, _deserialize(bag, m, d)) for t, m, log, d in _raw(bag, topics))


def read_raw(path: str | Path, topics: Iterable[str] | None = None) -> Iterator[tuple[str, str, int, bytes]]:
    """(topic, msgtype, log_time_ns, CDR bytes) of every message of BAG (or of ``topics``), as stored:
    what a copy of the bag writes back with :meth:`BagWriter.write_serialized`."""
    return _raw(_open_bag(path), topics)


def _damaged_part(info) -> str:
    """What an error about a missing topic adds for a damaged bag (``info``: :func:`bag_info`'s)."""
    return " in its readable part (the bag is damaged: no index; `lidar-weather-sim recover` it)" if info.damaged else ""


def cloud_topic(path: str | Path, topic: str | None = None) -> str:
    """``topic`` if given, else the bag's only PointCloud2 topic (``/lidar/points`` preferred)."""
    info = bag_info(path)
    clouds = [t.name for t in info.topics if t.msgtype == POINTCLOUD2]
    if topic is not None:
        if topic not in clouds:
            raise BagError(f"bag {info.path} has no PointCloud2 topic {topic} (PointCloud2 topics: "
                           f"{', '.join(clouds) or 'none'})")  # fmt: skip
        return topic
    if TOPIC_POINTS in clouds:
        return TOPIC_POINTS
    if not clouds:
        found = ", ".join(f"{t.name} ({t.msgtype})" for t in info.topics) or "none"
        raise BagError(f"bag {info.path} has no {POINTCLOUD2} topic{_damaged_part(info)}; topics: {found}")
    if len(clouds) != 1:
        raise BagError(f"bag {info.path}: {len(clouds)} PointCloud2 topics ({', '.join(clouds) or 'none'}); "
                       "choose one with --topic")  # fmt: skip
    return clouds[0]


def read_clouds(path: str | Path, topic: str | None = None, nan_policy: NanPolicy = "drop",
                reader: CloudReader | None = None) -> Iterator[CloudFrame]:  # fmt: skip
    """PointCloud2 frames of ``topic`` (default: /lidar/points or the bag's only PointCloud2 topic, see
    :func:`cloud_topic`) in the project's point layout, whatever driver wrote them
    (:mod:`lidar_weather_sim.io.layouts`; ``reader`` default: one that notes its assumptions on stderr);
    non-finite points handled per ``nan_policy``."""
    info = bag_info(path)
    topic = cloud_topic(path, topic) if topic is None else topic
    types = {t.name: t.msgtype for t in info.topics}
    if types.get(topic) != POINTCLOUD2:
        found = ", ".join(f"{name} ({msgtype})" for name, msgtype in types.items()) or "none"
        raise BagError(f"bag {info.path} has no {POINTCLOUD2} topic {topic}{_damaged_part(info)}; topics: {found}")
    return _clouds(path, topic, nan_policy, reader or CloudReader(f"{path} {topic}"))


def _clouds(path: str | Path, topic: str, nan_policy: NanPolicy, reader: CloudReader) -> Iterator[CloudFrame]:
    for index, item in enumerate(read_messages(path, [topic])):
        try:
            cloud = decode_message(item.msg, nan_policy)
            stamp = item.msg.header.stamp
            frame = reader.read(cloud.points, int(stamp.sec) * 1_000_000_000 + int(stamp.nanosec))
        except CloudFormatError as err:
            raise BagError(f"bag {path}, topic {topic}, message {index}: {err}") from err
        yield CloudFrame(item.log_time_ns, frame.stamp_ns, item.msg.header.frame_id, frame.points,
                         cloud.dropped_nonfinite + frame.placeholders)  # fmt: skip


def _fields(msg: Any) -> list[tuple[str, int, int, int]]:
    return [(f.name, int(f.offset), int(f.datatype), int(f.count)) for f in msg.fields]


def _indexed_stats(bag: _Bag) -> tuple[list[TopicInfo], int, int]:
    with Reader(bag.path) as reader:
        topics = []
        for name, topic in reader.topics.items():
            first = next(reader.messages(topic.connections), None) if topic.msgtype == POINTCLOUD2 else None
            fields = _fields(_deserialize(bag, POINTCLOUD2, first[2])) if first else None
            topics.append(TopicInfo(name, topic.msgtype, topic.msgcount, fields))
        if not reader.message_count:
            return topics, 0, 0
        return topics, reader.start_time, reader.end_time - 1  # rosbags' end_time is exclusive


def _scanned_stats(bag: _Bag) -> tuple[list[TopicInfo], int, int]:
    types: dict[str, str] = {}
    counts: dict[str, int] = {}
    fields: dict[str, list[tuple[str, int, int, int]]] = {}
    times = []
    for topic, msgtype, log_time, data in _raw(bag):
        types.setdefault(topic, msgtype)
        counts[topic] = counts.get(topic, 0) + 1
        if msgtype == POINTCLOUD2 and topic not in fields:
            fields[topic] = _fields(_deserialize(bag, msgtype, data))
        times.append(log_time)
    topics = [TopicInfo(t, types[t], counts[t], fields.get(t)) for t in types]
    return topics, min(times, default=0), max(times, default=0)


def bag_info(path: str | Path) -> BagInfo:
    """Storage, log-time span, message counts and PointCloud2 fields of BAG.

    Intact bags are summarised from their index; damaged bags are scanned.
    """
    bag = _open_bag(path)
    try:
        topics, start, end = (_indexed_stats if bag.intact else _scanned_stats)(bag)
    except BagError:
        raise
    except READ_ERRORS as err:
        raise _damaged(bag, err) from err
    count = sum(t.count for t in topics)
    return BagInfo(bag.storage, bag.path, start, end, (end - start) / 1e9, count, topics, not bag.intact)


def _format_time(ns: int) -> str:
    return f"{datetime.fromtimestamp(ns / 1e9, tz=timezone.utc).isoformat()} ({ns} ns)"


def _format_field(name: str, offset: int, datatype: int, count: int) -> str:
    dtype = DATATYPE_TO_DTYPE[datatype].name if datatype in DATATYPE_TO_DTYPE else f"datatype {datatype}"
    return f"{name}: {dtype}{f'[{count}]' if count > 1 else ''} @ {offset}"


def format_info(info: BagInfo) -> str:
    """Human-readable summary of :func:`bag_info` (for ``lidar-weather-sim info BAG``)."""
    lines = [f"Bag:       {info.path}", f"Storage:   {info.storage}"]
    if info.damaged:
        lines.append(f"State:     damaged (no index); run `lidar-weather-sim recover {info.path}`")
    lines += [f"Messages:  {info.message_count}", f"Duration:  {info.duration_s:.3f} s"]
    if info.message_count:
        lines += [f"Start:     {_format_time(info.start_ns)}", f"End:       {_format_time(info.end_ns)}"]
    lines.append("Topics:")
    for topic in info.topics:
        lines.append(f"  {topic.name}  [{topic.msgtype}]  {topic.count} messages")
        for field in topic.pointcloud_fields or ():
            lines.append(f"      {_format_field(*field)}")
    return "\n".join(lines)


# --- writing ------------------------------------------------------------------------------


def _remove_bag(path: Path) -> None:
    if path.is_file():
        path.unlink()
    elif (path / "metadata.yaml").exists() or any(path.glob("*.mcap")) or any(path.glob("*.db3")):
        shutil.rmtree(path)
    else:
        raise BagError(f"{path} exists and is not a bag; not overwriting it")


class BagWriter:
    """Writes a rosbag2 directory; use as a context manager or call :meth:`close`.

    While open, SIGINT and SIGTERM (when opened in the main thread) and interpreter
    exit first close the bag, so a recording always ends with a valid index. The
    previous handler then runs; a default SIGTERM exits with status 143 (128 + 15).
    Inside an rclpy process pass ``handle_signals=False``: rclpy's own handler
    (installed below Python's ``signal`` module, so invisible to it) must stay in
    place to shut the context down, and the node closes the bag when it stops.
    """

    _SIGNALS = (signal.SIGINT, signal.SIGTERM)

    def __init__(self, path: str | Path, storage: str = "mcap", overwrite: bool = False,
                 handle_signals: bool = True) -> None:  # fmt: skip
        if storage not in _STORAGES:
            raise ValueError(f"storage must be one of {sorted(_STORAGES)}, not {storage!r}")
        self.path = Path(path)
        if self.path.suffix in (".mcap", ".db3"):  # rosbags would write OUT.mcap/OUT.mcap.mcap
            raise BagError(f"{self.path}: a rosbag2 output is a directory (its {self.path.suffix} file goes inside); "
                           f"give it a name without {self.path.suffix}")
        if self.path.exists():
            if not overwrite:
                raise BagError(f"{self.path} already exists (--overwrite / overwrite=True replaces it)")
            _remove_bag(self.path)
        try:
            self._writer: Writer | None = Writer(self.path, version=9, storage_plugin=_STORAGES[storage])
            self._writer.open()
        except (WriterError, OSError) as err:
            raise BagError(f"cannot create bag {self.path}: {err}") from err
        self._mcap: Path | None = None  # the MCAP file, sealed with its summary CRC on close
        if storage == "mcap":
            checksum_chunks(self._writer.storage)
            self._mcap = Path(self._writer.storage.path)
        self._connections: dict[str, Any] = {}
        self._lock = threading.RLock()  # serialises writes and close across threads
        self._owner: int | None = None  # thread inside a write or close
        self._pending: int | None = None
        self._previous: dict[int, Any] = {}
        if handle_signals and threading.current_thread() is threading.main_thread():
            self._previous = {sig: signal.signal(sig, self._on_signal) for sig in self._SIGNALS}
        atexit.register(self.close)

    def __enter__(self) -> BagWriter:
        return self

    def __exit__(self, *exc_info: object) -> None:
        self.close()

    def write(self, topic: str, msg: Any, log_time_ns: int) -> None:
        """Write a rosbags message object (type from its ``__msgtype__``) at log time ``log_time_ns``."""
        self.write_serialized(topic, msg.__msgtype__, typestore().serialize_cdr(msg, msg.__msgtype__), log_time_ns)

    def write_serialized(self, topic: str, msgtype: str, data: bytes, log_time_ns: int) -> None:
        """Write CDR bytes (e.g. from rclpy's ``serialize_message``) of ``msgtype`` at ``log_time_ns``."""
        with self._critical():
            if self._writer is None:
                raise BagError(f"bag {self.path} is closed")
            self._writer.write(self._connection(topic, msgtype), int(log_time_ns), data)

    def _connection(self, topic: str, msgtype: str) -> Any:
        conn = self._connections.get(topic)
        if conn is None:
            try:
                conn = self._writer.add_connection(topic, msgtype, typestore=typestore())
            except (TypesysError, KeyError) as err:
                raise BagError(f"unknown message type {msgtype} for topic {topic}") from err
            self._connections[topic] = conn
        if conn.msgtype != msgtype:
            raise BagError(f"topic {topic} already carries {conn.msgtype}, not {msgtype}")
        return conn

    def write_cloud(
        self, topic: str, points: np.ndarray, stamp_ns: int, frame_id: str, log_time_ns: int | None = None
    ) -> int:
        """Write ``points`` as a PointCloud2 stamped ``stamp_ns`` (header) at ``log_time_ns``.

        The log time defaults to the stamp. Returns the number of non-finite points dropped.
        """
        msg, dropped = build_message(points, stamp_ns=stamp_ns, frame_id=frame_id, types=message_types())
        self.write(topic, msg, stamp_ns if log_time_ns is None else log_time_ns)
        return dropped

    def close(self) -> None:
        """Finish the storage index and metadata.yaml; restore signal handlers. Idempotent."""
        with self._critical():
            writer, self._writer = self._writer, None
            try:
                if writer is not None:
                    writer.close()
                    if self._mcap is not None:
                        seal(self._mcap)
            finally:
                self._restore_handlers()

    def _restore_handlers(self) -> None:
        atexit.unregister(self.close)
        if threading.current_thread() is not threading.main_thread():
            return  # signal.signal only works there; our handler stays and chains
        for sig, previous in self._previous.items():
            if signal.getsignal(sig) == self._on_signal:
                signal.signal(sig, previous)
        self._previous = {}

    @contextmanager
    def _critical(self) -> Iterator[None]:
        """Hold the lock; a signal interrupting this thread's write is handled afterwards."""
        with self._lock:
            self._owner = threading.get_ident()
            try:
                yield
            finally:
                self._owner = None
        if self._pending is not None:
            signum, self._pending = self._pending, None
            self._on_signal(signum, None)

    def _on_signal(self, signum: int, frame: Any) -> None:
        """Close the bag (after any write in progress), then run the previous handler."""
        if self._owner == threading.get_ident():  # the main thread was interrupted mid-write
            self._pending = signum
            return
        previous = self._previous.get(signum, signal.SIG_DFL)
        self.close()
        if callable(previous):
            previous(signum, frame)
        elif previous == signal.SIG_IGN:
            return
        elif signum == signal.SIGINT:
            raise KeyboardInterrupt
        else:
            raise SystemExit(128 + signum)


# --- recovery -----------------------------------------------------------------------------


def recover(path: str | Path) -> RecoveryReport:
    """Rebuild a damaged MCAP bag (killed writer) as a valid, indexed bag in place.

    Every complete message is copied into a new bag; the damaged original is
    kept next to it as ``<name>.damaged`` and ``metadata.yaml`` is regenerated.
    An intact bag is left untouched.
    """
    bag = _open_bag(path)
    if bag.intact:
        info = bag_info(bag.path)
        return RecoveryReport(bag.path, info.message_count, [t.name for t in info.topics], bag.path, None)
    if bag.storage != "mcap":
        raise BagError(f"{bag.path}: only MCAP bags can be recovered (sqlite3 commits only on close)")
    damaged = bag.path.with_name(bag.path.name + ".damaged")
    staging = bag.path.with_name(f".{bag.path.name}.recovering")
    if damaged.exists() or staging.exists():
        raise BagError(f"{damaged} or {staging} exists already; move it away first")
    is_file = bag.path.is_file()
    built = staging / (bag.path.stem if is_file else bag.path.name)
    try:
        count, topics = _copy_messages(bag, built)
    except BaseException:
        shutil.rmtree(staging, ignore_errors=True)
        raise
    bag.path.rename(damaged)
    (built / f"{built.name}.mcap" if is_file else built).rename(bag.path)
    shutil.rmtree(staging)
    return RecoveryReport(bag.path, count, topics, bag.path, damaged)


def _copy_messages(bag: _Bag, out: Path) -> tuple[int, list[str]]:
    count, topics = 0, []
    with BagWriter(out, storage="mcap") as writer:
        for topic, msgtype, log_time, data in _raw(bag):
            writer.write_serialized(topic, msgtype, data, log_time)
            count += 1
            topics += [] if topic in topics else [topic]
    return count, topics
