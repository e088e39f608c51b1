"""Sensor profiles: beam geometry, scan timing, optics, pulse and detection parameters.

A profile is a YAML file in ``config/sensors/`` validated by :class:`SensorProfile`.
Angles follow REP-103 in the sensor frame: azimuth = atan2(y, x) (positive to
the left), elevation positive upwards. Channels are numbered by elevation,
0 = lowest beam.
"""

from __future__ import annotations

from functools import cached_property
from pathlib import Path
from typing import Literal

import numpy as np
from pydantic import Field, model_validator

from lidar_weather_sim.core.config import ConfigError, ConfigModel, load_named
from lidar_weather_sim.core.names import RETURN_MODES

#: A return mode's name (:data:`~lidar_weather_sim.core.names.RETURN_MODES`).
ReturnMode = Literal[RETURN_MODES]


class Beam(ConfigModel):
    elevation_deg: float = Field(ge=-90, le=90, description="Beam elevation (deg, up positive)")
    azimuth_offset_deg: float = Field(0.0, ge=-180, le=180, description="Horizontal offset from the column azimuth (deg)")


class Scan(ConfigModel):
    frame_rate_hz: float = Field(gt=0, le=200, description="Frames per second (Hz)")
    azimuth_min_deg: float = Field(-180.0, ge=-180, le=180, description="Right edge of the horizontal FOV (deg)")
    azimuth_max_deg: float = Field(180.0, ge=-180, le=180, description="Left edge of the horizontal FOV (deg)")
    columns: int = Field(gt=0, le=16384, description="Firing columns per frame")
    direction: Literal["cw", "ccw"] = Field("cw", description="Sweep direction seen from above (cw: left to right)")
    sweep_fraction: float = Field(
        1.0, gt=0, le=1, description="Share of the frame period spent sweeping the FOV (1 for spinning heads)"
    )
    layer_schedule: list[list[int]] | None = Field(
        None, description="Channels active in frame k are layer_schedule[k % len]; all channels when absent"
    )

    @model_validator(mode="after")
    def _fov(self) -> "Scan":
        if self.azimuth_max_deg <= self.azimuth_min_deg:
            raise ValueError(f"azimuth_max_deg {self.azimuth_max_deg} must exceed azimuth_min_deg {self.azimuth_min_deg}")
        return self


class RangeSpec(ConfigModel):
    min_m: float = Field(0.0, ge=0, description="Closest reported range (m)")
    max_m: float = Field(gt=0, description="Farthest range cast (m)")
    resolution_m: float = Field(gt=0, description="Returns closer than this merge into one echo (m)")
    noise_sigma_m: float = Field(0.0, ge=0, description="Gaussian range noise, one sigma (m)")


class Optics(ConfigModel):
    divergence_h_mrad: float = Field(ge=0, description="Full horizontal beam divergence (1/e^2, mrad)")
    divergence_v_mrad: float = Field(ge=0, description="Full vertical beam divergence (1/e^2, mrad)")
    subrays_h: int = Field(1, ge=1, le=16, description="Sub-rays across the horizontal divergence")
    subrays_v: int = Field(1, ge=1, le=16, description="Sub-rays across the vertical divergence")
    overlap_start_m: float = Field(0.0, ge=0, description="Biaxial optics: sender/receiver FOVs start to overlap (m)")
    overlap_full_m: float = Field(0.0, ge=0, description="Biaxial optics: full overlap from here on (m)")
    # Physical optics, read by the atmosphere reference (lidar_weather_sim.references.droplets) and
    # lidar_weather_sim.physics; optional: profiles without them have no wavelength-resolved atmosphere.
    wavelength_nm: float | None = Field(None, gt=300, lt=2000, description="Laser wavelength (nm)")
    lens_separation_m: float | None = Field(
        None, ge=0, description="Biaxial optics: distance between the sender's and the receiver's optical axes (m)"
    )
    receiver_fov_mrad: float | None = Field(None, gt=0, description="Full field of view of one receiver channel (mrad)")
    tx_aperture_radius_m: float = Field(0.0, ge=0, description="Radius of the beam at the sender's exit (m)")
    rx_aperture_radius_m: float = Field(0.0, ge=0, description="Radius of the receiver's aperture (m)")
    overlap_model: Literal["cone", "defocus"] = Field(
        "cone", description="Biaxial overlap of the physical atmosphere: the receiver's view as a cone from its whole "
        "aperture (cone) or the aperture's blur on its field stop (defocus), lidar_weather_sim.physics.overlap"
    )

    @property
    def subrays(self) -> int:
        return self.subrays_h * self.subrays_v


class Pulse(ConfigModel):
    fwhm_m: float = Field(gt=0, description="Full width at half maximum of the Gaussian echo pulse, in range (m)")


class Detection(ConfigModel):
    max_echoes: int = Field(1, ge=1, le=8, description="Echoes detected per beam (the nearest ones)")
    return_mode: ReturnMode = Field(
        "all", description="What each beam reports of its detected echoes: strongest (highest peak), last (farthest), "
        "first (nearest), dual (last and strongest, Velodyne's dual return) or all (every echo)"
    )
    power_constant: float = Field(
        gt=0, description="C of P = C * w * rho * cos(theta) / R^2 * T^2: peak amplitude of a full-beam hit (noise units m^2)"
    )
    noise_mean: float = Field(0.0, ge=0, description="Mean noise level without background light (noise units)")
    noise_sigma: float = Field(1.0, gt=0, description="Noise standard deviation without background light (noise units)")
    threshold_sigma: float = Field(3.0, gt=0, description="x of the detection threshold mu + x sigma (thesis eq. 4)")
    sun_noise_per_w_m2: float = Field(
        0.0, ge=0, description="Rise of the noise mean per W/m^2 of solar irradiance (noise units per W/m^2)"
    )
    sun_sigma_per_w_m2: float = Field(
        0.0, ge=0, description="Rise of the noise sigma per W/m^2 of solar irradiance (shot noise; noise units per W/m^2)"
    )
    false_alarms_per_beam: float = Field(
        0.0, ge=0, description="Mean noise detections per beam and frame at the threshold (label NOISE)"
    )
    intensity_dynamic_range: float = Field(
        1.0e4, gt=1, description="Peak amplitude ratio above the dark threshold mapped onto intensity 0-255 (log scale)"
    )
    ac_coupling_tau_m: float = Field(
        0.0, ge=0, description="Time constant of the receiver's AC coupling (first-order high-pass) in range units (m), "
        "applied to the atmosphere's volume return (physical model and reference); 0: DC-coupled"
    )


class SensorProfile(ConfigModel):
    name: str
    description: str = ""
    source: str = Field("", description="Where the values come from (data sheet, calibration file, thesis table)")
    beams: list[Beam] = Field(min_length=1)
    scan: Scan
    range: RangeSpec
    optics: Optics
    pulse: Pulse
    detection: Detection

    @model_validator(mode="after")
    def _schedule(self) -> "SensorProfile":
        for group in self.scan.layer_schedule or []:
            bad = [c for c in group if not 0 <= c < len(self.beams)]
            if bad:
                raise ValueError(f"scan.layer_schedule names channels {bad}, profile has {len(self.beams)} beams")
        return self

    @cached_property
    def channel_order(self) -> np.ndarray:
        """Index into ``beams`` of each channel (channel 0 = lowest elevation)."""
        return np.argsort([b.elevation_deg for b in self.beams], kind="stable")

    @property
    def period_s(self) -> float:
        return 1.0 / self.scan.frame_rate_hz

    def with_elevation_offsets(self, offsets_deg: dict[int, float]) -> "SensorProfile":
        """This profile with channel ``c``'s beam raised by ``offsets_deg[c]`` (deg; channel 0 = lowest): a unit
        whose beams point, and whose driver reports them, off the nominal table. ConfigError naming the channel
        when it does not exist or when an offset would move a beam past a neighbour (channels keep their order)."""
        if not offsets_deg:
            return self
        order = self.channel_order
        bad = sorted(c for c in offsets_deg if not 0 <= c < len(order))
        if bad:
            raise ConfigError(f"elevation_offsets_deg: channels {bad} do not exist (the profile has channels "
                              f"0..{len(order) - 1})")  # fmt: skip
        elevation = np.array([b.elevation_deg for b in self.beams], dtype=np.float64)
        for channel, offset in offsets_deg.items():
            elevation[order[channel]] += offset
        moved = elevation[order]
        if np.any(np.abs(moved) > 90):
            c = int(np.argmax(np.abs(moved)))
            raise ConfigError(f"elevation_offsets_deg: channel {c} would point at {moved[c]:.4g} deg, beyond +-90 deg")
        if np.any(np.diff(moved) < 0):
            c = int(np.argmax(np.diff(moved) < 0))
            raise ConfigError(f"elevation_offsets_deg: channels {c} and {c + 1} would cross ({moved[c]:.4g} and "
                              f"{moved[c + 1]:.4g} deg): offsets must keep the channels' order")  # fmt: skip
        beams = [b.model_copy(update={"elevation_deg": float(e)}) for b, e in zip(self.beams, elevation)]
        return self.model_copy(update={"beams": beams})

    def with_return_mode(self, mode: str) -> "SensorProfile":
        """This profile reporting ``mode`` (one of :data:`~lidar_weather_sim.core.names.RETURN_MODES`; else a
        ConfigError naming ``return_mode`` and the valid modes)."""
        if mode not in RETURN_MODES:
            raise ConfigError(f"return_mode {mode!r} is not one of {', '.join(RETURN_MODES)}")
        return self.model_copy(update={"detection": self.detection.model_copy(update={"return_mode": mode})})


def profiles_dir() -> Path:
    """``config/sensors`` of the workspace (found from this file or ``LWS_WORKSPACE``)."""
    from lidar_weather_sim.core.paths import config_dir

    return config_dir() / "sensors"


def load_profile(name_or_path: str | Path) -> SensorProfile:
    """A profile by name (``config/sensors/<name>.yaml``) or by path."""
    return load_named(name_or_path, profiles_dir(), SensorProfile, "sensor profile")
