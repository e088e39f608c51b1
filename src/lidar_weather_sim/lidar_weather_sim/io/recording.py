"""A recorded LiDAR bag (measured or simulated) as frames plus the poses that were recorded with them.

ROS-free: clouds come from :func:`lidar_weather_sim.io.bags.read_clouds`, poses from the
bag's ``/tf`` and ``/tf_static`` (or a ``nav_msgs/Odometry`` topic with the base ->
sensor mount on ``/tf_static``) in a :class:`~lidar_weather_sim.poses.tf_buffer.TransformBuffer`
that holds the whole recording. Frames of other vehicles published as ``actor_<id>``
(what ``lidar-weather-sim run`` writes) give the actor poses.

Time: simulated seconds are counted from the bag's first message (``start_ns``); a
frame's scan index is its stamp over the sensor's period from there.
"""

from __future__ import annotations

import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable

import numpy as np

from lidar_weather_sim.core.names import TOPIC_TF, TOPIC_TF_STATIC, actor_frame
from lidar_weather_sim.io.bags import BagError, CloudFrame, bag_info, cloud_topic, read_clouds, read_messages
from lidar_weather_sim.io.layouts import CloudReader, stderr_note
from lidar_weather_sim.poses.sources import TfPoseSource, add_odometry, add_tf_message
from lidar_weather_sim.poses.tf_buffer import TransformBuffer, TransformError

ODOMETRY = "nav_msgs/msg/Odometry"
ACTOR_FRAME = re.compile(r"^actor_(\d+)$")


@dataclass
class Recording:
    """Frames of one PointCloud2 topic in stamp order, and the recorded transforms."""

    path: Path
    topic: str
    frames: list[CloudFrame]
    start_ns: int
    buffer: TransformBuffer = field(repr=False)
    fixed_frame: str | None  # root of the transform tree, None without /tf
    sensor_frame: str
    layout: CloudReader = field(repr=False)  # the driver read and what was assumed (io/layouts.py)

    @classmethod
    def load(cls, path: str | Path, topic: str | None = None,
             note: Callable[[str], None] | None = stderr_note) -> "Recording":  # fmt: skip
        """The bag's frames of ``topic`` (default: /lidar/points or the only PointCloud2 topic) in the project's
        point layout, whatever driver wrote them; ``note`` gets the one line of what the reader assumed."""
        path = Path(path)
        topic = cloud_topic(path, topic)
        info = bag_info(path)
        layout = CloudReader(f"{path} {topic}", note)
        frames = sorted(read_clouds(path, topic, reader=layout), key=lambda f: f.stamp_ns)
        if not frames:
            raise BagError(f"bag {path}: topic {topic} holds no clouds")
        span_s = max(info.duration_s, (frames[-1].stamp_ns - frames[0].stamp_ns) * 1e-9) + 10.0
        buffer = TransformBuffer(cache_time_s=span_s, extrapolation_tolerance_s=0.05)
        odometry = [t.name for t in info.topics if t.msgtype == ODOMETRY]
        for m in read_messages(path, [TOPIC_TF, TOPIC_TF_STATIC, *odometry]):
            if m.msgtype == ODOMETRY:
                add_odometry(buffer, m.msg, m.msg.header.frame_id, m.msg.child_frame_id)
            else:
                add_tf_message(buffer, m.msg, static=m.topic == TOPIC_TF_STATIC)
        sensor = frames[0].frame_id
        start = min(info.start_ns, frames[0].stamp_ns)
        return cls(path, topic, frames, start, buffer, _root(buffer, sensor), sensor, layout)

    # -- time ---------------------------------------------------------------------
    def time_s(self, stamp_ns: int) -> float:
        return (int(stamp_ns) - self.start_ns) * 1e-9

    def scan_index(self, frame: CloudFrame, period_s: float) -> int:
        """The scan number of ``frame`` counted from the bag's start (decides alternating layers)."""
        return int(round(self.time_s(frame.stamp_ns) / period_s))

    # -- poses ----------------------------------------------------------------------
    @property
    def has_poses(self) -> bool:
        return self.fixed_frame is not None

    def actor_ids(self) -> list[int]:
        return sorted(int(m.group(1)) for f in self.buffer.frames() if (m := ACTOR_FRAME.match(f)))

    def actor_poses(self, time_s: float) -> dict[int, np.ndarray]:
        """Body-to-fixed 4x4 of each ``actor_<id>`` frame known at ``time_s`` (simulated s)."""
        stamp = self.start_ns + int(round(time_s * 1e9))
        out = {}
        for actor in self.actor_ids():
            try:
                out[actor] = self.buffer.lookup(self.fixed_frame, actor_frame(actor), stamp).as_matrix()
            except TransformError:
                continue
        return out

    def pose_source(self) -> TfPoseSource:
        """The recorded sensor poses (rolling shutter: one per firing time) and actor poses."""
        if not self.has_poses:
            raise BagError(f"bag {self.path}: no /tf or odometry pose of the sensor frame '{self.sensor_frame}'")
        return TfPoseSource(self.buffer, self.fixed_frame, self.sensor_frame, self.actor_poses, self.start_ns)

    def sensor_from_fixed(self, frame: CloudFrame) -> np.ndarray | None:
        """4x4 fixed-to-sensor transform at the frame's stamp (None without poses)."""
        if not self.has_poses:
            return None
        return self.buffer.lookup(self.fixed_frame, self.sensor_frame, frame.stamp_ns).inverse().as_matrix()


def _root(buffer: TransformBuffer, sensor_frame: str) -> str | None:
    """The root of the tree the sensor frame hangs in (None if the sensor frame has no parent)."""
    if sensor_frame not in buffer.frames():
        return None
    root = buffer.root(sensor_frame)
    return None if root == sensor_frame.lstrip("/") else root
