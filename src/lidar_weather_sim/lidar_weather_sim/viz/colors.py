"""Point colours by one field, as indices into one 256-entry palette shared by every picture of a run.

Palette layout (RGB): 0-15 the pictures' own colours (background, grid, text, ego, actor boxes,
legend panel), 16-31 categorical colours (labels or echo numbers), 32-255 a continuous colour map
(224 steps; matplotlib's, sampled once). One fixed palette lets every picture be a paletted PNG and
a GIF frame as it is (no quantisation per frame).

Fields: ``label`` (ground truth, :class:`~lidar_weather_sim.core.points.Label`) and ``echo`` (1-based;
4 and more share one colour) are categorical; ``intensity`` (0-255), ``epw`` (echo pulse width, m) and
``distance`` (range along the beam, m; from x, y, z when the cloud has no ``distance`` field) are
continuous, over a fixed range for the whole run so that frames compare (see :func:`make_spec`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from lidar_weather_sim.core.points import Label

FIELDS = ("label", "echo", "epw", "intensity", "distance")

BACKGROUND, GRID, TEXT, EGO, BOX, PANEL, DIM = range(7)
_OWN = [(18, 18, 22), (58, 58, 68), (235, 235, 235), (255, 255, 255), (255, 60, 255), (34, 34, 40), (140, 140, 150)]
CATEGORY_BASE = 16
LUT_BASE = 32
LUT_SIZE = 256 - LUT_BASE

#: Colour of each ground-truth label (legend order); codes outside the enum are drawn as UNKNOWN.
LABEL_COLORS: dict[Label, tuple[int, int, int]] = {
    Label.UNKNOWN: (120, 120, 120),
    Label.STATIC: (150, 165, 190),
    Label.VEHICLE: (255, 150, 20),
    Label.OBSTACLE: (230, 30, 30),
    Label.COVER: (160, 100, 50),
    Label.RAIN: (40, 110, 255),
    Label.FOG: (150, 225, 235),
    Label.SNOW: (255, 255, 255),
    Label.SPRAY: (0, 230, 170),
    Label.NOISE: (240, 230, 30),
}
#: Colours of echo numbers 1, 2, 3 and 4+.
ECHO_COLORS = [(70, 160, 255), (255, 170, 30), (240, 50, 140), (140, 255, 110)]
_CMAPS = {"intensity": ("viridis", "intensity (0-255)", "-"), "epw": ("plasma", "echo pulse width", "m"),
          "distance": ("turbo", "distance", "m")}  # fmt: skip


@dataclass(frozen=True)
class ColorSpec:
    """How one field is coloured: categories (code, name, RGB) or a colour map over [vmin, vmax] (unit)."""

    field: str
    title: str
    categories: tuple[tuple[int, str, tuple[int, int, int]], ...] = ()
    cmap: str = ""
    vmin: float = 0.0
    vmax: float = 1.0
    unit: str = ""

    @property
    def categorical(self) -> bool:
        return bool(self.categories)

    def lut_rgb(self) -> np.ndarray:
        """(LUT_SIZE, 3) uint8 colours of the continuous map, low to high (empty when categorical)."""
        if self.categorical:
            return np.zeros((0, 3), np.uint8)
        import matplotlib  # the colour maps only; no pyplot

        return (matplotlib.colormaps[self.cmap](np.linspace(0.0, 1.0, LUT_SIZE))[:, :3] * 255 + 0.5).astype(np.uint8)

    def palette(self) -> list[int]:
        """The 768 RGB values of the picture palette for this field."""
        pal = np.zeros((256, 3), np.uint8)
        pal[: len(_OWN)] = _OWN
        for k, (_, _, rgb) in enumerate(self.categories):
            pal[CATEGORY_BASE + k] = rgb
        if not self.categorical:
            pal[LUT_BASE:] = self.lut_rgb()
        return pal.reshape(-1).tolist()


def field_values(points: np.ndarray, field: str) -> np.ndarray:
    """Values of ``field`` per point (float64); ``distance`` is computed from x, y, z (m) when absent.
    A field the cloud lacks raises ValueError naming the fields it has."""
    names = points.dtype.names or ()
    if field == "distance" and field not in names:
        return np.sqrt(points["x"].astype(np.float64) ** 2 + points["y"] ** 2 + points["z"] ** 2)
    if field not in names:
        raise ValueError(f"the clouds have no '{field}' field to colour by (fields: {', '.join(names)})")
    return points[field].astype(np.float64)


def make_spec(field: str, sample: np.ndarray, distance_max_m: float) -> ColorSpec:
    """The colouring of ``field`` for a run. Continuous ranges: intensity 0-255, distance 0 to
    ``distance_max_m`` (m), EPW 0 to the 99th percentile of ``sample`` (a frame of the run, m) rounded up
    to 0.1 m. Raises ValueError for an unknown field or one ``sample`` does not have."""
    if field not in FIELDS:
        raise ValueError(f"cannot colour by '{field}': choose one of {', '.join(FIELDS)}")
    values = field_values(sample, field)
    if field == "label":
        cats = tuple((int(code), code.name.lower(), rgb) for code, rgb in LABEL_COLORS.items())
        return ColorSpec(field, "label (ground truth)", cats)
    if field == "echo":
        names = ["1st", "2nd", "3rd", "4th+"]
        return ColorSpec(field, "echo number", tuple((k + 1, names[k], rgb) for k, rgb in enumerate(ECHO_COLORS)))
    cmap, title, unit = _CMAPS[field]
    if field == "intensity":
        return ColorSpec(field, title, cmap=cmap, vmin=0.0, vmax=255.0, unit=unit)
    if field == "distance":
        return ColorSpec(field, title, cmap=cmap, vmin=0.0, vmax=float(distance_max_m), unit=unit)
    top = float(np.percentile(values, 99.0)) if len(values) else 1.0
    return ColorSpec(field, title, cmap=cmap, vmin=0.0, vmax=max(0.1, np.ceil(top * 10.0) / 10.0), unit=unit)


def _category_lookup(spec: ColorSpec) -> np.ndarray:
    """256-entry table: field code -> palette index (unknown label codes -> UNKNOWN; echo >= 4 -> 4th+)."""
    table = np.full(256, CATEGORY_BASE, np.uint8)  # label UNKNOWN / echo 1st is entry 0
    codes = np.array([code for code, _, _ in spec.categories])
    table[codes] = CATEGORY_BASE + np.arange(len(codes))
    if spec.field == "echo":
        table[codes.max():] = CATEGORY_BASE + len(codes) - 1
    return table


def color_indices(points: np.ndarray, spec: ColorSpec) -> np.ndarray:
    """Palette index (uint8) of every point."""
    values = field_values(points, spec.field)
    if spec.categorical:
        return _category_lookup(spec)[np.clip(values, 0, 255).astype(np.intp)]
    scaled = (values - spec.vmin) / max(spec.vmax - spec.vmin, 1e-12) * (LUT_SIZE - 1)
    return (LUT_BASE + np.clip(np.rint(np.nan_to_num(scaled)), 0, LUT_SIZE - 1)).astype(np.uint8)
