"""The gap's view of a recording and its re-simulation: every frame zoned (road level, recorded vehicles) and
summed into a :class:`~lidar_weather_sim.gap.signatures.Signature`, measured or re-simulated
(:class:`GapResimulator`, a :class:`~lidar_weather_sim.replay.resimulator.Resimulator` that zones its frames)."""

from __future__ import annotations

from typing import Callable

import numpy as np

from lidar_weather_sim.gap.signatures import FrameContext, Signature
from lidar_weather_sim.io.recording import Recording
from lidar_weather_sim.replay.resimulator import Resimulator
from lidar_weather_sim.replay.surroundings import ActorBox, road_level
from lidar_weather_sim.scenario.effects import Effect
from lidar_weather_sim.scenario.schema import Scenario


def frame_contexts(recording: Recording, scenario: Scenario | None) -> list[FrameContext]:
    """Zoning context of every frame: the road level and the recorded vehicles (sizes from the
    scenario's actors, else a mid-size car)."""
    road_z = road_level(recording)
    sizes = {a.id: a.size for a in scenario.actors} if scenario is not None else {}
    out = []
    for frame in recording.frames:
        boxes = []
        to_sensor = recording.sensor_from_fixed(frame) if recording.has_poses else None
        if to_sensor is not None:
            for actor_id, pose in recording.actor_poses(recording.time_s(frame.stamp_ns)).items():
                size = sizes.get(actor_id)
                dims = (size.length_m, size.width_m, size.height_m) if size else ()
                boxes.append(ActorBox(actor_id, to_sensor @ pose, *dims))
        out.append(FrameContext(road_z, tuple(boxes)))
    return out


def channel_count(recording: Recording) -> int:
    """The channels a recording's points name (the highest channel index + 1)."""
    return int(max(int(f.points["channel"].max(initial=0)) for f in recording.frames)) + 1


def measured_signature(recording: Recording, indices, contexts: list[FrameContext], channels: int,
                       keep: Callable[[np.ndarray], np.ndarray] | None = None) -> Signature:  # fmt: skip
    """The recording's frames ``indices`` as a :class:`Signature`; ``keep(points)`` (a boolean mask, e.g. the
    azimuth sectors of a :class:`~lidar_weather_sim.gap.split.DataSplit`) selects the points counted."""
    sig = Signature(channels)
    for i in indices:
        points = recording.frames[i].points
        sig.add(points if keep is None else points[keep(points)], contexts[i])
    return sig


class GapResimulator(Resimulator):
    """A :class:`~lidar_weather_sim.replay.resimulator.Resimulator` whose frames are zoned with the recording's
    contexts (:func:`frame_contexts`) and summed into signatures."""

    def __init__(self, recording: Recording, scenario: Scenario, profile: str | None = None,
                 backend: str | None = None, atmosphere_model: str | None = None) -> None:  # fmt: skip
        super().__init__(recording, scenario, profile, backend, atmosphere_model)
        self.contexts = frame_contexts(recording, scenario)

    def signature(self, effects: list[Effect], indices, keep: Callable[[np.ndarray], np.ndarray] | None = None,
                  frames: list[np.ndarray] | None = None) -> Signature:  # fmt: skip
        """The :class:`Signature` of the frames ``indices`` simulated with ``effects`` (or of ``frames``, those
        frames already simulated; only the points ``keep(points)`` selects, when given)."""
        sig = Signature(self.channels)
        for i, points in zip(sorted(indices), self.frames(effects, indices) if frames is None else frames):
            sig.add(points if keep is None else points[keep(points)], self.contexts[i])
        return sig
