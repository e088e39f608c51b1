"""The virtual LiDAR: incremental casting of the scan, regions, echo decision, frames.

Data path per batch of columns (the columns swept since the last pose update):
scan pattern -> sensor pose per column (rolling shutter) -> backend cast ->
regions -> candidate returns with LIDAR-equation amplitudes -> echo decision
(:mod:`lidar_weather_sim.echo`) -> points in the sensor frame at their own
firing time. A frame is returned when its sweep is complete; its stamp is the
scan start and every point's ``time_stamp`` is its column's firing time after
that (ns).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Protocol

import numpy as np

from lidar_weather_sim.echo import (
    Threshold,
    detect_echoes,
    overlap_factor,
    peak_amplitude,
    surface_reflectance,
)
from lidar_weather_sim.points import Label, empty_points
from lidar_weather_sim.regions import RayBatch, Region, combine, region_rng
from lidar_weather_sim.scan import ScanPattern
from lidar_weather_sim.sensor_profile import SensorProfile

#: Nebula return types (nebula_common ReturnType).
RETURN_LAST, RETURN_FIRST, RETURN_IDENTICAL, RETURN_SECOND = 1, 2, 6, 7


class PoseSource(Protocol):
    def sensor_poses(self, times_s: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """World (fixed-frame) pose of the sensor at each time: translations (N, 3) m, quaternions (N, 4) xyzw."""

    def actor_poses(self, time_s: float) -> dict[int, np.ndarray]:
        """Body-to-world 4x4 transform of every actor present at ``time_s``."""


@dataclass
class Frame:
    index: int
    stamp_s: float  # scan start, simulated time (s)
    points: np.ndarray
    rays: int


def quaternion_matrices(q: np.ndarray) -> np.ndarray:
    """Rotation matrices (N, 3, 3) of unit quaternions (N, 4) in x, y, z, w order."""
    x, y, z, w = q[:, 0], q[:, 1], q[:, 2], q[:, 3]
    return np.stack(
        [
            np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)], -1),
            np.stack([2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)], -1),
            np.stack([2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)], -1),
        ],
        -2,
    )


@dataclass
class _FrameAccumulator:
    index: int
    start_s: float
    next_column: int = 0
    parts: list[np.ndarray] = field(default_factory=list)
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
        from lidar_weather_sim.raycast.scene_caster import SceneCaster

        self.profile = profile
        self.pattern = ScanPattern(profile)
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
        frames = []
        while True:
            acc = self._frame
            last = int(np.searchsorted(self.pattern.column_time_s, time_s - acc.start_s, side="right"))
            if last > acc.next_column:
                self._cast(acc, np.arange(acc.next_column, last), poses)
                acc.next_column = last
            if acc.next_column < self.pattern.n_columns:
                return frames
            frames.append(self._finish(acc))
            self._frame = _FrameAccumulator(acc.index + 1, acc.start_s + period)

    def _finish(self, acc: _FrameAccumulator) -> Frame:
        points = np.concatenate(acc.parts) if acc.parts else empty_points(0, self.ground_truth)
        return Frame(acc.index, acc.start_s, points, acc.rays)

    # -- one batch -------------------------------------------------------------------
    def _cast(self, acc: _FrameAccumulator, columns: np.ndarray, poses: PoseSource) -> None:
        profile, pattern = self.profile, self.pattern
        batch = pattern.batch(acc.index, columns)
        n_cols, n_beams, n_sub = batch.directions.shape[:3]
        times = acc.start_s + batch.time_s
        translation, quaternion = poses.sensor_poses(times)
        rotation = quaternion_matrices(np.asarray(quaternion, dtype=np.float64))
        world_dirs = np.einsum("cij,cbsj->cbsi", rotation, batch.directions)
        origins = np.repeat(np.asarray(translation, dtype=np.float64), n_beams, axis=0)  # (N, 3)
        n = n_cols * n_beams
        actor_poses = poses.actor_poses(float(times.mean()))
        hits = self.caster.cast(
            np.repeat(origins, n_sub, axis=0).astype(np.float32),
            world_dirs.reshape(-1, 3).astype(np.float32),
            actor_poses,
            profile.range.max_m,
        )
        shape = (n, n_sub)
        distance = hits.distance.reshape(shape).astype(np.float64)
        material = hits.material.reshape(shape)
        label = self._material_label[material]
        actor = hits.hit_actor.reshape(shape)
        if (actor >= 0).any():
            label = np.where(actor >= 0, self._actor_label[np.maximum(actor, 0)], label)
        ray_batch = RayBatch(
            frame_index=acc.index,
            origins=origins,
            directions=world_dirs.reshape(n, n_sub, 3),
            sensor_directions=batch.directions.reshape(n, n_sub, 3),
            channel=np.tile(batch.channels, n_cols),
            time_s=np.repeat(times, n_beams),
            weights=batch.weights,
            distance=distance,
            normal=hits.normal.reshape(n, n_sub, 3),
            material=material,
            object_id=hits.object_id.reshape(shape),
            label=label,
        )
        effects = [
            region.apply(ray_batch, region_rng(self.seed, acc.index, name, int(columns[0])))
            for name, region in self.regions
        ]
        effect = combine(effects, shape)
        candidates = self._candidates(ray_batch, effect)
        candidates = self._add_false_alarms(candidates, n, acc.index, int(columns[0]))
        threshold = self.threshold()
        echoes = detect_echoes(
            *candidates,
            threshold=threshold,
            fwhm_m=profile.pulse.fwhm_m,
            resolution_m=profile.range.resolution_m,
            max_echoes=profile.detection.max_echoes,
        )
        acc.parts.append(self._points(echoes, batch, columns, acc, int(columns[0])))
        acc.rays += n * n_sub

    def _candidates(self, rays: RayBatch, effect) -> tuple[np.ndarray, ...]:
        """Candidate returns (beam, range, amplitude, label, object id) of scene hits and scatterers."""
        profile = self.profile
        n, n_sub = rays.shape
        C = profile.detection.power_constant
        optics = profile.optics
        hit = np.isfinite(rays.distance)
        mat = np.where(rays.material >= 0, rays.material, -1)
        cos_inc = np.abs(np.einsum("nsk,nsk->ns", rays.normal, rays.directions))
        refl = surface_reflectance(self._reflectivity[mat], self._retro[mat], cos_inc) * effect.reflectance_scale
        rng_m = np.where(hit, rays.distance + effect.range_offset_m, np.inf)
        one_way = effect.transmission
        alpha = effect.extinction_per_m
        amp = peak_amplitude(
            C, rays.weights[None, :], refl, rng_m, one_way**2 * np.exp(-2.0 * alpha * np.where(hit, rng_m, 0.0)),
            overlap_factor(rng_m, optics.overlap_start_m, optics.overlap_full_m),
        )
        amp = np.where(hit, amp, 0.0)
        beam = np.broadcast_to(np.arange(n)[:, None], shape=(n, n_sub))
        subray = np.broadcast_to(np.arange(n_sub)[None, :], shape=(n, n_sub))
        cols = [beam.ravel(), subray.ravel(), rng_m.ravel(), amp.ravel(), rays.label.ravel(), rays.object_id.ravel(),
                np.ones(n * n_sub)]  # fmt: skip
        sc = effect.scatterers
        if sc is not None:
            b, s = sc.beam, sc.subray
            t2 = one_way[b, s] ** 2 * np.exp(-2.0 * alpha[b, s] * sc.range_m)
            sc_amp = peak_amplitude(C, rays.weights[s], sc.reflectance, sc.range_m, t2,
                                    overlap_factor(sc.range_m, optics.overlap_start_m, optics.overlap_full_m))  # fmt: skip
            extra = [b, s, sc.range_m, sc_amp, sc.label, sc.object_id, sc.occlusion]
            cols = [np.concatenate([a, e]) for a, e in zip(cols, extra)]
            cols[3] = _occlude(cols[0] * n_sub + cols[1], cols[2], cols[3], cols[6])
        beam, _, rng_m, amp, label, obj, _ = cols
        keep = amp > 0
        return beam[keep], rng_m[keep], amp[keep], label[keep].astype(np.uint8), obj[keep].astype(np.uint32)

    def _add_false_alarms(self, candidates, n_beams: int, frame: int, first_column: int):
        rate = self.profile.detection.false_alarms_per_beam
        if rate <= 0:
            return candidates
        rng = region_rng(self.seed, frame, "noise_floor", first_column)
        count = rng.poisson(rate, n_beams)
        beam = np.repeat(np.arange(n_beams), count)
        lo = max(self.profile.optics.overlap_start_m, self.profile.range.min_m)
        ranges = rng.uniform(lo, self.profile.range.max_m, len(beam))
        amp = self.threshold().level * (1.0 + rng.exponential(0.2, len(beam)))
        extra = (beam, ranges, amp, np.full(len(beam), Label.NOISE, np.uint8), np.zeros(len(beam), np.uint32))
        return tuple(np.concatenate([a, e]) for a, e in zip(candidates, extra))

    def _points(self, echoes, batch, columns, acc: _FrameAccumulator, first_column: int) -> np.ndarray:
        profile, pattern = self.profile, self.pattern
        n_beams = len(batch.channels)
        rng = region_rng(self.seed, acc.index, "range_noise", first_column)
        ranges = echoes.range_m + rng.normal(0.0, profile.range.noise_sigma_m, len(echoes.range_m))
        keep = ranges >= max(profile.range.min_m, 0.0)
        beam = echoes.beam[keep]
        col = columns[beam // n_beams]
        channel = batch.channels[beam % n_beams]
        az = pattern.column_azimuth[col] + pattern.azimuth_offset[channel]
        el = pattern.elevation[channel]
        r = ranges[keep]
        points = empty_points(len(r), self.ground_truth)
        cos_el = np.cos(el)
        points["x"] = r * cos_el * np.cos(az)
        points["y"] = r * cos_el * np.sin(az)
        points["z"] = r * np.sin(el)
        points["azimuth"] = np.arctan2(np.sin(az), np.cos(az))
        points["elevation"] = el
        points["distance"] = r
        points["channel"] = channel
        points["time_stamp"] = np.round(pattern.column_time_s[col] * 1e9).astype(np.uint32)
        points["echo"] = echoes.echo[keep]
        points["epw"] = echoes.epw_m[keep]
        points["intensity"] = self._intensity(echoes.amplitude[keep])
        points["return_type"] = _return_types(beam, echoes.echo[keep])
        if self.ground_truth:
            points["label"] = echoes.label[keep]
            points["object_id"] = echoes.object_id[keep]
        return points

    def _intensity(self, amplitude: np.ndarray) -> np.ndarray:
        """0-255, logarithmic in the peak amplitude above the dark threshold (0 = at threshold,
        255 = ``intensity_dynamic_range`` times above it)."""
        span = np.log(self.profile.detection.intensity_dynamic_range)
        level = np.log(np.maximum(amplitude, 1e-12) / self.dark_threshold()) / span
        return np.clip(np.round(255.0 * level), 0, 255).astype(np.uint8)


def _return_types(beam: np.ndarray, echo: np.ndarray) -> np.ndarray:
    """Nebula return type per echo: IDENTICAL when alone, else FIRST / SECOND / LAST."""
    if not len(beam):
        return np.zeros(0, np.uint8)
    last = np.ones(len(beam), bool)
    last[:-1] = beam[1:] != beam[:-1]
    first = echo == 1
    out = np.where(first, RETURN_FIRST, np.where(last, RETURN_LAST, RETURN_SECOND))
    return np.where(first & last, RETURN_IDENTICAL, out).astype(np.uint8)


def _occlude(key: np.ndarray, range_m: np.ndarray, amplitude: np.ndarray, occlusion: np.ndarray) -> np.ndarray:
    """Scale each candidate by the two-way light left after the candidates in front of it on the
    same sub-ray (``key``): prod over nearer ones of (1 - occlusion)^2."""
    order = np.lexsort((range_m, key))
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
