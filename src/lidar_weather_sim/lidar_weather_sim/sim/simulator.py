"""The virtual LiDAR: incremental casting of the scan, regions, echo decision, frames.

Data path per batch of columns (the columns swept since the last pose update):
scan pattern -> sensor pose per column (rolling shutter) -> backend cast ->
regions -> candidate returns with LIDAR-equation amplitudes -> echo decision
(:mod:`lidar_weather_sim.sensor.echo`) -> points in the sensor frame at their own
firing time. A frame is returned when its sweep is complete; its stamp is the
scan start and every point's ``time_stamp`` is its column's firing time after
that (ns).

Speed (``benchmarks/sim_frame_time.py``): ``advance`` plans its batches first and
asks the pose source once for all their sensor poses (one per column, exact) and
actor poses; the sensor-frame sub-ray directions are a table per set of active
channels; rotation, the LIDAR equation, echo detection and point assembly are numba
kernels that reproduce the numpy expressions operation for operation (same clouds,
bit for bit), run in chunks on all cores (:mod:`lidar_weather_sim.core.workers`); large
temporaries are reused from batch to batch and each frame's points are written into
one buffer.
"""

from __future__ import annotations

import bisect
import functools
from dataclasses import dataclass
from typing import Protocol

import numba
import numpy as np

from lidar_weather_sim.core import workers
from lidar_weather_sim.core.geometry import quaternion_matrices
from lidar_weather_sim.core.points import Label, empty_points, point_dtype
from lidar_weather_sim.core.seeding import Reseedable
from lidar_weather_sim.regions.base import RayBatch, Region, combine, region_entropy, region_rng
from lidar_weather_sim.sensor.echo import (
    MIN_RANGE_M,
    RETRO_GAIN,
    Threshold,
    detect_echoes,
    overlap_factor,
    peak_amplitude,
)
from lidar_weather_sim.sensor.profile import SensorProfile
from lidar_weather_sim.sensor.scan import ScanPattern

#: Nebula return types (nebula_common ReturnType).
RETURN_LAST, RETURN_FIRST, RETURN_IDENTICAL, RETURN_SECOND = 1, 2, 6, 7


class PoseSource(Protocol):
    def sensor_poses(self, times_s: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """World (fixed-frame) pose of the sensor at each time: translations (N, 3) m, quaternions (N, 4) xyzw."""

    def actor_poses(self, time_s: float) -> dict[int, np.ndarray]:
        """Body-to-world 4x4 transform of every actor present at ``time_s``.

        A pose source may also offer ``actor_poses_at(times_s) -> list[dict]`` (the same for
        several times at once), or ``poses_at(sensor_times_s, actor_times_s)`` -> (translations,
        quaternions, list[dict]) (both at once); the simulator then uses it once per ``advance``."""


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
    """Virtual LiDAR over a scene; call :meth:`advance` whenever the sensor pose advances."""

    def __init__(
        self,
        profile: SensorProfile,
        scene,
        *,
        backend: str | None = None,
        regions: list[tuple[str, Region]] | None = None,
        seed: int = 0,
        sun_irradiance_w_m2: float = 0.0,
        ground_truth: bool = True,
        max_catch_up_frames: int = 10,
    ) -> None:
        from lidar_weather_sim.scene.raycast.scene_caster import SceneCaster

        self.profile = profile
        self.pattern = ScanPattern(profile)
        self._column_times = self.pattern.column_time_s.tolist()  # for bisect (s)
        self.scene = scene
        self.caster = SceneCaster(scene.static, scene.actors, backend=backend)
        self.regions = list(regions or [])
        self.seed = int(seed)
        self.sun_irradiance_w_m2 = float(sun_irradiance_w_m2)
        self.ground_truth = ground_truth
        self.max_catch_up_frames = max_catch_up_frames
        # material tables with a last row for "no hit" (material index -1)
        mats = scene.materials
        self._reflectivity = np.append(mats.reflectivity, 0.0)
        self._retro = np.append(mats.retro_share, 0.0)
        self._material_label = np.append(np.asarray(mats.labels, dtype=np.uint8), np.uint8(Label.UNKNOWN))
        ids = np.array(sorted(scene.actor_labels) or [0])
        self._actor_label = np.full(int(ids.max()) + 1, Label.VEHICLE, dtype=np.uint8)
        for actor_id, label in scene.actor_labels.items():
            self._actor_label[actor_id] = label
        self._frame: _FrameAccumulator | None = None
        self._last_time_s: float | None = None
        self._geo: tuple[np.ndarray, ...] | None = None  # see _point_tables
        self._scratch = workers.Scratch()  # per-batch temporaries, reused
        self._noise = Reseedable()  # the receiver's noise streams (region_rng's), seeded per batch
        self._region_time_s: float | None = None  # simulated time the regions were last stepped to

    # -- receiver ----------------------------------------------------------------
    def threshold(self) -> Threshold:
        """Noise mean and sigma raised by background light (sun irradiance, W/m^2)."""
        d = self.profile.detection
        e = self.sun_irradiance_w_m2
        return Threshold(
            d.noise_mean + d.sun_noise_per_w_m2 * e, d.noise_sigma + d.sun_sigma_per_w_m2 * e, d.threshold_sigma
        )

    def dark_threshold(self) -> float:
        d = self.profile.detection
        return d.noise_mean + d.threshold_sigma * d.noise_sigma

    # -- time ----------------------------------------------------------------------
    def restart(self, *, regions: list[tuple[str, Region]] | None = None, sun_irradiance_w_m2: float | None = None,
                seed: int | None = None) -> None:  # fmt: skip
        """Forget the scan in progress and the regions' clock; replace regions, sun (W/m^2) and seed
        where given. The scene and its caster stay (no rebuild): re-simulating the same frames with
        other weather costs only the casts."""
        self._frame = None
        self._last_time_s = None
        self._region_time_s = None
        if regions is not None:
            self.regions = list(regions)
        if sun_irradiance_w_m2 is not None:
            self.sun_irradiance_w_m2 = float(sun_irradiance_w_m2)
        if seed is not None:
            self.seed = int(seed)

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
                    frames.append(self._finish(batch_acc))
        self._frame = acc
        return frames

    def _finish(self, acc: _FrameAccumulator) -> Frame:
        points = acc.points[: acc.count] if acc.points is not None else empty_points(0, self.ground_truth)
        return Frame(acc.index, acc.start_s, points, acc.rays)

    # -- one batch -------------------------------------------------------------------
    def _cast(self, acc: _FrameAccumulator, columns: np.ndarray, times: np.ndarray, translation: np.ndarray,
              rotation: np.ndarray, actor_poses: dict[int, np.ndarray]) -> None:  # fmt: skip
        """Cast ``columns`` (a run) of frame ``acc`` fired at ``times`` (s) from the sensor poses
        (translations (C, 3), rotation matrices (C, 3, 3)) with the actors at ``actor_poses``."""
        profile, pattern = self.profile, self.pattern
        first = int(columns[0])
        table = pattern.direction_table(acc.index)
        if columns[-1] - first + 1 == len(columns):  # a run of columns (always, from advance): a view
            directions = table[first : first + len(columns)]
        else:
            directions = table[columns]
        n_cols, n_beams, n_sub = directions.shape[:3]
        n = n_cols * n_beams
        origins32, dirs32, dirs64 = _world_rays(directions, rotation, translation, bool(self.regions), self._scratch)
        # regions get the hits in the ray batch and may keep them: then the caster's arrays must be new;
        # without regions the LIDAR-equation kernel gathers the static hits' attributes itself
        hits = self.caster.cast(origins32, dirs32, actor_poses, profile.range.max_m, reuse=not self.regions,
                                gather=bool(self.regions))  # fmt: skip
        shape = (n, n_sub)
        ray_batch = effect = None
        if self.regions:
            material = hits.material.reshape(shape)
            label = self._material_label[material]
            actor = hits.hit_actor.reshape(shape)
            if (actor >= 0).any():
                label = np.where(actor >= 0, self._actor_label[np.maximum(actor, 0)], label)
            ray_batch = RayBatch(
                frame_index=acc.index,
                origins=np.repeat(translation, n_beams, axis=0),
                directions=dirs64.reshape(n, n_sub, 3),
                sensor_directions=directions.reshape(n, n_sub, 3),
                channel=np.tile(pattern.active_channels(acc.index), n_cols),
                time_s=np.repeat(times, n_beams),
                weights=pattern.subray_weight,
                distance=hits.distance.reshape(shape).astype(np.float64),
                normal=hits.normal.reshape(n, n_sub, 3),
                material=material,
                object_id=hits.object_id.reshape(shape),
                label=label,
            )
            batch_time = float(times.mean())  # regions advance in simulated time before they are sampled
            previous = self._region_time_s
            for _, region in self.regions:
                region.step(batch_time if previous is None else previous, batch_time)
            self._region_time_s = batch_time
            effects = [
                region.apply(ray_batch, region_rng(self.seed, acc.index, name, first)) for name, region in self.regions
            ]
            effect = combine(effects, shape)
        candidates, segments = self._candidates(hits, directions, rotation, ray_batch, effect)
        candidates, segments = self._add_false_alarms(candidates, segments, n, acc.index, first)
        echoes = detect_echoes(
            *candidates,
            threshold=self.threshold(),
            fwhm_m=profile.pulse.fwhm_m,
            resolution_m=profile.range.resolution_m,
            max_echoes=profile.detection.max_echoes,
            segments=segments,
            scratch=self._scratch,
        )
        self._points(echoes, columns, n_beams, acc, first)
        acc.rays += n * n_sub

    def _candidates(self, hits, directions, rotation, rays: RayBatch | None, effect):
        """Candidate returns (beam, range, amplitude, label, object id) of scene hits and scatterers,
        and the runs of those arrays that hold them (see :func:`_surface_returns`; None: all).

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
            scale = np.ascontiguousarray(np.broadcast_to(effect.reflectance_scale, (n, n_sub)), np.float64)
            offset = np.ascontiguousarray(np.broadcast_to(effect.range_offset_m, (n, n_sub)), np.float64)
            t2 = np.ascontiguousarray(np.broadcast_to(t2, (n, n_sub)), np.float64)
        else:
            scale = offset = t2 = np.zeros((1, 1))
        beam, rng_m, amp, label, obj, segments = _surface_returns(
            (hits.distance, hits.triangle, hits.normal, hits.material, hits.hit_actor, hits.object_id),
            self.caster.static_tables, directions, rotation, self._reflectivity, self._retro, self._material_label,
            self._actor_label, self.pattern.subray_weight, float(C), float(optics.overlap_start_m),
            float(optics.overlap_full_m), effect is not None, scale, offset, t2, sc is None, self._scratch,
        )  # fmt: skip
        if sc is None:
            return (beam, rng_m, amp, label, obj), segments
        # scatterers: every sub-ray stays a candidate until the occlusion is applied
        beam = np.broadcast_to(np.arange(n)[:, None], shape=(n, n_sub))
        subray = np.broadcast_to(np.arange(n_sub)[None, :], shape=(n, n_sub))
        cols = [beam.ravel(), subray.ravel(), rng_m, amp, rays.label.ravel(), rays.object_id.ravel(),
                np.ones(n * n_sub)]  # fmt: skip
        b, s = sc.beam, sc.subray
        t2 = one_way[b, s] ** 2 * np.exp(-2.0 * alpha[b, s] * sc.range_m)
        overlap = overlap_factor(sc.range_m, optics.overlap_start_m, optics.overlap_full_m)
        if sc.bypass_overlap is not None:
            overlap = np.where(sc.bypass_overlap, 1.0, overlap)
        sc_amp = peak_amplitude(C, rays.weights[s], sc.reflectance, sc.range_m, t2, overlap)
        extra = [b, s, sc.range_m, sc_amp, sc.label, sc.object_id, sc.occlusion]
        cols = [np.concatenate([a, e]) for a, e in zip(cols, extra)]
        cols[3] = _occlude(cols[0] * n_sub + cols[1], cols[2], cols[3], cols[6], n * n_sub)
        beam, _, rng_m, amp, label, obj, _ = cols
        keep = amp > 0
        return (beam[keep], rng_m[keep], amp[keep], label[keep].astype(np.uint8), obj[keep].astype(np.uint32)), None

    def _add_false_alarms(self, candidates, segments, n_beams: int, frame: int, first_column: int):
        rate = self.profile.detection.false_alarms_per_beam
        if rate <= 0:
            return candidates, segments
        if segments is not None:
            candidates = _compact_candidates(candidates, segments)
        rng = self._noise.seed(region_entropy(self.seed, frame, "noise_floor", first_column))
        count = rng.poisson(rate, n_beams)
        beam = np.repeat(np.arange(n_beams), count)
        lo = max(self.profile.optics.overlap_start_m, self.profile.range.min_m)
        ranges = rng.uniform(lo, self.profile.range.max_m, len(beam))
        amp = self.threshold().level * (1.0 + rng.exponential(0.2, len(beam)))
        extra = (beam, ranges, amp, np.full(len(beam), Label.NOISE, np.uint8), np.zeros(len(beam), np.uint32))
        return tuple(np.concatenate([a, e]) for a, e in zip(candidates, extra)), None

    def _points(self, echoes, columns: np.ndarray, n_beams: int, acc: _FrameAccumulator, first_column: int) -> None:
        """Append to the frame the points of the echoes at or beyond the minimum range after range
        noise. Intensity is 0-255, logarithmic in the peak amplitude above the dark threshold
        (0 = at threshold, 255 = ``intensity_dynamic_range`` times above it)."""
        profile = self.profile
        starts, counts = echoes.runs
        rng = self._noise.seed(region_entropy(self.seed, acc.index, "range_noise", first_column))
        # where the echoes are: their ranges with noise; of those kept, the indices and amplitude ratios
        ranges, kept, log_ratio = (self._scratch.get(name, len(echoes.range_m), dtype) for name, dtype in
                                   (("noisy_range", np.float64), ("kept", np.int64), ("log_ratio", np.float64)))  # fmt: skip
        noise = _range_noise(rng, float(profile.range.noise_sigma_m), int(counts.sum()), self._scratch)
        count = _kept_echoes(noise, echoes.range_m, echoes.amplitude, starts, counts, max(profile.range.min_m, 0.0),
                             self.dark_threshold(), ranges, kept, log_ratio)  # fmt: skip
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
        _fill_points(
            points, kept, ranges, echoes.beam, echoes.echo, echoes.epw_m, log_ratio, float(span),
            np.ascontiguousarray(columns, np.int64), self.pattern.active_channels(acc.index), n_beams, *geo,
            echoes.label, echoes.object_id, self.ground_truth, _padding_bytes(points.dtype),
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


def _occlude(key: np.ndarray, range_m: np.ndarray, amplitude: np.ndarray, occlusion: np.ndarray,
             n_keys: int) -> np.ndarray:  # fmt: skip
    """Scale each candidate by the two-way light left after the candidates in front of it on the
    same sub-ray (``key``, 0..n_keys - 1): prod over nearer ones of (1 - occlusion)^2."""
    order = _sub_ray_order(key, range_m, n_keys)
    k, occ = key[order], np.clip(occlusion[order], 0.0, 1.0)
    log_t = 2.0 * np.log(np.maximum(1.0 - occ, 1e-30))
    cum = np.cumsum(log_t)
    start = np.ones(len(k), bool)
    start[1:] = k[1:] != k[:-1]
    group_base = np.maximum.accumulate(np.where(start, np.arange(len(k)), 0))
    before = cum - log_t - (cum[group_base] - log_t[group_base])  # exclusive sum within the group
    out = np.empty_like(amplitude)
    out[order] = amplitude[order] * np.exp(before)
    return out


@numba.njit(cache=True)
def _sub_ray_order(key, range_m, n_keys):
    """``np.lexsort((range_m, key))`` for keys 0..n_keys - 1 with few candidates each: a counting
    sort by key, then an insertion sort by range per key (both stable; NaN last, as numpy)."""
    start = np.zeros(n_keys + 1, np.int64)
    for k in key:
        start[k + 1] += 1
    for k in range(n_keys):
        start[k + 1] += start[k]
    fill = start[:-1].copy()
    order = np.empty(len(key), np.int64)
    for i in range(len(key)):
        order[fill[key[i]]] = i
        fill[key[i]] += 1
    for k in range(n_keys):
        for q in range(start[k] + 1, start[k + 1]):
            i = order[q]
            r = range_m[i]
            p = q
            while p > start[k]:
                before = range_m[order[p - 1]]
                if not (before > r or (np.isnan(before) and not np.isnan(r))):
                    break
                order[p] = order[p - 1]
                p -= 1
            order[p] = i
    return order


# -- kernels ---------------------------------------------------------------------------
# They reproduce the numpy expressions they replace operation for operation (numpy's
# einsum adds three products as (p0 + p2) + p1), so the clouds are bit for bit the same.


#: Rays per chunk when a batch is shared between threads (:mod:`lidar_weather_sim.core.workers`).
CHUNK_RAYS = 32768


def _world_rays(directions, rotation, translation, want64, scratch=None):
    """Sensor-frame sub-ray directions (C, B, S, 3) rotated by each column's rotation (C, 3, 3):
    float32 origins and directions (C*B*S, 3) for the caster, column-major (transposes of
    (3, C*B*S) arrays, which Mitsuba takes without a copy; in ``scratch`` if given), and the
    float64 directions (C*B*S, 3) if ``want64`` (else an empty array)."""
    n_cols, n_beams, n_sub = directions.shape[:3]
    m = n_cols * n_beams * n_sub
    new = workers.allocator(scratch)
    o32 = new("origins32", (3, m), np.float32).T
    d32 = new("directions32", (3, m), np.float32).T
    d64 = np.empty((m if want64 else 0, 3))
    cuts = workers.bounds(n_cols, CHUNK_RAYS // max(n_beams * n_sub, 1))
    workers.run_chunks(lambda c: _world_rays_run(directions, rotation, translation, cuts[c], cuts[c + 1], want64,
                                                 o32, d32, d64), len(cuts) - 1)  # fmt: skip
    return o32, d32, d64


@numba.njit(cache=True, nogil=True)
def _world_rays_run(directions, rotation, translation, c0, c1, want64, o32, d32, d64):
    """Columns c0..c1 of :func:`_world_rays`."""
    n_beams, n_sub = directions.shape[1:3]
    k = c0 * n_beams * n_sub
    for c in range(c0, c1):
        r = rotation[c]
        tx, ty, tz = np.float32(translation[c, 0]), np.float32(translation[c, 1]), np.float32(translation[c, 2])
        for b in range(n_beams):
            for s in range(n_sub):
                x, y, z = directions[c, b, s, 0], directions[c, b, s, 1], directions[c, b, s, 2]
                wx = (r[0, 0] * x + r[0, 2] * z) + r[0, 1] * y
                wy = (r[1, 0] * x + r[1, 2] * z) + r[1, 1] * y
                wz = (r[2, 0] * x + r[2, 2] * z) + r[2, 1] * y
                o32[k, 0], o32[k, 1], o32[k, 2] = tx, ty, tz
                d32[k, 0], d32[k, 1], d32[k, 2] = wx, wy, wz
                if want64:
                    d64[k, 0], d64[k, 1], d64[k, 2] = wx, wy, wz
                k += 1


def _surface_returns(hits, static, directions, rotation, reflectivity, retro, material_label, actor_label, weights,
                     power, overlap_start, overlap_full, effects, scale, offset, two_way, compact,
                     scratch=None):  # fmt: skip
    """Range and peak amplitude (LIDAR equation) of every sub-ray's scene hit.

    ``hits``: the caster's distance, triangle, normal, material, actor and object id per
    sub-ray (:class:`~lidar_weather_sim.scene.raycast.scene_caster.Hits`); ``static``: the static
    mesh's normal, material and object id per triangle, which a static hit's are read from
    (the per-ray ones only for actor hits).

    ``compact``: the candidates with amplitude > 0 as (beam, range, amplitude, label,
    object id), beam-major (in ``scratch`` if given), each chunk's from its first ray's
    index on, and these runs as (starts, counts): the echo stage reads them where they
    are. Else range (inf for a miss) and amplitude (0 for a miss) of every sub-ray, flat
    (the other outputs empty; runs None). With ``effects`` the regions' reflectance
    scale, range offset and two-way transmission (N, S) apply.
    """
    n_cols, n_beams, n_sub = directions.shape[:3]
    m = n_cols * n_beams * n_sub
    size = m if compact else 0
    new = workers.allocator(scratch if compact else None)
    out = (new("cand_beam", size, np.int64), new("cand_range", m, np.float64), new("cand_amp", m, np.float64),
           new("cand_label", size, np.uint8), new("cand_obj", size, np.uint32))  # fmt: skip
    cuts = workers.bounds(n_cols, CHUNK_RAYS // max(n_beams * n_sub, 1))
    counts = workers.run_chunks(
        lambda c: _surface_returns_run(
            *hits, *static, directions, rotation, reflectivity, retro, material_label, actor_label, weights, power,
            overlap_start, overlap_full, effects, scale, offset, two_way, compact, cuts[c], cuts[c + 1], *out,
        ),
        len(cuts) - 1,
    )  # fmt: skip
    if not compact:
        return *out, None
    return *out, (cuts[:-1] * (n_beams * n_sub), np.array(counts, np.int64))


def _compact_candidates(candidates, segments):
    """The candidates of ``segments`` (starts, counts) moved together (in place): flat arrays."""
    count = _compact_run(tuple(candidates), *segments)
    return tuple(x[:count] for x in candidates)


@numba.njit(cache=True)
def _compact_run(out, starts, counts):
    beam, rng, amp, label, obj = out
    count = 0
    for c in range(len(counts)):
        src = starts[c]
        if src != count:
            for k in range(counts[c]):
                beam[count + k], rng[count + k], amp[count + k] = beam[src + k], rng[src + k], amp[src + k]
                label[count + k], obj[count + k] = label[src + k], obj[src + k]
        count += counts[c]
    return count


@numba.njit(cache=True, nogil=True)
def _surface_returns_run(distance, triangle, normal, material, actor, object_id, static_normal, static_material,
                         static_object_id, directions, rotation, reflectivity, retro, material_label, actor_label,
                         weights, power, overlap_start, overlap_full, effects, scale, offset, two_way, compact, c0, c1,
                         out_beam, out_rng, out_amp, out_label, out_obj):  # fmt: skip
    """Columns c0..c1 of :func:`_surface_returns`; compact candidates are written from the chunk's
    first ray index on. Returns how many."""
    n_beams, n_sub = directions.shape[1:3]
    no_material = len(reflectivity) - 1
    smooth = overlap_full > overlap_start
    width = overlap_full - overlap_start
    k = c0 * n_beams * n_sub
    count = k
    for c in range(c0, c1):
        r = rotation[c]
        for b in range(n_beams):
            beam = c * n_beams + b
            for s in range(n_sub):
                dist = np.float64(distance[k])
                if not np.isfinite(dist):
                    if not compact:
                        out_rng[k] = np.inf
                        out_amp[k] = 0.0
                    k += 1
                    continue
                t = triangle[k]
                if t >= 0:  # the static triangle's normal, unflipped: |cos| is the same
                    a = -1
                    n0, n1, n2 = static_normal[t, 0], static_normal[t, 1], static_normal[t, 2]
                    mat, obj = static_material[t], static_object_id[t]
                else:  # an actor's hit
                    a = actor[k]
                    n0, n1, n2, mat, obj = normal[k, 0], normal[k, 1], normal[k, 2], material[k], object_id[k]
                x, y, z = directions[c, b, s, 0], directions[c, b, s, 1], directions[c, b, s, 2]
                wx = (r[0, 0] * x + r[0, 2] * z) + r[0, 1] * y
                wy = (r[1, 0] * x + r[1, 2] * z) + r[1, 1] * y
                wz = (r[2, 0] * x + r[2, 2] * z) + r[2, 1] * y
                cos_inc = abs((np.float64(n0) * wx + np.float64(n2) * wz) + np.float64(n1) * wy)
                cos_inc = min(max(cos_inc, 0.0), 1.0)
                mat = mat if mat >= 0 else no_material
                refl = reflectivity[mat] * ((1.0 - retro[mat]) * cos_inc + retro[mat] * RETRO_GAIN)
                rng = dist
                if effects:
                    refl = refl * scale[beam, s]
                    rng = dist + offset[beam, s]
                rr = max(rng, MIN_RANGE_M)
                amp = power * weights[s] * refl / (rr * rr)
                if effects:
                    amp = amp * two_way[beam, s]
                if smooth:
                    u = min(max((rng - overlap_start) / width, 0.0), 1.0)
                    amp = amp * (u * u * (3.0 - 2.0 * u))
                else:
                    amp = amp * (1.0 if rng >= overlap_start else 0.0)
                if not compact:
                    out_rng[k] = rng
                    out_amp[k] = amp
                elif amp > 0:
                    out_beam[count] = beam
                    out_rng[count] = rng
                    out_amp[count] = amp
                    out_label[count] = actor_label[a] if a >= 0 else material_label[mat]
                    out_obj[count] = obj
                    count += 1
                k += 1
    return count - c0 * n_beams * n_sub


#: Below this many draws numpy's ``normal`` is faster (numba's unboxing of a new generator costs ~15 us).
NUMBA_NORMAL_MIN = 2048


def _range_noise(rng: np.random.Generator, sigma: float, n: int, scratch) -> np.ndarray:
    """``rng.normal(0, sigma, n)`` (m): the same values, drawn by numba's port of numpy's
    generator (3x faster) into ``scratch`` when there are many."""
    if n < NUMBA_NORMAL_MIN:
        return rng.normal(0.0, sigma, n)
    out = scratch.get("range_noise", n, np.float64)
    _normal(rng, sigma, out)
    return out


@numba.njit(cache=True)
def _normal(rng, sigma, out):
    for k in range(len(out)):
        out[k] = rng.normal(0.0, sigma)


@numba.njit(cache=True)
def _kept_echoes(noise, range_m, amplitude, starts, counts, min_range, dark, ranges, kept, ratio):
    """The echoes in the runs (starts, counts) in order: ``ranges`` (where the echoes are) gets
    each one's range plus its ``noise``; those at or beyond ``min_range`` get their index
    into ``kept`` and their peak amplitude (at least 1e-12) over ``dark`` into ``ratio``, as
    numpy's sum, flatnonzero, maximum and division. Returns how many were kept."""
    j = count = 0
    for c in range(len(counts)):
        for i in range(starts[c], starts[c] + counts[c]):
            ranges[i] = noise[j] + range_m[i]
            j += 1
            if ranges[i] >= min_range:
                a = amplitude[i]
                kept[count] = i
                ratio[count] = (a if not a < 1e-12 else 1e-12) / dark
                count += 1
    return count


@functools.cache
def _padding_bytes(dtype: np.dtype) -> np.ndarray:
    """Offsets of the bytes of a point that belong to no field (written as zeros)."""
    used = np.zeros(dtype.itemsize, bool)
    for base, offset in (dtype.fields[name][:2] for name in dtype.names):
        used[offset : offset + base.itemsize] = True
    return np.flatnonzero(~used)


def _fill_points(points, kept, *args):
    """Points of the echoes ``kept`` (ascending) in the sensor frame at their firing time; every
    byte of ``points`` is written (padding as zeros), so it may come from ``np.empty``."""
    raw = points.view(np.uint8).reshape(len(points), points.dtype.itemsize)
    *args, label, object_id, ground_truth, padding = args
    cuts = workers.bounds(len(kept), CHUNK_RAYS // 4)

    def run(c):
        _fill_points_run(points, raw, kept, cuts[c], cuts[c + 1], *args, padding)
        if ground_truth:  # a kernel of its own: numba types every branch, the other layout has no such fields
            _fill_ground_truth_run(points, kept, cuts[c], cuts[c + 1], label, object_id)

    workers.run_chunks(run, len(cuts) - 1)


@numba.njit(cache=True, nogil=True)
def _fill_ground_truth_run(points, kept, j0, j1, label, object_id):
    for j in range(j0, j1):
        p = points[j]
        p["label"] = label[kept[j]]
        p["object_id"] = object_id[kept[j]]


@numba.njit(cache=True, nogil=True)
def _fill_points_run(points, raw, kept, j0, j1, ranges, beam, echo, epw, log_ratio, span, columns, channels, n_beams,
                     cos_az, sin_az, azimuth, cos_el, sin_el, elevation, stamp, padding):  # fmt: skip
    """Points j0..j1 of :func:`_fill_points` (``raw``: the same memory as bytes, (N, itemsize))."""
    first = -n_beams  # first beam of the current column (none yet): divisions only where it changes
    col = 0
    for j in range(j0, j1):
        for b in padding:
            raw[j, b] = 0
        i = kept[j]
        bm = beam[i]
        if not first <= bm < first + n_beams:
            col = columns[bm // n_beams]
            first = bm // n_beams * n_beams
        ch = channels[bm - first]
        r = ranges[i]
        p = points[j]
        p["x"] = r * cos_el[ch] * cos_az[col, ch]
        p["y"] = r * cos_el[ch] * sin_az[col, ch]
        p["z"] = r * sin_el[ch]
        p["azimuth"] = azimuth[col, ch]
        p["elevation"] = elevation[ch]
        p["distance"] = r
        p["channel"] = ch
        p["time_stamp"] = stamp[col]
        p["echo"] = echo[i]
        p["epw"] = epw[i]
        p["intensity"] = np.uint8(min(max(np.rint(255.0 * (log_ratio[j] / span)), 0.0), 255.0))
        # Nebula return type: IDENTICAL when alone, else FIRST / SECOND / LAST (among the kept echoes)
        last = j + 1 == len(kept) or beam[kept[j + 1]] != bm
        if echo[i] == 1:
            p["return_type"] = RETURN_IDENTICAL if last else RETURN_FIRST
        else:
            p["return_type"] = RETURN_LAST if last else RETURN_SECOND
