"""Region plugin ``faults``: sensor faults to test a perception stack against.

Faults act on the light that leaves and reaches the sensor, as the one-way ``transmission`` of the
region protocol (the echo stage squares it), so a faulted beam returns nothing from the scene or from
any other region's scatterers. The profile's noise-floor false alarms (``false_alarms_per_beam``, 0
in every shipped profile) are not faulted. Angles are in the sensor frame (REP-103: azimuth 0 along
x, counter-clockwise positive, degrees); frames count from 0 in the run.

- ``dead_channels``: channels (rows of the scan pattern) that output nothing;
- ``channel_gains``: weak channels, channel -> gain (0-1) of its receiver: every return on the channel
  (scene and scatterers) is that much weaker (one-way transmission sqrt(gain)), so the faint ones fall
  below the threshold;
- ``blocked_sectors_deg``: azimuth sectors ``[from, to]`` (a sector with from > to wraps through
  +-180) whose sub-rays keep ``blocked_transmission`` of their light (0: nothing; e.g. a sticker or
  a mount bracket in front of the cover);
- ``dropout_probability``: a random output mask: each beam of each frame is lost with this
  probability (seeded per frame and batch, as every region's randomness);
- ``mask_period_frames`` / ``mask_frames``: a periodic output mask: the first ``mask_frames`` of every
  ``mask_period_frames`` frames are empty (a driver that drops whole packets of scans).

References for such corruptions: Robo3D (Kong et al., ICCV 2023: beam missing, crosstalk, incomplete
echo, ...) and AWSIM's LiDAR masks; these four are the ones a ray transmission expresses exactly.
"""

from __future__ import annotations

import numpy as np
from pydantic import Field, model_validator

from lidar_weather_sim.core.config import ConfigError, ConfigModel
from lidar_weather_sim.regions.base import RayBatch, RegionContext, RegionEffect


class FaultParams(ConfigModel):
    dead_channels: list[int] = Field(default_factory=list, description="Channels (scan-pattern rows, from 0) with no output")
    channel_gains: dict[int, float] = Field(default_factory=dict, description="Weak channels: channel -> receiver gain "
                                            "(0-1; every return on it that much weaker)")  # fmt: skip
    blocked_sectors_deg: list[tuple[float, float]] = Field(
        default_factory=list, description="Sensor-frame azimuth sectors [from, to] (deg, -180..180; from > to wraps "
                                          "through 180) whose light is blocked")  # fmt: skip
    blocked_transmission: float = Field(0.0, ge=0, le=1, description="One-way transmission left in a blocked sector")
    dropout_probability: float = Field(0.0, ge=0, le=1, description="Random output mask: each beam of each frame is "
                                                                     "lost with this probability")  # fmt: skip
    mask_period_frames: int = Field(0, ge=0, description="Periodic output mask: every this many frames (0: off) ...")
    mask_frames: int = Field(1, ge=1, description="... the first this many frames are empty")

    @model_validator(mode="after")
    def _check(self) -> "FaultParams":
        for k, (lo, hi) in enumerate(self.blocked_sectors_deg):
            if not (-180.0 <= lo <= 180.0 and -180.0 <= hi <= 180.0):
                raise ValueError(f"blocked_sectors_deg.{k}: [{lo}, {hi}] outside -180..180 deg")
        if any(c < 0 for c in self.dead_channels):
            raise ValueError(f"dead_channels: {self.dead_channels} has a negative channel")
        bad = {c: g for c, g in self.channel_gains.items() if c < 0 or not 0.0 <= g <= 1.0}
        if bad:
            raise ValueError(f"channel_gains: {bad}: channels from 0, gains 0-1")
        if self.mask_period_frames and self.mask_frames >= self.mask_period_frames:
            raise ValueError(f"mask_frames {self.mask_frames} must be below mask_period_frames "
                             f"{self.mask_period_frames} (else every frame is empty)")  # fmt: skip
        return self


class FaultRegion:
    name = "faults"
    Params = FaultParams

    def __init__(self, params: FaultParams, context: RegionContext) -> None:
        self.p = params
        n_channels = len(context.profile.beams)
        for key, channels in (("dead_channels", params.dead_channels), ("channel_gains", list(params.channel_gains))):
            if any(c >= n_channels for c in channels):
                raise ConfigError(f"region 'faults': {key} {channels}: the profile has channels 0..{n_channels - 1}")
        self._one_way = np.ones(n_channels)  # per channel: sqrt of its receiver gain
        for channel, gain in params.channel_gains.items():
            self._one_way[channel] = np.sqrt(gain)

    def step(self, t0_s: float, t1_s: float) -> None:
        """Faults do not evolve in time (the periodic mask counts frames)."""

    def apply(self, batch: RayBatch, rng: np.random.Generator) -> RegionEffect:
        n, s = batch.shape
        p = self.p
        transmission = np.ones((n, s))
        if p.mask_period_frames and batch.frame_index % p.mask_period_frames < p.mask_frames:
            return RegionEffect(transmission=np.zeros((n, s)))
        if p.dead_channels:
            transmission[np.isin(batch.channel, p.dead_channels)] = 0.0
        if p.blocked_sectors_deg:
            d = batch.sensor_directions
            azimuth = np.degrees(np.arctan2(d[..., 1], d[..., 0]))
            blocked = np.zeros((n, s), bool)
            for lo, hi in p.blocked_sectors_deg:
                blocked |= ((azimuth >= lo) & (azimuth <= hi)) if lo <= hi else ((azimuth >= lo) | (azimuth <= hi))
            transmission[blocked] = np.minimum(transmission[blocked], p.blocked_transmission)
        if p.dropout_probability > 0:
            transmission[rng.random(n) < p.dropout_probability] = 0.0
        if p.channel_gains:
            transmission *= self._one_way[batch.channel][:, None]
        return RegionEffect(transmission=transmission)
