"""Point sets that regions read from ROS topics instead of computing them (ROS-free store).

A region that can take its input from another node (the ``spray`` region with
``source: topic`` reads the particles ``spray_node`` publishes) calls
:meth:`TopicInputs.want` when it is built, naming the topic, the fields it
needs and itself as the owner. ``lidar_sim_node`` subscribes to every wanted
topic (PointCloud2) and hands each decoded message to :meth:`TopicInputs.put`,
which checks the frame and the fields and keeps the newest; the region reads it
with :meth:`TopicInputs.latest` when it is applied. When a region set is
replaced, :meth:`TopicInputs.retain` drops the topics only the old regions
wanted (and the node unsubscribes). Without a node (offline runs, tests) the
caller puts the arrays itself.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class TopicPoints:
    """The newest points of a topic: structured array, header stamp (s) and frame."""

    points: np.ndarray
    stamp_s: float
    frame_id: str


class TopicInputs:
    """Newest :class:`TopicPoints` per topic, for the regions that want them.

    ``fixed_frame``: the frame of the simulated world (the node's fixed frame); points in
    another frame are refused.
    """

    def __init__(self, fixed_frame: str = "map") -> None:
        self.fixed_frame = fixed_frame
        self._fields: dict[str, tuple[str, ...]] = {}
        self._latest: dict[str, TopicPoints] = {}
        self._owners: dict[str, list] = {}  # topic -> the regions that want it (None: kept for good)

    @property
    def topics(self) -> tuple[str, ...]:
        """The topics some region wants, in the order first asked for."""
        return tuple(self._fields)

    def want(self, topic: str, fields: tuple[str, ...], owner=None) -> None:
        """Ask for ``topic``, whose points must carry ``fields`` (a later call adds fields), on behalf of
        ``owner`` (the region; None: for good)."""
        old = self._fields.get(topic, ())
        self._fields[topic] = old + tuple(f for f in fields if f not in old)
        self._owners.setdefault(topic, []).append(owner)

    def retain(self, owners) -> None:
        """Keep only the topics some of ``owners`` (the regions in use or about to be) or no owner wants."""
        keep = {id(o) for o in owners}
        for topic in list(self._owners):
            left = [o for o in self._owners[topic] if o is None or id(o) in keep]
            if left:
                self._owners[topic] = left
            else:
                del self._owners[topic], self._fields[topic]
                self._latest.pop(topic, None)

    def put(self, topic: str, points: np.ndarray, stamp_s: float, frame_id: str) -> None:
        """Keep ``points`` as the newest of ``topic``; raises ValueError naming the topic and the missing
        field or the wrong frame (the caller logs it and keeps the previous points)."""
        if frame_id != self.fixed_frame:
            raise ValueError(f"{topic}: frame_id '{frame_id}' is not the fixed frame '{self.fixed_frame}'")
        names = points.dtype.names or ()
        missing = [f for f in self._fields.get(topic, ()) if f not in names]
        if missing:
            raise ValueError(f"{topic}: points lack the field(s) {', '.join(missing)} (have {', '.join(names)})")
        self._latest[topic] = TopicPoints(points, float(stamp_s), frame_id)

    def latest(self, topic: str) -> TopicPoints | None:
        """The newest points of ``topic`` (None before the first message)."""
        return self._latest.get(topic)
