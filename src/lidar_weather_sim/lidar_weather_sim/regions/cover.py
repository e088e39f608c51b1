"""Region plugin ``cover``: dirt, water and custom textures on the sensor cover (thesis paper 1).

Per sub-ray (sensor frame direction -> u, v over the field of view):

- one-way ``transmission`` from the texture (the echo stage squares it: two-way
  loss ~ T^2, thesis line 1333), so dirt shortens range where it sits; ``texture_contrast``
  scales the texture's patches around its mean (0: a uniform film);
- forward scattering (samples 3, 5): a share of the beam energy leaves the core
  sub-ray(s) and is spread over the outer ones (a wider beam, same total energy). It acts once,
  on the way out: the return crosses the cover at its transmission alone (the receiver takes what
  the cover passes over its aperture, as the integrating sphere of the measurement did), so the
  one-way transmission carries the square root of each sub-ray's factor and an extended target
  behind a uniform dirt returns T^2 (thesis line 1333), whatever the share;
- Monte-Carlo range noise (Table II): extra Gaussian sigma
  ``sigma0 sqrt((1 + increase)^2 - 1)`` on scene hits, sigma0 = the profile's noise;
- near-field cover returns (0-0.5 m, exponential, bypassing the biaxial overlap)
  at a rate that grows with dirt or water (:mod:`lidar_weather_sim.regions.near_field`; times
  ``texture_return_gain``: a unit may blank them, which no datum of the thesis sizes), plus the
  sensor's own near-field ghosts at ``near_field_ghost_per_beam``: the same returns from the clean
  window and housing (multiple reflection inside the sensor, thesis lines 329 and 498), the effect
  ``sensor.near_field_ghost`` of the gap search. Only those beyond the profile's minimum range
  (``range.min_m``) are reported.

Textures can change over time: ``target_texture`` is blended in linearly from
``blend_start_s`` over ``blend_duration_s`` (simulated s), e.g. dirt building up.
The texture realisation is seeded by ``texture_seed`` (fixed over a run); the
per-frame randomness comes from the generator passed to :meth:`apply`.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
from pydantic import Field

from lidar_weather_sim.core.config import ConfigError, ConfigModel
from lidar_weather_sim.core.points import Label
from lidar_weather_sim.regions.base import RayBatch, RegionContext, RegionEffect
from lidar_weather_sim.regions.cover_textures import CoverTexture, make_texture, with_contrast, with_mean
from lidar_weather_sim.regions.near_field import NearFieldModel, sample_near_field
from lidar_weather_sim.sensor.scan import ScanPattern


class CoverParams(ConfigModel):
    texture: str = Field("clean", description="clean, a config/cover/samples.yaml entry (1u..6l, water_film), "
                                                "dirt:<mean transmission> or image:<path>")
    mean_transmission: float | None = Field(None, ge=0, le=1, description="Rescale the texture's opacity to this mean "
                                                                          "transmission (0-1); none = as drawn")
    target_texture: str | None = Field(None, description="Texture blended in over time (same names), none = static")
    blend_start_s: float = Field(0.0, ge=0, description="Simulated time the blend starts (s)")
    blend_duration_s: float = Field(0.0, ge=0, description="Duration of the blend (s); 0 = switch at blend_start_s")
    texture_seed: int = Field(0, ge=0, le=2**32 - 1, description="Seed of the texture realisation (hierarchical random field)")
    texture_return_gain: float = Field(1.0, ge=0, le=1, description="Share (0-1) of the cover returns the texture's "
                                       "dirt or water makes (multipath at 0-0.5 m) that the unit reports: 1 the thesis "
                                       "samples' rate, 0 a unit that blanks them (its transmission loss untouched)")
    forward_share: float | None = Field(None, ge=0, le=1, description="Share (0-1) of the beam energy the texture "
                                        "scatters forward into a wider cone, overriding the texture's (the thesis "
                                        "samples': 0.26-0.35 for the heavy ones, 0 for the rest; a generic dirt's "
                                        "interpolated by opacity); 0 = a dirt that only absorbs; none = the texture's")
    texture_contrast: float = Field(1.0, ge=0, le=1, description="Scale (0-1) of the texture's spread of "
                                    "transmission around its mean over the window: 1 the texture's patches as drawn, "
                                    "0 a uniform film of the same mean transmission")
    near_field_scale_m: float = Field(0.1, gt=0, description="Exponential range scale of cover returns (m)")
    near_field_amplitude: float = Field(3.0, gt=0, description="Median cover-return peak over the dark threshold")
    near_field_sigma_ln: float = Field(0.8, ge=0, description="Log-sd of the cover-return peak amplitude")
    near_field_ghost_channel_weights: list[float] | None = Field(
        None, description="Relative ghost rate of each channel (channel 0 = lowest elevation; the rate per beam is "
        "near_field_ghost_per_beam times its channel's weight): a window whose reflections reach some layers' "
        "receivers more; none = 1 for every channel")
    near_field_ghost_per_beam: float = Field(0.0, ge=0, le=10, description="Mean near-field ghosts per beam and "
                                             "frame: cover returns of the clean window and housing, added to the "
                                             "texture's")  # fmt: skip


class CoverRegion:
    name = "cover"
    Params = CoverParams

    def __init__(self, params: CoverParams, context: RegionContext) -> None:
        self.p = params
        self.profile = context.profile
        rng = np.random.default_rng(params.texture_seed)
        sigma0 = self.profile.range.noise_sigma_m
        self.textures: list[CoverTexture] = [make_texture(params.texture, rng, sigma0)]
        if params.target_texture:
            self.textures.append(make_texture(params.target_texture, rng, sigma0))
        if params.mean_transmission is not None:
            self.textures = [with_mean(t, params.mean_transmission) for t in self.textures]
        if params.forward_share is not None:
            self.textures = [replace(t, forward_share=params.forward_share) for t in self.textures]
        if params.texture_contrast != 1.0:
            self.textures = [with_contrast(t, params.texture_contrast) for t in self.textures]
        beams = [b.elevation_deg for b in self.profile.beams]
        half = 0.5 * np.rad2deg(self.profile.optics.divergence_v_mrad * 1e-3)
        self._el = np.deg2rad([min(beams) - half, max(beams) + half])
        scan = self.profile.scan
        self._az = np.deg2rad([scan.azimuth_min_deg, scan.azimuth_max_deg])
        self._tables: list[np.ndarray] | None = None  # see _pattern_samples
        weights = params.near_field_ghost_channel_weights
        if weights is not None and (len(weights) != len(self.profile.beams) or min(weights) < 0):
            raise ConfigError(f"cover near_field_ghost_channel_weights {weights}: need {len(self.profile.beams)} "
                              f"weights >= 0, one per channel of profile '{self.profile.name}'")  # fmt: skip
        self._ghost_weights = None if weights is None else np.asarray(weights, dtype=np.float64)

    def step(self, t0_s: float, t1_s: float) -> None:
        """Stateless in time: the blend weight is a function of each beam's firing time."""

    def blend_weight(self, time_s: np.ndarray) -> np.ndarray:
        p = self.p
        if len(self.textures) == 1:
            return np.zeros_like(time_s, dtype=np.float64)
        if p.blend_duration_s <= 0:
            return (time_s >= p.blend_start_s).astype(np.float64)
        return np.clip((time_s - p.blend_start_s) / p.blend_duration_s, 0.0, 1.0)

    def uv(self, sensor_directions: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Texture coordinates (0-1) of sensor-frame unit directions: u across azimuth, v across elevation."""
        d = sensor_directions
        az = np.arctan2(d[..., 1], d[..., 0])
        el = np.arcsin(np.clip(d[..., 2], -1.0, 1.0))
        span = self._el[1] - self._el[0]
        v = (el - self._el[0]) / span if span > 1e-9 else np.full_like(el, 0.5)  # one flat beam: mid-texture
        return (az - self._az[0]) / (self._az[1] - self._az[0]), v

    def texture_samples(self, batch: RayBatch) -> list[np.ndarray]:
        """Each texture's transmission (N, S) on the batch's sub-rays; from the scan pattern's table
        (:meth:`_pattern_samples`, the same values) when the batch says its columns."""
        if batch.column is None:
            u, v = self.uv(batch.sensor_directions)
            return [t.sample(u, v) for t in self.textures]
        tables = self._pattern_samples()
        rows = batch.column * tables[0].shape[1] + batch.channel  # (np.take of rows: ~3x faster than [col, ch])
        return [np.take(table.reshape(-1, table.shape[-1]), rows, axis=0) for table in tables]

    def _pattern_samples(self) -> list[np.ndarray]:
        """Each texture sampled at every sub-ray direction of the profile's scan pattern, (columns,
        channels, sub-rays), built on first use: the cover is fixed to the sensor, so a direction always
        meets the same spot."""
        if self._tables is None:
            pattern = ScanPattern(self.profile)
            tables = [np.zeros((pattern.n_columns, pattern.n_channels, pattern.n_subrays)) for _ in self.textures]
            for layer in range(len(self.profile.scan.layer_schedule or [None])):
                channels = pattern.active_channels(layer)
                u, v = self.uv(pattern.direction_table(layer))
                for table, texture in zip(tables, self.textures):
                    table[:, channels] = texture.sample(u, v)
            self._tables = tables
        return self._tables

    def beam_two_way(self) -> np.ndarray:
        """(columns, channels) two-way transmission through the cover of what a weather spread along each beam of
        the scan pattern returns, with the first texture (before any blend): the mean over the beam's sub-rays
        (weighted by their share of its energy) of T^2 times the forward-scatter factor, as :meth:`apply` gives
        them and the simulator's volume returns read them (a weather fills every sub-ray of the beam: the light
        scattered forward off the core lights the weather on the outer ones)."""
        weights = np.asarray(ScanPattern(self.profile).subray_weight, dtype=np.float64)
        factors = _forward_scatter_factors(weights, self.textures[0].forward_share)
        return (self._pattern_samples()[0] ** 2 * factors * weights).sum(axis=-1) / weights.sum()

    def apply(self, batch: RayBatch, rng: np.random.Generator) -> RegionEffect:
        n, s = batch.shape
        w = self.blend_weight(np.asarray(batch.time_s, dtype=np.float64))[:, None]
        tex = self.textures
        samples = self.texture_samples(batch)
        t = samples[0] if len(tex) == 1 else (1 - w) * samples[0] + w * samples[1]
        wm = float(w.mean())
        mix = lambda attr: getattr(tex[0], attr) * (1 - wm) + (getattr(tex[1], attr) * wm if len(tex) > 1 else 0.0)  # noqa: E731
        factors = _forward_scatter_factors(np.asarray(batch.weights, dtype=np.float64), mix("forward_share"))
        t = t * np.sqrt(factors)[None, :]  # the echo stage squares it: the factor once, on the way out
        extra = mix("extra_range_sigma_m")
        offset = rng.normal(0.0, extra, (n, s)) if extra > 0 else None
        texture_rate, ghosts = mix("near_field_per_beam") * self.p.texture_return_gain, self.p.near_field_ghost_per_beam
        rate = texture_rate + ghosts
        scatterers = None
        if rate > 0:
            model = NearFieldModel(rate, 1.0, self.p.near_field_scale_m, self.p.near_field_amplitude,
                                   self.p.near_field_sigma_ln)  # fmt: skip
            scale = 1.0 if self._ghost_weights is None else \
                (texture_rate + ghosts * self._ghost_weights[batch.channel]) / rate  # fmt: skip
            scatterers = sample_near_field(model, n, batch.weights, self.profile, rng, Label.COVER, Label.COVER, scale)
        return RegionEffect(transmission=t, scatterers=scatterers, range_offset_m=offset)


def _forward_scatter_factors(weights: np.ndarray, share: float) -> np.ndarray:
    """Per-sub-ray factors moving ``share`` of the core sub-rays' energy onto the others (sum w f = sum w)."""
    if share <= 0 or len(weights) < 2:
        return np.ones(len(weights))
    core = weights >= weights.max() - 1e-12
    if core.all():
        return np.ones(len(weights))
    moved = share * weights[core].sum()
    return np.where(core, 1.0 - share, 1.0 + moved / weights[~core].sum())
