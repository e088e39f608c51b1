"""The virtual LiDAR: the scan cast incrementally, as a pipeline of named stages per batch of columns.

:meth:`LidarSimulator.advance` plans the batches (the columns fired since the last pose update),
asks the pose source once for all their poses, and runs each batch through :meth:`LidarSimulator._cast`,
which reads as the data path::

    poses -> rays -> cast -> regions -> candidates -> occlusion -> echoes -> returns -> points

- **poses**: the sensor pose of every column at its own firing time (rolling shutter), the actors'
  poses at the batch time;
- **rays**: the scan pattern's sub-ray directions (:mod:`lidar_weather_sim.sensor.scan`) in the map frame;
- **cast**: the rays handed to the scene's caster (:mod:`lidar_weather_sim.scene.raycast`, given to the
  simulator, never built by it), nearest hits back;
- **regions**: the region plugins step in simulated time and return their effects on the batch
  (:mod:`lidar_weather_sim.regions.base`);
- **candidates**: every scene hit and scatterer with its LIDAR-equation amplitude
  (:mod:`lidar_weather_sim.sensor.radiometry`); **occlusion**: each scaled by the light the
  candidates in front of it on its sub-ray leave, grouped by beam for the echo stage;
- **echoes**: the threshold decision on each beam's waveform (:mod:`lidar_weather_sim.sensor.echo`);
- **returns**: what the profile's return mode (``detection.return_mode``) reports of each beam's echoes
  (:func:`~lidar_weather_sim.sensor.echo.select_returns`; ``all``: every echo);
- **points**: range noise, intensity, points in the sensor frame at their firing time, appended to the
  frame; a frame is returned when its sweep is complete (stamp: the scan start; ``time_stamp``: ns after).

The numba kernels behind the stages live in :mod:`lidar_weather_sim.sim.kernels` and run in chunks on
all cores. With regions, a large batch (``PARALLEL_MIN_RAYS``) applies its regions side by side and runs
its candidates -> points in a background thread while the next batch is cast and its regions applied;
a frame is returned once its last batch is detected (:meth:`LidarSimulator.flush`). Every stage draws
from streams seeded per batch, so the clouds are bit for bit those of one thread. Speed:
``benchmarks/performance/sim_frame_time.py`` (clear), ``benchmarks/performance/weather_frame_time.py`` (every region, per stage).

Why one module of ~550 lines: it is the frame pipeline, read top to bottom in one pass; the numba
kernels it calls are already in kernels.py.
"""

from __future__ import annotations

import bisect
from concurrent.futures import Future
from dataclasses import dataclass
from typing import Protocol

import numpy as np

from lidar_weather_sim.core import workers
from lidar_weather_sim.core.geometry import quaternion_matrices
from lidar_weather_sim.core.points import Label, empty_points, fill_polar, point_dtype
from lidar_weather_sim.core.scratch import Scratch
from lidar_weather_sim.core.seeding import Reseedable
from lidar_weather_sim.regions.base import RayBatch, Region, RegionEffect, combine, region_entropy, region_rng
from lidar_weather_sim.sensor.echo import Echoes, detect_echoes, select_returns
from lidar_weather_sim.sensor.profile import SensorProfile
from lidar_weather_sim.sensor.radiometry import Threshold, dark_level, overlap_factor, peak_amplitude
from lidar_weather_sim.sensor.response import SensorResponse, apply_response
from lidar_weather_sim.sensor.scan import ScanPattern
from lidar_weather_sim.sensor.volume_tables import Volume, stack_volume
from lidar_weather_sim.sim.kernels import (
    KeptEchoes,
    ScanTables,
    compact_candidates,
    fill_points,
    kept_echoes,
    occluded_candidates,
    range_noise,
    surface_returns,
    world_rays,
)

#: :meth:`LidarSimulator._returns` of return mode ``all``: no selection, every echo is reported.
_EVERY_ECHO = np.zeros(0, np.uint8)
#: Sub-rays in a batch from which its regions are applied side by side and its detection runs behind the
#: next batch's cast: below, the threads' hand-overs (and the GIL's 5 ms switch interval) cost more than they save.
PARALLEL_MIN_RAYS = 20000


class PoseSource(Protocol):
    def sensor_poses(self, times_s: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """World (fixed-frame) pose of the sensor at each time: translations (N, 3) m, quaternions (N, 4) xyzw."""

    def actor_poses(self, time_s: float) -> dict[int, np.ndarray]:
        """Body-to-world 4x4 transform of every actor present at ``time_s``.

        A pose source may also offer ``actor_poses_at(times_s) -> list[dict]`` (the same for
        several times at once), or ``poses_at(sensor_times_s, actor_times_s)`` -> (translations,
        quaternions, list[dict]) (both at once); the simulator then uses it once per ``advance``."""


def scenario_settings(scenario) -> dict:
    """What the simulator takes from a scenario besides its world: ``seed``, ``sun_irradiance_w_m2``
    (W/m^2, from ``weather.sun``), ``response`` (``sensor.response``), ``elevation_offsets_deg``
    (``sensor.elevation_offsets_deg``) and ``beam_origin_m`` (``sensor.beam_origin_radial_m`` and
    ``beam_origin_z_m``), as keyword arguments of :class:`LidarSimulator` and :meth:`~LidarSimulator.restart`."""
    return {"seed": int(scenario.seed), "sun_irradiance_w_m2": float(scenario.weather.sun.irradiance_w_m2),
            "response": scenario.sensor.response,
            "elevation_offsets_deg": dict(scenario.sensor.elevation_offsets_deg),
            "beam_origin_m": (float(scenario.sensor.beam_origin_radial_m), float(scenario.sensor.beam_origin_z_m))}  # fmt: skip


@dataclass
class Frame:
    index: int
    stamp_s: float  # scan start, simulated time (s)
    points: np.ndarray
    rays: int


@dataclass
class _FrameAccumulator:
    index: int
    start_s: float
    next_column: int = 0
    points: np.ndarray | None = None  # room for every echo the frame can have; filled from the start
    count: int = 0  # points filled
    rays: int = 0


class LidarSimulator:
    """Virtual LiDAR over a scene; call :meth:`advance` whenever the sensor pose advances.

    ``caster`` casts the rays (``scene.caster(backend)``, built once by whoever owns the scene - a
    :class:`~lidar_weather_sim.scenario.world.World` - and shared by every simulator of it); without
    one the scene's caster on ``backend`` is built here. ``scene`` gives the material table and the
    actors' labels; ``sun_irradiance_w_m2`` (W/m^2) raises the noise floor; ``response`` is the unit's
    departure from the model after detection (:mod:`lidar_weather_sim.sensor.response`);
    ``elevation_offsets_deg`` (channel -> deg) raises channels off the profile's table
    (:meth:`~lidar_weather_sim.sensor.profile.SensorProfile.with_elevation_offsets`); ``beam_origin_m``
    (radial, up; m) puts the beams' origin that far out from the axis (along the column's azimuth, turning with
    the head) and above the sensor frame's origin (the pose), in which the points are still reported (a
    driver whose point frame is not the beams' origin, as Ouster's); ``seed`` seeds
    every random stream (same seed and poses, same clouds).

    ``reflectivity_through_air`` (default False): the scene's surveyed reflectivity was measured through the air
    the regions now put between sensor and surface (a twin re-simulated under the weather its recording is
    supposed to hold, as the gap search does): a static hit on a triangle with a recorded range R
    (:attr:`~lidar_weather_sim.scene.scene.Scene.recorded_range_m`) gets its reflectivity back by exp(2 alpha R),
    alpha the regions' extinction on its sub-ray, so the air's loss counts once. Off, the reflectivity is the
    surface's own and the air dims it (a twin of a clear recording put in fog).
    """

    def __init__(
        self,
        profile: SensorProfile,
        scene,
        *,
        caster=None,
        backend: str | None = None,
        regions: list[tuple[str, Region]] | None = None,
        seed: int = 0,
        sun_irradiance_w_m2: float = 0.0,
        response: SensorResponse | None = None,
        elevation_offsets_deg: dict[int, float] | None = None,
        beam_origin_m: tuple[float, float] = (0.0, 0.0),
        ground_truth: bool = True,
        max_catch_up_frames: int = 10,
    ) -> None:
        self._nominal_profile = profile  # the profile's own elevation table (offsets apply to it)
        self.elevation_offsets_deg: dict[int, float] = {}
        self._set_profile(profile.with_elevation_offsets(elevation_offsets_deg or {}))
        self.elevation_offsets_deg = dict(elevation_offsets_deg or {})
        self.beam_origin_m = (float(beam_origin_m[0]), float(beam_origin_m[1]))
        self.scene = scene
        self.caster = scene.caster(backend) if caster is None else caster
        self._part_caster = None  # the scene's sensor_parts (fixed to the sensor), cast in the sensor frame
        parts = getattr(scene, "sensor_parts", None)
        if parts is not None and len(parts.triangles):
            from lidar_weather_sim.scene.raycast.scene_caster import SceneCaster

            self._part_caster = SceneCaster(parts, {}, backend=getattr(self.caster, "backend", backend))
        self.regions = list(regions or [])
        self.seed = int(seed)
        self.sun_irradiance_w_m2 = float(sun_irradiance_w_m2)
        self.response = response or SensorResponse()
        self.ground_truth = ground_truth
        self.max_catch_up_frames = max_catch_up_frames
        # material tables with a last row for "no hit" (material index -1)
        mats = scene.materials
        self._reflectivity = np.append(mats.reflectivity, 0.0)
        self._retro = np.append(mats.retro_share, 0.0)
        self._material_label = np.append(np.asarray(mats.labels, dtype=np.uint8), np.uint8(Label.UNKNOWN))
        recorded = getattr(scene, "recorded_range_m", None)
        # per static triangle (a last row for "no static hit", triangle -1): 0 where not surveyed
        self._recorded_range = None if recorded is None else np.append(np.nan_to_num(recorded, nan=0.0), 0.0)
        self.reflectivity_through_air = False
        ids = np.array(sorted(scene.actor_labels) or [0])
        self._actor_label = np.full(int(ids.max()) + 1, Label.VEHICLE, dtype=np.uint8)
        for actor_id, label in scene.actor_labels.items():
            self._actor_label[actor_id] = label
        self._frame: _FrameAccumulator | None = None
        self._last_time_s: float | None = None
        self._scratch = Scratch()  # per-batch temporaries of the detection stages, reused
        self._ray_scratch = Scratch()  # the rays' (cast while the previous batch's detection runs)
        self._detection: Future | None = None  # the last batch's detection, running in the background
        self._noise = Reseedable()  # the receiver's noise streams (region_rng's), seeded per batch
        self._region_time_s: float | None = None  # simulated time the regions were last stepped to

    @classmethod
    def of_world(cls, world, *, backend: str | None = None, regions: list[tuple[str, Region]] | None = None,
                 seed: int | None = None, caster=None, **options) -> "LidarSimulator":  # fmt: skip
        """The simulator of a :class:`~lidar_weather_sim.scenario.world.World`: its profile, scene and shared
        caster on ``backend`` (or ``caster``, e.g. one wrapping it), with the scenario's settings
        (:func:`scenario_settings`); ``regions`` (default: the scenario's), ``seed`` and ``options`` (e.g.
        ``sun_irradiance_w_m2``) override them."""
        settings = {**scenario_settings(world.scenario), **({} if seed is None else {"seed": seed}), **options}
        return cls(world.profile, world.scene, caster=world.caster(backend) if caster is None else caster,
                   regions=world.regions() if regions is None else regions, **settings)  # fmt: skip

    def _set_profile(self, profile: SensorProfile) -> None:
        """Use ``profile`` (its scan pattern and point tables built anew)."""
        self.profile = profile
        self.pattern = ScanPattern(profile)
        self._column_times = self.pattern.column_time_s.tolist()  # for bisect (s)
        self._geo: tuple[np.ndarray, ...] | None = None  # see _point_tables

    # -- receiver ----------------------------------------------------------------
    def threshold(self) -> Threshold:
        """Noise mean and sigma raised by background light (sun irradiance, W/m^2)."""
        return Threshold.under_sun(self.profile.detection, self.sun_irradiance_w_m2)

    def dark_threshold(self) -> float:
        return dark_level(self.profile.detection)

    # -- time ----------------------------------------------------------------------
    def restart(self, *, regions: list[tuple[str, Region]] | None = None, sun_irradiance_w_m2: float | None = None,
                seed: int | None = None, response: SensorResponse | None = None,
                return_mode: str | None = None, elevation_offsets_deg: dict[int, float] | None = None,
                beam_origin_m: tuple[float, float] | None = None) -> None:  # fmt: skip
        """Forget the scan in progress and the regions' clock; replace regions, sun (W/m^2), seed,
        sensor response, return mode (:data:`~lidar_weather_sim.core.names.RETURN_MODES`), the channels'
        elevation offsets (channel -> deg, on the profile's own table; {}: none) and the beams' origin (radial,
        up; m) where given. The scene and
        its caster stay (no rebuild): re-simulating the same frames with other weather costs only the casts."""
        self.flush()
        self._frame = None
        self._last_time_s = None
        self._region_time_s = None
        if regions is not None:
            self.regions = list(regions)
        if sun_irradiance_w_m2 is not None:
            self.sun_irradiance_w_m2 = float(sun_irradiance_w_m2)
        if seed is not None:
            self.seed = int(seed)
        if response is not None:
            self.response = response
        if elevation_offsets_deg is not None and dict(elevation_offsets_deg) != self.elevation_offsets_deg:
            mode = self.profile.detection.return_mode
            self._set_profile(self._nominal_profile.with_elevation_offsets(elevation_offsets_deg).with_return_mode(mode))
            self.elevation_offsets_deg = dict(elevation_offsets_deg)
        if return_mode is not None and return_mode != self.profile.detection.return_mode:
            self.profile = self.profile.with_return_mode(return_mode)
        if beam_origin_m is not None:
            self.beam_origin_m = (float(beam_origin_m[0]), float(beam_origin_m[1]))

    def cast_frame(self, index: int, start_s: float, poses: PoseSource, batch_s: float | None = None) -> Frame:
        """Cast the whole frame ``index`` (its scan pattern: scala4 alternates layers by index) whose
        scan starts at ``start_s`` (simulated s), e.g. to re-simulate a recorded frame, in batches of
        ``batch_s`` (s; None = one batch) as :meth:`advance` would at that pose rate. Regions step
        from their last time to this frame's, so call it in increasing time."""
        if self._last_time_s is not None and start_s < self._last_time_s:
            raise ValueError(f"time went backwards: frame at {start_s:.6f} s after {self._last_time_s:.6f} s")
        self._frame = _FrameAccumulator(int(index), float(start_s))
        self._last_time_s = None
        last_column_s = float(self.pattern.column_time_s[-1]) + 1e-7  # rounding of start_s + t never drops it
        steps = np.arange(batch_s, last_column_s, batch_s) if batch_s else np.zeros(0)
        for t in steps:
            self.advance(round(float(start_s) + float(t), 9), poses)
        frames = self.advance(float(start_s) + last_column_s, poses)
        return frames[0]

    def advance(self, time_s: float, poses: PoseSource) -> list[Frame]:
        """Cast every column fired up to ``time_s`` (simulated, s); return the frames completed."""
        period = self.profile.period_s
        if self._frame is None:
            self._frame = _FrameAccumulator(0, float(time_s))
        if self._last_time_s is not None and time_s < self._last_time_s:
            raise ValueError(f"time went backwards: {time_s:.6f} s after {self._last_time_s:.6f} s")
        self._last_time_s = time_s
        behind = int((time_s - self._frame.start_s) // period)
        if behind > self.max_catch_up_frames:  # a jump in time: restart the scan instead of casting stale frames
            skipped = behind - 1
            self._frame = _FrameAccumulator(self._frame.index + skipped, self._frame.start_s + skipped * period)
        # Plan the batches (the columns fired up to time_s, frame by frame), evaluate the poses of
        # all of them at once (per-call costs of the pose source), then cast them in order.
        n_columns = self.pattern.n_columns
        plans = []  # (accumulator, first column, end column)
        acc, next_column = self._frame, self._frame.next_column
        while True:
            last = bisect.bisect_right(self._column_times, time_s - acc.start_s)  # np.searchsorted(side="right")
            if last > next_column:
                plans.append((acc, next_column, last))
                next_column = last
            if next_column < n_columns:
                break
            acc, next_column = _FrameAccumulator(acc.index + 1, acc.start_s + period), 0
        frames = []
        if plans:
            times = [p[0].start_s + self.pattern.column_time_s[p[1] : p[2]] for p in plans]
            mean = [float(np.add.reduce(t) / len(t)) for t in times]  # t.mean(), without its per-call overhead
            translation, rotation, actors = _poses(poses, np.concatenate(times), mean)
            k = 0
            for (batch_acc, first, end), batch_times, actor_poses in zip(plans, times, actors):
                self._frame = batch_acc
                sl = slice(k, k + len(batch_times))
                self._cast(batch_acc, np.arange(first, end), batch_times, translation[sl], rotation[sl], actor_poses)
                k += len(batch_times)
                batch_acc.next_column = end
                if end >= n_columns:
                    self.flush()
                    frames.append(self._finish(batch_acc))
        self._frame = acc
        return frames

    def _finish(self, acc: _FrameAccumulator) -> Frame:
        points = acc.points[: acc.count] if acc.points is not None else empty_points(0, self.ground_truth)
        radial, up = self.beam_origin_m
        if (radial or up) and len(points):  # cast from the beams' origin, reported in the sensor frame
            azimuth = points["azimuth"].astype(np.float64)
            points["x"] += radial * np.cos(azimuth)
            points["y"] += radial * np.sin(azimuth)
            points["z"] += up
            fill_polar(points)
        if not self.response.identity:
            rng = np.random.default_rng(region_entropy(self.seed, acc.index, "sensor_response", 0))
            points = apply_response(points, self.response, rng, float(self.profile.range.min_m))
        return Frame(acc.index, acc.start_s, points, acc.rays)

    # -- one batch: the pipeline ---------------------------------------------------------
    def _cast(self, acc: _FrameAccumulator, columns: np.ndarray, times: np.ndarray, translation: np.ndarray,
              rotation: np.ndarray, actor_poses: dict[int, np.ndarray]) -> None:  # fmt: skip
        """Cast ``columns`` (a run) of frame ``acc`` fired at ``times`` (s) from the sensor poses
        (translations (C, 3) m, rotation matrices (C, 3, 3), map frame) with the actors at ``actor_poses``."""
        directions = self._directions(acc.index, columns)
        radial, up = self.beam_origin_m
        if radial or up:  # the beams' origin in the sensor frame, turning with the head
            azimuth = self.pattern.column_azimuth[columns]
            local = np.stack([radial * np.cos(azimuth), radial * np.sin(azimuth), np.full(len(columns), up)], axis=1)
            translation = translation + np.einsum("cij,cj->ci", rotation, local)
        origins32, dirs32, dirs64 = world_rays(directions, rotation, translation, bool(self.regions), self._ray_scratch)
        hits = self._cast_rays(origins32, dirs32, actor_poses)
        if self._part_caster is not None:
            self._cast_sensor_parts(hits, directions, rotation, columns)
        ray_batch, effect = self._regions(acc.index, columns, times, translation, directions, dirs64, hits)
        self.flush()
        args = (acc, columns, directions, rotation, hits, ray_batch, effect)
        # the caster's arrays are new with regions (_cast_rays)
        if self.regions and workers.THREADS > 1 and hits.distance.size >= PARALLEL_MIN_RAYS:
            self._detection = workers.background().submit(self._detect, *args)
        else:
            self._detect(*args)

    def flush(self) -> None:
        """Wait for the detection of the last batch cast (with regions it runs in the background while the
        next batch is cast and its regions applied; its error, if any, is raised here). :meth:`advance` does
        before it returns a frame; call it before changing ``seed``, ``sun_irradiance_w_m2`` or ``regions``
        between calls (:meth:`restart` does)."""
        detection, self._detection = self._detection, None
        if detection is not None:
            detection.result()

    def _detect(self, acc: _FrameAccumulator, columns: np.ndarray, directions: np.ndarray, rotation: np.ndarray, hits,
                ray_batch: RayBatch | None, effect: RegionEffect | None) -> None:  # fmt: skip
        """The batch's candidates, echoes and points, appended to ``acc``. Reads neither the rays' scratch
        nor the regions: it may run while the next batch is cast."""
        candidates, segments = self._candidates(hits, directions, rotation, ray_batch, effect)
        candidates, segments = self._add_false_alarms(candidates, segments, len(columns) * directions.shape[1],
                                                      acc.index, int(columns[0]))  # fmt: skip
        echoes = self._echoes(candidates, segments, _volume(ray_batch, effect))
        self._points(echoes, self._returns(echoes), columns, directions.shape[1], acc, int(columns[0]))
        acc.rays += directions.shape[0] * directions.shape[1] * directions.shape[2]

    def _directions(self, frame_index: int, columns: np.ndarray) -> np.ndarray:
        """Sensor-frame unit sub-ray directions (C, B, S, 3) of ``columns`` in frame ``frame_index``'s pattern."""
        table = self.pattern.direction_table(frame_index)
        first = int(columns[0])
        if columns[-1] - first + 1 == len(columns):  # a run of columns (always, from advance): a view
            return table[first : first + len(columns)]
        return table[columns]

    def _cast_rays(self, origins32: np.ndarray, dirs32: np.ndarray, actor_poses: dict[int, np.ndarray]):
        """The caster's nearest hits of the map-frame rays. Regions get the hits in the ray batch and may
        keep them: then the caster's arrays must be new; without regions the LIDAR-equation kernel
        gathers the static hits' attributes itself."""
        return self.caster.cast(origins32, dirs32, actor_poses, self.profile.range.max_m, reuse=not self.regions,
                                gather=bool(self.regions))  # fmt: skip

    def _cast_sensor_parts(self, hits, directions: np.ndarray, rotation: np.ndarray, columns: np.ndarray) -> None:
        """The scene's fixed parts of the sensor (``scene.sensor_parts``, sensor frame) cast with the sensor-frame
        rays of ``columns`` (from the beams' origin); where one is nearer than the scene's hit it replaces it in
        ``hits`` as an actor's hit (its object id as the actor, the normal turned into the map frame by each
        column's ``rotation``). Exact at every column's firing time: the parts move with the sensor."""
        d = directions.reshape(-1, 3)
        per_column = len(d) // len(columns)
        radial, up = self.beam_origin_m
        if radial or up:
            azimuth = self.pattern.column_azimuth[columns]
            local = np.stack([radial * np.cos(azimuth), radial * np.sin(azimuth), np.full(len(columns), up)], axis=1)
            origins = np.repeat(local, per_column, axis=0)
        else:
            origins = np.zeros_like(d)
        part = self._part_caster.cast(origins, d, {}, self.profile.range.max_m)
        idx = np.flatnonzero(part.distance < hits.distance)
        if not len(idx):
            return
        column = idx // per_column
        hits.distance[idx] = part.distance[idx]
        hits.triangle[idx] = -1
        hits.normal[idx] = np.einsum("nij,nj->ni", rotation[column], part.normal[idx].astype(np.float64))
        hits.material[idx] = part.material[idx]
        hits.object_id[idx] = part.object_id[idx]
        hits.hit_actor[idx] = part.object_id[idx]

    def _regions(self, frame_index: int, columns: np.ndarray, times: np.ndarray, translation: np.ndarray,
                 directions: np.ndarray, dirs64: np.ndarray, hits) -> tuple[RayBatch | None, RegionEffect | None]:  # fmt: skip
        """The ray batch the regions see and their combined effect on it (None, None without regions).
        The regions step in simulated time to the batch's mean firing time before they are sampled."""
        if not self.regions:
            return None, None
        pattern = self.pattern
        n_cols, n_beams, n_sub = directions.shape[:3]
        n, shape = n_cols * n_beams, (n_cols * n_beams, n_sub)
        material = hits.material.reshape(shape)
        label = self._material_label[material]
        actor = hits.hit_actor.reshape(shape)
        if (actor >= 0).any():
            label = np.where(actor >= 0, self._actor_label[np.maximum(actor, 0)], label)
        ray_batch = RayBatch(
            frame_index=frame_index,
            origins=np.repeat(translation, n_beams, axis=0),
            directions=dirs64.reshape(n, n_sub, 3),
            sensor_directions=directions.reshape(n, n_sub, 3),
            channel=np.tile(pattern.active_channels(frame_index), n_cols),
            time_s=np.repeat(times, n_beams),
            weights=pattern.subray_weight,
            distance=hits.distance.reshape(shape).astype(np.float64),
            normal=hits.normal.reshape(n, n_sub, 3),
            material=material,
            object_id=hits.object_id.reshape(shape),
            label=label,
            column=np.repeat(columns, n_beams),
        )
        batch_time = float(times.mean())
        previous = self._region_time_s
        for _, region in self.regions:
            region.step(batch_time if previous is None else previous, batch_time)
        self._region_time_s = batch_time
        first = int(columns[0])
        # regions are independent of each other (own state, own random stream): a large batch applies them
        # side by side
        def apply(k: int) -> RegionEffect:
            name, region = self.regions[k]
            return region.apply(ray_batch, region_rng(self.seed, frame_index, name, first))

        if n * n_sub >= PARALLEL_MIN_RAYS:
            effects = workers.run_chunks(apply, len(self.regions))
        else:
            effects = [apply(k) for k in range(len(self.regions))]
        return ray_batch, combine(effects, shape)

    def _echoes(self, candidates, segments, volume: Volume | None = None) -> Echoes:
        """The threshold decision on each beam's waveform (:func:`~lidar_weather_sim.sensor.echo.detect_echoes`),
        with the beams' ``volume`` returns (None: none)."""
        profile = self.profile
        return detect_echoes(
            *candidates,
            threshold=self.threshold(),
            fwhm_m=profile.pulse.fwhm_m,
            resolution_m=profile.range.resolution_m,
            max_echoes=profile.detection.max_echoes,
            segments=segments,
            scratch=self._scratch,
            volume=volume,
        )

    def _returns(self, echoes: Echoes) -> np.ndarray:
        """The return type each echo is reported as under the profile's return mode, 0 for one it does not
        report (:func:`~lidar_weather_sim.sensor.echo.select_returns`); empty for ``all`` (every echo)."""
        mode = self.profile.detection.return_mode
        if mode == "all":
            return _EVERY_ECHO
        out = self._scratch.get("reported", len(echoes.beam), np.uint8)
        return select_returns(echoes.beam, echoes.amplitude, echoes.runs, mode, out)

    def _candidates(self, hits, directions, rotation, rays: RayBatch | None, effect):
        """Candidate returns (beam, range, amplitude, label, object id) of scene hits and scatterers,
        and the runs of those arrays that hold them (see :func:`surface_returns`; None: all).

        ``rays`` and ``effect`` are None without regions (no scaling, offset or losses)."""
        profile = self.profile
        n_cols, n_beams, n_sub = directions.shape[:3]
        n = n_cols * n_beams
        C = profile.detection.power_constant
        optics = profile.optics
        sc = effect.scatterers if effect is not None else None
        if effect is not None:
            hit = np.isfinite(rays.distance)
            rng_m = np.where(hit, rays.distance + effect.range_offset_m, np.inf)
            one_way = effect.transmission
            alpha = effect.extinction_per_m
            t2 = one_way**2 * np.exp(-2.0 * alpha * np.where(hit, rng_m, 0.0))
            if self.reflectivity_through_air and self._recorded_range is not None:
                t2 = t2 * np.exp(2.0 * alpha * self._recorded_range[hits.triangle].reshape(n, n_sub))
            scale = np.ascontiguousarray(np.broadcast_to(effect.reflectance_scale, (n, n_sub)), np.float64)
            offset = np.ascontiguousarray(np.broadcast_to(effect.range_offset_m, (n, n_sub)), np.float64)
            t2 = np.ascontiguousarray(np.broadcast_to(t2, (n, n_sub)), np.float64)
        else:
            scale = offset = t2 = np.zeros((1, 1))
        beam, rng_m, amp, label, obj, segments = surface_returns(
            (hits.distance, hits.triangle, hits.normal, hits.material, hits.hit_actor, hits.object_id),
            self.caster.static_tables, directions, rotation, self._reflectivity, self._retro, self._material_label,
            self._actor_label, self.pattern.subray_weight, float(C), float(optics.overlap_start_m),
            float(optics.overlap_full_m), effect is not None, scale, offset, t2, sc is None, self._scratch,
        )  # fmt: skip
        if sc is None:
            return (beam, rng_m, amp, label, obj), segments
        b, s = sc.beam, sc.subray
        t2 = one_way[b, s] ** 2 * np.exp(-2.0 * alpha[b, s] * sc.range_m)
        overlap = overlap_factor(sc.range_m, optics.overlap_start_m, optics.overlap_full_m)
        if sc.bypass_overlap is not None:
            overlap = np.where(sc.bypass_overlap, 1.0, overlap)
        sc_amp = peak_amplitude(C, rays.weights[s], sc.reflectance, sc.range_m, t2, overlap)
        return self._occlusion((rng_m, amp, rays.label.ravel(), rays.object_id.ravel()),
                               (b, s, sc.range_m, sc_amp, sc.label, sc.object_id, sc.occlusion), n, n_sub)

    def _occlusion(self, surface, scatterers, n_beams: int, n_sub: int):
        """Scene hits (every sub-ray's) and scatterers of the batch as candidates grouped by beam, each
        scaled by the two-way light the candidates in front of it on its sub-ray leave
        (:func:`~lidar_weather_sim.sim.kernels.occluded_candidates`): those left with light, and their runs."""
        *candidates, segments = occluded_candidates(surface, scatterers, n_beams, n_sub, self._scratch)
        return tuple(candidates), segments

    def _add_false_alarms(self, candidates, segments, n_beams: int, frame: int, first_column: int):
        rate = self.profile.detection.false_alarms_per_beam
        if rate <= 0:
            return candidates, segments
        if segments is not None:
            candidates = compact_candidates(candidates, segments)
        rng = self._noise.seed(region_entropy(self.seed, frame, "noise_floor", first_column))
        count = rng.poisson(rate, n_beams)
        beam = np.repeat(np.arange(n_beams), count)
        lo = max(self.profile.optics.overlap_start_m, self.profile.range.min_m)
        ranges = rng.uniform(lo, self.profile.range.max_m, len(beam))
        amp = self.threshold().level * (1.0 + rng.exponential(0.2, len(beam)))
        extra = (beam, ranges, amp, np.full(len(beam), Label.NOISE, np.uint8), np.zeros(len(beam), np.uint32))
        return tuple(np.concatenate([a, e]) for a, e in zip(candidates, extra)), None

    def _points(self, echoes, reported: np.ndarray, columns: np.ndarray, n_beams: int, acc: _FrameAccumulator,
                first_column: int) -> None:  # fmt: skip
        """Append to the frame the points of the echoes the return mode reports (``reported``, see
        :meth:`_returns`) at or beyond the minimum range after range noise. Intensity is 0-255, logarithmic in the peak amplitude above the dark threshold
        (0 = at threshold, 255 = ``intensity_dynamic_range`` times above it)."""
        profile = self.profile
        starts, counts = echoes.runs
        rng = self._noise.seed(region_entropy(self.seed, acc.index, "range_noise", first_column))
        # where the echoes are: their ranges with noise; of those kept, the indices and amplitude ratios
        ranges, kept, log_ratio = (self._scratch.get(name, len(echoes.range_m), dtype) for name, dtype in
                                   (("noisy_range", np.float64), ("kept", np.int64), ("log_ratio", np.float64)))  # fmt: skip
        noise = range_noise(rng, float(profile.range.noise_sigma_m), int(counts.sum()), self._scratch)
        count = kept_echoes(noise, echoes.range_m, echoes.amplitude, starts, counts, max(profile.range.min_m, 0.0),
                             self.dark_threshold(), ranges, kept, log_ratio, reported)  # fmt: skip
        kept, log_ratio = kept[:count], log_ratio[:count]
        if acc.points is None:
            # at most max_echoes per beam: one allocation per frame, no copies (pages never written cost nothing)
            size = self.pattern.n_columns * len(self.pattern.active_channels(acc.index)) * profile.detection.max_echoes
            acc.points = np.empty(size, point_dtype(self.ground_truth))
        points = acc.points[acc.count : acc.count + len(kept)]
        acc.count += len(kept)
        if not len(kept):
            return
        span = np.log(profile.detection.intensity_dynamic_range)
        np.log(log_ratio, out=log_ratio)
        geo = self._point_tables()
        fill_points(
            points, kept, KeptEchoes(ranges, echoes.beam, echoes.echo, echoes.epw_m, reported), log_ratio, float(span),
            ScanTables(np.ascontiguousarray(columns, np.int64), self.pattern.active_channels(acc.index), n_beams, *geo),
            (echoes.label, echoes.object_id) if self.ground_truth else None,
        )  # fmt: skip

    def _point_tables(self) -> tuple[np.ndarray, ...]:
        """Per (column, channel): cos and sin of the azimuth, the wrapped azimuth; per channel: cos
        and sin of the elevation, the elevation; per column: the time stamp (ns). Built once."""
        if self._geo is None:
            pattern = self.pattern
            az = pattern.column_azimuth[:, None] + pattern.azimuth_offset[None, :]
            cos_az, sin_az = np.cos(az), np.sin(az)
            el = np.ascontiguousarray(pattern.elevation, dtype=np.float64)
            stamp = np.round(pattern.column_time_s * 1e9).astype(np.uint32)
            self._geo = (cos_az, sin_az, np.arctan2(sin_az, cos_az), np.cos(el), np.sin(el), el, stamp)
        return self._geo


def _volume(rays: RayBatch | None, effect: RegionEffect | None) -> Volume | None:
    """The volume returns of ``effect`` on the batch's beams as the echo kernel reads them (None: none): each
    term one layer (each beam its table of the term's), cut at its hit (default: the central sub-ray's scene hit
    moved by the range offset, inf on a miss) and scaled by the beam's two-way transmission (its sub-rays' mean,
    weighted by their share of the energy: the volume fills them all) and the light the central sub-ray's
    scatterers leave (each as if in front of the whole volume: the cover's returns are; a drop blocks ~1e-4)."""
    if effect is None or not effect.volume:
        return None
    core = int(np.argmax(rays.weights))
    distance = rays.distance[:, core]
    scene_hit = np.where(np.isfinite(distance), distance + effect.range_offset_m[:, core], np.inf)
    one_way = effect.transmission
    two_way = one_way[:, core] ** 2  # exact where every sub-ray passes the same light
    # column by column: numpy's any(axis=1) over (N, 3) takes ~6x as long
    mixed = np.flatnonzero(np.logical_or.reduce([one_way[:, k] != one_way[:, 0] for k in range(one_way.shape[1])]))
    if len(mixed):
        weights = np.asarray(rays.weights, dtype=np.float64)
        two_way[mixed] = one_way[mixed] ** 2 @ (weights / weights.sum())
    sc = effect.scatterers
    if sc is not None:  # what the central sub-ray's scatterers leave of its light (the cover's returns lie in front)
        on_core = (sc.subray == core) & (sc.occlusion > 0)
        np.multiply.at(two_way, sc.beam[on_core], (1.0 - sc.occlusion[on_core]) ** 2)
    tables = list({id(t): t for term in effect.volume for t in term.tables}.values())
    index = {id(table): k for k, table in enumerate(tables)}
    n = len(distance)
    layers = [(np.array([index[id(t)] for t in term.tables])[term.beam_table(n)], two_way * term.scale,
               scene_hit if term.hit_m is None else term.hit_m) for term in effect.volume]  # fmt: skip
    table = np.stack([np.where(scale > 0, k, -1) for k, scale, _ in layers], axis=1)
    scale = np.stack([np.broadcast_to(scale, n) for _, scale, _ in layers], axis=1)
    hit_m = np.stack([np.broadcast_to(hit, n) for _, _, hit in layers], axis=1)
    return stack_volume(tables, table, scale, hit_m)


def _poses(poses: PoseSource, times: np.ndarray, actor_times: list[float]):
    """Sensor translations (C, 3) and rotation matrices (C, 3, 3), float64, at each column time (s)
    and the actors' poses at each of ``actor_times`` (s), from the pose source's fewest calls."""
    both = getattr(poses, "poses_at", None)
    if both is not None:
        translation, quaternion, actors = both(times, actor_times)
    else:
        translation, quaternion = poses.sensor_poses(times)
        many = getattr(poses, "actor_poses_at", None)
        actors = many(actor_times) if many is not None else [poses.actor_poses(t) for t in actor_times]
    translation = np.ascontiguousarray(translation, dtype=np.float64)
    return translation, quaternion_matrices(np.asarray(quaternion, dtype=np.float64)), actors
