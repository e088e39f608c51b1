"""Re-simulation of a recording: every chosen frame cast again from its recorded sensor poses; with what the gap
search and the augmentation share about a recording: the road level, the vehicles around the sensor as boxes
(sensor frame, REP-103, m) and the beam keys that pair the returns of two clouds of one sensor.

The scene is built once from the scenario (roads, static meshes, actor bodies); each
call to :meth:`Resimulator.frames` patches the scenario with a list of effects
(:mod:`lidar_weather_sim.scenario.effects`), rebuilds only the regions and the noise floor
(:meth:`LidarSimulator.restart`) and casts the frames in time order with the recorded
poses (rolling shutter: the pose of each column's firing time), in batches of the columns
fired in 10 ms as ``lidar-weather-sim run`` casts them (moving particles are placed per
batch). Actors follow their
``actor_<id>`` frames in the recording when it has them, else the scenario. Frame
index, seed and region randomness are the same from call to call (common random
numbers), so two effect lists are compared on the same draws.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from lidar_weather_sim.io.bags import BagError
from lidar_weather_sim.io.recording import Recording
from lidar_weather_sim.scenario.effects import Effect, apply_effects
from lidar_weather_sim.scenario.schema import Scenario
from lidar_weather_sim.scenario.world import World
from lidar_weather_sim.scene.raycast.memo_caster import MemoCaster
from lidar_weather_sim.sim.offline import POSE_STEP_S
from lidar_weather_sim.sim.simulator import LidarSimulator, scenario_settings


class RecordedPoses:
    """The recording's sensor poses; actors from the recording, else from the scenario player.

    A recording without /tf or odometry takes its sensor poses from the scenario's ``trajectory`` (a twin's
    ``scenario.yaml`` holds the poses KISS-ICP found on the clouds, in the recording's time). Lookups are
    memoised: re-simulating the same frames again asks for the same times."""

    def __init__(self, recording: Recording, world: World) -> None:
        if recording.has_poses or not world.scenario.trajectory:
            try:
                self._tf = recording.pose_source()
            except BagError as err:
                raise BagError(f"{err}, and scenario '{world.scenario.name}' has no 'trajectory' to take them from "
                               "(lidar-weather-sim twin BAG writes one)") from None  # fmt: skip
        else:
            self._tf = world.player
        self._actors = recording.actor_poses if recording.actor_ids() else world.player.actor_poses
        self._known = set(world.scene.actors)  # recorded actors the scenario has no body for are not cast (a twin)
        self._sensor: dict[tuple[float, int], tuple[np.ndarray, np.ndarray]] = {}
        self._actor: dict[float, dict[int, np.ndarray]] = {}

    def sensor_poses(self, times_s: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        times_s = np.asarray(times_s, dtype=np.float64)
        key = (float(times_s[0]), len(times_s))
        if key not in self._sensor:
            self._sensor[key] = self._tf.sensor_poses(times_s)
        return self._sensor[key]

    def actor_poses(self, time_s: float) -> dict[int, np.ndarray]:
        if time_s not in self._actor:
            self._actor[time_s] = {k: v for k, v in self._actors(time_s).items() if k in self._known}
        return self._actor[time_s]


class Resimulator:
    """Casts a recording's frames again with ``scenario`` plus effects (see module doc). ``through_air``: the
    effects' air is taken to be the recording's, which a twin's surveyed reflectivity was measured through
    (:class:`~lidar_weather_sim.sim.simulator.LidarSimulator`'s ``reflectivity_through_air``). ``keep_casts``: each
    batch's scene hits are cast once and kept (:class:`~lidar_weather_sim.scene.raycast.memo_caster.MemoCaster`),
    for a caller that simulates the same frames many times (the gap search)."""

    def __init__(self, recording: Recording, scenario: Scenario, profile: str | None = None,
                 backend: str | None = None, through_air: bool = False, keep_casts: bool = False) -> None:  # fmt: skip
        self.recording = recording
        self.scenario = scenario
        self.world = World.build(scenario, profile)
        self.poses = RecordedPoses(recording, self.world)
        caster = self.world.caster(backend)
        self.sim = LidarSimulator.of_world(self.world, backend=backend, regions=[],
                                           caster=MemoCaster(caster) if keep_casts else caster)  # fmt: skip
        self.sim.reflectivity_through_air = through_air
        self.channels = len(self.world.profile.beams)
        self.casts = 0  # frames cast so far (for progress and cost reports)
        self._memo: dict = {}  # what the regions of frames(..., memo=True) share (the spray particles' states)

    @property
    def is_twin(self) -> bool:
        """The scene holds reflectivity read off a recording through its air (a twin's mesh) and the effects' air
        is taken for that air (``through_air``)."""
        return self.sim.reflectivity_through_air and self.world.scene.recorded_range_m is not None

    def frames(self, effects: list[Effect], indices, redraw: int = 0, memo: bool = False) -> list[np.ndarray]:
        """Points of the recording's frames ``indices`` simulated with ``effects``; ``redraw`` > 0: another,
        independent draw of every random process (the scenario's seed + ``redraw``). ``memo``: the regions keep
        what frames cast again with the same regions will need (the spray particles' states at each step, for
        the few frames a search screens on every round; the same points, bit for bit), and take it from there."""
        patched = apply_effects(self.scenario, effects)
        if redraw:
            patched = patched.model_copy(update={"seed": patched.seed + redraw})
        world = replace(self.world, scenario=patched)
        mode = patched.sensor.return_mode or self.world.profile.detection.return_mode
        regions = world.regions(pose_source=self.poses, memo=self._memo if memo else None)
        self.sim.restart(regions=regions, return_mode=mode, **scenario_settings(patched))
        period = self.world.profile.period_s
        out = []
        for i in sorted(indices):
            frame = self.recording.frames[i]
            start = self.recording.time_s(frame.stamp_ns)
            index = self.recording.scan_index(frame, period)
            out.append(self.sim.cast_frame(index, start, self.poses, batch_s=POSE_STEP_S).points)
            self.casts += 1
        return out


# -- what a recording shows around the sensor ----------------------------------------------------------------


@dataclass(frozen=True)
class ActorBox:
    """A vehicle in the sensor frame: ``pose`` body-to-sensor 4x4 (body origin: centre of the
    footprint on the road, x forward), size in m (default: a mid-size car)."""

    actor_id: int
    pose: np.ndarray
    length_m: float = 4.7
    width_m: float = 1.85
    height_m: float = 1.45


def road_level(recording: Recording, max_frames: int = 50) -> float:
    """z of the road in the sensor frame (m): the road is the lowest surface around, so the 2nd
    percentile of the z of the returns 5-60 m away, over up to ``max_frames`` frames."""
    step = max(1, len(recording.frames) // max_frames)
    z = []
    for frame in recording.frames[::step]:
        p = frame.points
        keep = (p["distance"] >= 5.0) & (p["distance"] <= 60.0)
        z.append(p["z"][keep].astype(np.float64))
    z = np.concatenate(z) if z else np.zeros(0)
    return float(np.percentile(z, 2.0)) if len(z) else -1.0e3  # no returns: no road zone


# -- beams of a cloud by channel and azimuth column ----------------------------------------------------------


def beam_keys(points: np.ndarray, columns: int) -> np.ndarray:
    """One integer per point naming its beam: channel x columns + azimuth column."""
    col = np.floor((points["azimuth"].astype(np.float64) + np.pi) / (2.0 * np.pi) * columns).astype(np.int64)
    return points["channel"].astype(np.int64) * columns + np.clip(col, 0, columns - 1)


def nearest_returns(points: np.ndarray, columns: int) -> tuple[np.ndarray, np.ndarray]:
    """(beam keys, index into ``points``) of each beam's nearest return, sorted by key."""
    keys = beam_keys(points, columns)
    order = np.lexsort((points["distance"], keys))
    keys = keys[order]
    first = np.ones(len(keys), bool)
    first[1:] = keys[1:] != keys[:-1]
    return keys[first], order[first]


def paired_beams(a: np.ndarray, b: np.ndarray, columns: int) -> tuple[np.ndarray, np.ndarray]:
    """Indices into ``a`` and into ``b`` of each beam's nearest return, over the beams both frames return on."""
    ka, ia = nearest_returns(a, columns)
    kb, ib = nearest_returns(b, columns)
    _, ja, jb = np.intersect1d(ka, kb, assume_unique=True, return_indices=True)
    return ia[ja], ib[jb]
