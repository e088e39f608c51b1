"""The simulator behind ``lidar_sim_node``, with runtime settings that take effect from the next frame.

No ROS import (it sits under ``ros/`` only because it serves the node): the
node turns parameters into :class:`RuntimeSettings`, validates them with
:meth:`SimSession.build_regions` in its on-set callback and hands them to
:meth:`SimSession.request` after the set. Pending settings are swapped in at
the first frame boundary: never in the middle of a frame, so every frame is
cast with one set of regions, seed and sun irradiance. If the frame being
cast has not fired a column yet, that frame already uses them; otherwise the
next one does. :attr:`SimSession.settings_from_s` tells which frame that was.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import yaml

from lidar_weather_sim.core.config import ConfigError
from lidar_weather_sim.regions.base import REGISTRY, Region
from lidar_weather_sim.regions.topic_inputs import TopicInputs
from lidar_weather_sim.scenario.world import World
from lidar_weather_sim.sim.simulator import Frame, LidarSimulator, PoseSource


@dataclass(frozen=True)
class RuntimeSettings:
    """What can change while the node runs."""

    regions: tuple[str, ...]
    region_params: dict[str, dict] = field(default_factory=dict)  # plugin -> params, over the scenario's
    sun_irradiance_w_m2: float = 0.0
    seed: int = 0


def parse_region_params(text: str) -> dict[str, dict]:
    """The ``region_params`` parameter: a YAML mapping plugin -> mapping of its parameters ('' = none)."""
    try:
        data = yaml.safe_load(text) if text.strip() else {}
    except yaml.YAMLError as exc:
        raise ConfigError(f"region_params: invalid YAML: {getattr(exc, 'problem', exc)}") from None
    data = {} if data is None else data
    if not isinstance(data, dict) or not all(isinstance(v, dict) or v is None for v in data.values()):
        raise ConfigError(f"region_params must map region plugin names to parameter mappings, got {text!r}")
    return {str(name): dict(values or {}) for name, values in data.items()}


class SimSession:
    """A :class:`LidarSimulator` over a :class:`World`, with settings applied at frame boundaries."""

    def __init__(self, world: World, settings: RuntimeSettings, *, backend: str | None, ground_truth: bool,
                 inputs: TopicInputs | None = None, pose_source: PoseSource | None = None) -> None:  # fmt: skip
        self.world = world
        self.inputs = TopicInputs() if inputs is None else inputs  # points the regions read from topics
        self.pose_source = pose_source  # the regions' actor poses (spray emitters); None: the scenario player
        self.settings = settings
        self._options = {"backend": backend or None, "ground_truth": ground_truth}
        self._pending: tuple[RuntimeSettings, list[tuple[str, Region]]] | None = None
        self.restart()

    def restart(self) -> None:
        """A fresh simulator (time starts again) with the newest accepted settings."""
        if self._pending is not None:
            self.settings = self._pending[0]
            self._pending = None
        s = self.settings
        self.sim = LidarSimulator.of_world(
            self.world, regions=self.build_regions(s), seed=s.seed, sun_irradiance_w_m2=s.sun_irradiance_w_m2,
            **self._options,
        )  # fmt: skip
        self.inputs.retain(region for _, region in self.sim.regions)  # topics of replaced regions go
        self.frame_start_s: float | None = None  # scan start of the frame being cast
        self.last_time_s: float | None = None
        self.settings_from_s: float | None = None  # scan start of the first frame cast with settings (None: all)

    def build_regions(self, settings: RuntimeSettings) -> list[tuple[str, Region]]:
        """The region plugins of ``settings``; raises ConfigError naming an unknown plugin or bad parameter."""
        for name in settings.region_params:
            REGISTRY.get(name)  # a typo in region_params must not pass silently
        return self.world.regions(list(settings.regions), settings.region_params, pose_source=self.pose_source,
                                  inputs=self.inputs)  # fmt: skip

    def request(self, settings: RuntimeSettings, regions: list[tuple[str, Region]] | None = None) -> None:
        """Use ``settings`` from the next frame on (``regions``: already built from them)."""
        self._pending = (settings, self.build_regions(settings) if regions is None else regions)

    @property
    def pending(self) -> RuntimeSettings | None:
        return None if self._pending is None else self._pending[0]

    def advance(self, time_s: float, poses: PoseSource) -> list[Frame]:
        """Cast up to ``time_s`` (simulated s, must increase); return the frames completed."""
        sim, frames = self.sim, []
        if self._pending is not None and not self._frame_started():
            self._apply()
        if self._pending is not None and self.frame_start_s is not None:
            # finish the open frame with the old settings: its last column fires before the period ends
            split = self.frame_start_s + 0.5 * (sim.pattern.column_time_s[-1] + sim.profile.period_s)
            if time_s >= split:
                frames += self._advance(split, poses)
                self._apply()
        return frames + self._advance(time_s, poses)

    def _advance(self, time_s: float, poses: PoseSource) -> list[Frame]:
        frames = self.sim.advance(time_s, poses)
        if self.frame_start_s is None:
            self.frame_start_s = float(time_s)
        if frames:
            self.frame_start_s = frames[-1].stamp_s + self.sim.profile.period_s
        self.last_time_s = float(time_s)
        return frames

    def _frame_started(self) -> bool:
        """Has the open frame fired a column yet?"""
        if self.frame_start_s is None:
            return False
        return self.last_time_s - self.frame_start_s >= self.sim.pattern.column_time_s[0]

    def _apply(self) -> None:
        settings, regions = self._pending
        self._pending = None
        self.settings, self.settings_from_s = settings, self.frame_start_s
        self.sim.flush()  # a batch of the open frame may still be in detection
        self.sim.regions = list(regions)
        self.inputs.retain(region for _, region in regions)
        self.sim.seed = int(settings.seed)
        self.sim.sun_irradiance_w_m2 = float(settings.sun_irradiance_w_m2)
