"""The frames of a bag to draw and the actors around the sensor in each, in the sensor frame.

Frames are the clouds of one PointCloud2 topic in bag (log-time) order, numbered from 0; a selection
``A:B`` is Python's half-open slice [A, B) of those numbers (``A:`` to the end, ``:B`` from the start,
``N`` alone the one frame N). Only the selected clouds are decoded; reading stops after the last one.

Actors: the bag's ``/tf`` frames ``actor_<id>`` (what ``lidar-weather-sim run`` writes; body origin
at the centre of the footprint on the road, x forward) looked up in the cloud's frame at the middle of
the scan (header stamp + half the largest ``time_stamp`` offset: the scan is rolling shutter). Bags
carry no actor sizes, so a size comes from a scenario given by the caller (its ``actors[].size``, by
id); an actor without one is an :class:`ActorMarker` with ``size_m`` None (drawn as its frame's origin
and heading).
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from pathlib import Path
from typing import Iterator

import numpy as np

from lidar_weather_sim.core.names import TOPIC_TF, TOPIC_TF_STATIC, actor_frame
from lidar_weather_sim.io.bags import BagError, bag_info, cloud_topic, read_messages
from lidar_weather_sim.io.cloud_codec import CloudFormatError
from lidar_weather_sim.io.layouts import CloudReader
from lidar_weather_sim.poses.sources import add_tf_message
from lidar_weather_sim.poses.tf_buffer import TransformBuffer, TransformError

_ACTOR = re.compile(r"^actor_(\d+)$")


@dataclass(frozen=True)
class ActorMarker:
    """An actor in the sensor frame: ``pose`` body-to-sensor 4x4 (m), ``size_m`` (length, width,
    height) in m or None when unknown."""

    actor_id: int
    pose: np.ndarray
    size_m: tuple[float, float, float] | None

    def footprint(self) -> np.ndarray:
        """(4, 3) corners of the footprint (z = 0 in the body) in the sensor frame; needs a size."""
        length, width, _ = self.size_m
        body = np.array([[1, 1], [1, -1], [-1, -1], [-1, 1]], float) * (length / 2, width / 2)
        return self.to_sensor(np.c_[body, np.zeros(4)])

    def corners(self) -> np.ndarray:
        """(8, 3) corners of the box in the sensor frame (bottom four, then top four); needs a size."""
        length, width, height = self.size_m
        base = np.array([[1, 1], [1, -1], [-1, -1], [-1, 1]], float) * (length / 2, width / 2)
        body = np.r_[np.c_[base, np.zeros(4)], np.c_[base, np.full(4, height)]]
        return self.to_sensor(body)

    def to_sensor(self, body_points: np.ndarray) -> np.ndarray:
        return body_points @ self.pose[:3, :3].T + self.pose[:3, 3]


@dataclass(frozen=True)
class RenderFrame:
    """One selected frame: its number in the topic, stamp (ns), seconds since the bag's first message
    (``time_s``, as ``lidar-weather-sim run`` counts simulated time), the sensor frame's name, points (project layout or a subset of it) and actors."""

    index: int
    stamp_ns: int
    time_s: float
    frame_id: str
    points: np.ndarray
    actors: tuple[ActorMarker, ...]


def parse_selection(text: str | None, count: int) -> range:
    """Frame numbers selected by ``A:B`` / ``A:`` / ``:B`` / ``N`` among ``count`` frames (ValueError
    naming the problem when the text is malformed or selects nothing)."""
    if text is None or text.strip() in ("", ":"):
        selected = range(count)
    else:
        match = re.fullmatch(r"\s*(\d*)\s*(:?)\s*(\d*)\s*", text)
        if not match or (not match.group(2) and match.group(3)) or not (match.group(1) or match.group(3)):
            raise ValueError(f"--frames must be A:B, A:, :B or N with frame numbers >= 0, got '{text}'")
        start = int(match.group(1) or 0)
        stop = (int(match.group(3)) if match.group(3) else count) if match.group(2) else start + 1
        selected = range(start, min(stop, count))
    if len(selected) == 0:
        raise ValueError(f"--frames {text} selects no frame: the topic holds {count} clouds (frames 0 to {count - 1})")
    return selected


class FrameSource:
    """The selected frames of ``path``'s PointCloud2 ``topic`` (default: /lidar/points or the only
    one) with the actors of its /tf. ``sizes``: actor id -> (length, width, height) m."""

    def __init__(self, path: str | Path, topic: str | None = None, frames: str | None = None,
                 sizes: dict[int, tuple[float, float, float]] | None = None) -> None:  # fmt: skip
        self.path = Path(path)
        self.topic = cloud_topic(self.path, topic)
        info = bag_info(self.path)
        count = next(t.count for t in info.topics if t.name == self.topic)
        if count == 0:
            raise BagError(f"bag {self.path}: topic {self.topic} holds no clouds")
        self.selection = parse_selection(frames, count)
        self.start_ns = info.start_ns
        self.sizes = dict(sizes or {})
        self.buffer = TransformBuffer(cache_time_s=info.duration_s + 10.0, extrapolation_tolerance_s=0.05)
        for m in read_messages(self.path, [TOPIC_TF, TOPIC_TF_STATIC]):
            add_tf_message(self.buffer, m.msg, static=m.topic == TOPIC_TF_STATIC)
        self.actor_ids = sorted(int(m.group(1)) for f in self.buffer.frames() if (m := _ACTOR.match(f)))

    def __len__(self) -> int:
        return len(self.selection)

    def __iter__(self) -> Iterator[RenderFrame]:
        reader = CloudReader(f"{self.path} {self.topic}")
        for index, item in enumerate(read_messages(self.path, [self.topic])):
            if index >= self.selection.stop:
                break
            if index < self.selection.start:
                continue
            try:
                frame = reader.read_message(item.msg)
            except CloudFormatError as err:
                raise BagError(f"bag {self.path}, topic {self.topic}, message {index}: {err}") from err
            points, stamp_ns = frame.points, frame.stamp_ns
            frame_id = item.msg.header.frame_id
            yield RenderFrame(index, stamp_ns, (stamp_ns - self.start_ns) * 1e-9, frame_id, points,
                              self.actors(frame_id, stamp_ns + _half_scan_ns(points)))  # fmt: skip

    def actors(self, sensor_frame: str, stamp_ns: int) -> tuple[ActorMarker, ...]:
        """The actors whose frame is known in ``sensor_frame`` at ``stamp_ns`` (ns)."""
        out = []
        for actor_id in self.actor_ids:
            try:
                pose = self.buffer.lookup(sensor_frame, actor_frame(actor_id), stamp_ns).as_matrix()
            except TransformError:
                continue  # not present yet (appears later) or not in the sensor's tree
            out.append(ActorMarker(actor_id, pose, self.sizes.get(actor_id)))
        return tuple(out)


def _half_scan_ns(points: np.ndarray) -> int:
    if "time_stamp" not in (points.dtype.names or ()) or not len(points):
        return 0
    return int(points["time_stamp"].max()) // 2


def scenario_sizes(scenario) -> dict[int, tuple[float, float, float]]:
    """Actor id -> (length, width, height) in m of a :class:`~lidar_weather_sim.scenario.schema.Scenario`."""
    return {a.id: (a.size.length_m, a.size.width_m, a.size.height_m) for a in scenario.actors}
