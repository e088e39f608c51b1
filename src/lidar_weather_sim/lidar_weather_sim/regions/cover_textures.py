"""Sensor-cover transmission textures (thesis paper 1): database and seeded hierarchical random fields.

A texture is a grid of one-way transmission (0-1) over the sensor's field of
view: rows = elevation from the lowest to the highest beam edge, columns =
azimuth from ``azimuth_min_deg`` to ``azimuth_max_deg`` of the profile (sensor
frame, REP-103). The paper measured 4 x 18 points per cover; the grid is
sampled bilinearly, so any finer sampling is an interpolation.

Texture kinds (``config/cover/samples.yaml``, written by ``benchmarks/calibration/fit_cover.py``
from paper 1 Tables I and II):

- ``clean``: transmission 1 everywhere;
- a dirt sample (``1u`` ... ``6l``): a hierarchical random field. Level 1: the
  cover's mean transmission is drawn around the sample mean with the spread
  between the two covers of that sample (u/l); level 2: a spatially correlated
  Gaussian field with the within-cover spread is added and re-centred so the
  grid mean equals the level-1 mean exactly;
- ``water_film``: a uniform film with a small spread (estimate, see the file);
- ``dirt:<T>``: generic dirt of mean transmission T (0-1): a hierarchical field whose
  spreads, range noise, forward share and cover-return rate are interpolated between the
  thesis samples by opacity 1 - T (continuous in T, so T can be fitted);
- ``image:<path>``: a custom texture from a grey-scale image (PNG via
  matplotlib, or ``.npy``), 0 = opaque, 1 (or 255) = clear.

Besides transmission a texture carries the extra Monte-Carlo range noise
(m, one sigma) of Table II, the share of the beam energy scattered forward into
a wider cone (samples 3 and 5) and the rate of near-field cover returns.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np
from pydantic import Field
from scipy.ndimage import gaussian_filter, map_coordinates

from lidar_weather_sim.core.config import ConfigError, ConfigModel, load_yaml


class SampleSpec(ConfigModel):
    """One texture entry of ``config/cover/samples.yaml``."""

    mean_transmission: float = Field(ge=0, le=1, description="Mean one-way transmission (0-1)")
    between_sd: float = Field(0.0, ge=0, description="Spread of a cover's mean around the sample mean (0-1 units)")
    within_sd: float = Field(0.0, ge=0, description="Spread of the 4 x 18 grid points around the cover mean (0-1 units)")
    sigma_increase: float = Field(0.0, ge=-1, description="Relative increase of the range standard deviation (Table II)")
    forward_share: float = Field(0.0, ge=0, le=1, description="Share of beam energy scattered forward into a wider cone")
    near_field_per_beam: float = Field(0.0, ge=0, description="Mean near-field cover returns per beam and frame")
    source: str = ""


class SamplesFile(ConfigModel):
    grid: tuple[int, int] = Field((4, 18), description="Grid rows (elevation) x columns (azimuth) of a texture")
    correlation_cells: tuple[float, float] = Field((0.7, 2.0), description="Gaussian correlation length (cells)")
    source: str = ""
    samples: dict[str, SampleSpec]


@dataclass(frozen=True)
class CoverTexture:
    """Transmission grid (rows = elevation low->high, cols = azimuth min->max) and scalar effects."""

    name: str
    grid: np.ndarray
    extra_range_sigma_m: float = 0.0
    forward_share: float = 0.0
    near_field_per_beam: float = 0.0

    @property
    def mean(self) -> float:
        return float(self.grid.mean())

    def sample(self, u: np.ndarray, v: np.ndarray) -> np.ndarray:
        """Bilinear transmission at u (azimuth, 0-1 across the FOV) and v (elevation, 0-1), clamped at the edges."""
        rows, cols = self.grid.shape
        coords = np.stack([np.clip(v, 0, 1) * (rows - 1), np.clip(u, 0, 1) * (cols - 1)]).reshape(2, -1)
        return map_coordinates(self.grid, coords, order=1, mode="nearest").reshape(np.shape(u))


def samples_path() -> Path:
    from lidar_weather_sim.core.paths import config_dir

    return config_dir() / "cover" / "samples.yaml"


def load_samples(path: str | Path | None = None) -> SamplesFile:
    """The cover sample database (``config/cover/samples.yaml`` unless ``path``); read once per file and
    modification time (every cover region built reads it: hundreds of times in a gap search)."""
    path = Path(path or samples_path()).resolve()
    if not path.is_file():
        return load_yaml(path, SamplesFile)  # its one-line error names the file
    return _load_samples(path, path.stat().st_mtime_ns)


@functools.lru_cache(maxsize=8)
def _load_samples(path: Path, mtime_ns: int) -> SamplesFile:
    return load_yaml(path, SamplesFile)


def random_field(shape: tuple[int, int], correlation_cells, rng: np.random.Generator) -> np.ndarray:
    """Zero-mean, unit-variance, spatially correlated Gaussian field (Gaussian-smoothed white noise)."""
    field = gaussian_filter(rng.standard_normal(shape), sigma=correlation_cells, mode="wrap")
    field -= field.mean()
    sd = field.std()
    return field / sd if sd > 0 else field


def sample_texture(name: str, spec: SampleSpec, db: SamplesFile, rng: np.random.Generator,
                   base_range_sigma_m: float) -> CoverTexture:  # fmt: skip
    """One seeded realisation of a database entry (hierarchical random field, see module doc)."""
    cover_mean = float(np.clip(rng.normal(spec.mean_transmission, spec.between_sd), 0.0, 1.0))
    grid = cover_mean + spec.within_sd * random_field(db.grid, db.correlation_cells, rng)
    grid = np.clip(grid, 0.0, 1.0)
    grid += cover_mean - grid.mean()  # keep the level-1 mean after clipping
    extra = base_range_sigma_m * np.sqrt(max((1.0 + spec.sigma_increase) ** 2 - 1.0, 0.0))
    return CoverTexture(name, np.clip(grid, 0.0, 1.0), extra, spec.forward_share, spec.near_field_per_beam)


def dirt_spec(transmission: float, db: SamplesFile) -> SampleSpec:
    """A sample of mean ``transmission`` (0-1) with the other properties interpolated linearly
    in opacity between the thesis' dirt samples (all entries but ``water_film``)."""
    if not 0.0 <= transmission <= 1.0:
        raise ConfigError(f"cover texture 'dirt:{transmission}': transmission must be within 0-1")
    dirt = sorted((s for k, s in db.samples.items() if k != "water_film"), key=lambda s: 1.0 - s.mean_transmission)
    opacity = np.array([1.0 - s.mean_transmission for s in dirt])
    at = lambda attr: float(np.interp(1.0 - transmission, opacity, [getattr(s, attr) for s in dirt]))  # noqa: E731
    return SampleSpec(mean_transmission=transmission, within_sd=at("within_sd"), sigma_increase=at("sigma_increase"),
                      forward_share=at("forward_share"), near_field_per_beam=at("near_field_per_beam"),
                      source=f"interpolated between the thesis samples at opacity {1.0 - transmission:.3f}")  # fmt: skip


def with_mean(texture: CoverTexture, transmission: float) -> CoverTexture:
    """``texture`` with its opacity (1 - T) scaled so that its mean transmission is ``transmission``;
    the cover-return rate scales with the opacity too (more dirt or water, more multipath)."""
    opacity = 1.0 - texture.mean
    target = 1.0 - float(transmission)
    if opacity <= 1e-9:  # a clear texture: a uniform film of the wanted transmission
        return replace(texture, grid=np.full(texture.grid.shape, float(transmission)))
    grid = np.clip(1.0 - (1.0 - texture.grid) * (target / opacity), 0.0, 1.0)
    grid = np.clip(grid + (transmission - grid.mean()), 0.0, 1.0)
    return replace(texture, grid=grid, near_field_per_beam=texture.near_field_per_beam * target / opacity)


def with_contrast(texture: CoverTexture, contrast: float) -> CoverTexture:
    """``texture`` with the spread of its transmission around its mean scaled by ``contrast`` (0-1): 1 as drawn
    (the patches of the thesis' samples), 0 a uniform film of the same mean transmission."""
    mean = texture.mean
    return replace(texture, grid=mean + float(contrast) * (texture.grid - mean))


def image_texture(path: str | Path) -> CoverTexture:
    """A custom texture from a grey-scale image (row 0 = top of the FOV) or a ``.npy`` array of 0-1."""
    path = Path(path)
    try:
        if path.suffix == ".npy":
            data = np.load(path).astype(np.float64)
        else:
            import matplotlib.image

            data = matplotlib.image.imread(path).astype(np.float64)
    except (OSError, ValueError) as exc:
        raise ConfigError(f"{path}: cannot read cover texture image: {exc}") from None
    if data.ndim == 3:
        data = data[..., :3].mean(axis=2)
    if data.max() > 1.0:
        data = data / 255.0
    if data.ndim != 2 or min(data.shape) < 2:
        raise ConfigError(f"{path}: cover texture must be a 2-D image of at least 2 x 2, got shape {data.shape}")
    return CoverTexture(f"image:{path}", np.clip(data[::-1], 0.0, 1.0))


def make_texture(name: str, rng: np.random.Generator, base_range_sigma_m: float,
                 db: SamplesFile | None = None) -> CoverTexture:  # fmt: skip
    """Texture ``name``: ``clean``, a database entry (e.g. ``3l``, ``water_film``) or ``image:<path>``."""
    if name == "clean":
        return CoverTexture("clean", np.ones((2, 2)))
    if name.startswith("image:"):
        return image_texture(name[len("image:"):])
    db = db or load_samples()
    if name.startswith("dirt:"):
        try:
            transmission = float(name[len("dirt:"):])
        except ValueError:
            raise ConfigError(f"cover texture '{name}': expected dirt:<mean transmission 0-1>") from None
        return sample_texture(name, dirt_spec(transmission, db), db, rng, base_range_sigma_m)
    if name not in db.samples:
        raise ConfigError(f"{samples_path()}: unknown cover texture '{name}' (known: clean, dirt:<T>, image:<path>, "
                          f"{', '.join(db.samples)})")  # fmt: skip
    return sample_texture(name, db.samples[name], db, rng, base_range_sigma_m)


def blend(a: CoverTexture, b: CoverTexture, weight: float) -> CoverTexture:
    """(1 - weight) a + weight b; grids of different shape are resampled onto the finer one."""
    weight = float(np.clip(weight, 0.0, 1.0))
    shape = max(a.grid.shape, b.grid.shape, key=lambda s: s[0] * s[1])

    def on(t: CoverTexture) -> np.ndarray:
        v, u = np.meshgrid(np.linspace(0, 1, shape[0]), np.linspace(0, 1, shape[1]), indexing="ij")
        return t.sample(u, v)

    mix = lambda x, y: (1.0 - weight) * x + weight * y  # noqa: E731
    return replace(a, name=f"{a.name}->{b.name}@{weight:.2f}", grid=mix(on(a), on(b)),
                   extra_range_sigma_m=mix(a.extra_range_sigma_m, b.extra_range_sigma_m),
                   forward_share=mix(a.forward_share, b.forward_share),
                   near_field_per_beam=mix(a.near_field_per_beam, b.near_field_per_beam))  # fmt: skip
