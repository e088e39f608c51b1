"""The legend panel beside every picture (Pillow, paletted, no anti-aliasing so the palette stays fixed):
a title, the colour key (swatches for categories, a vertical colour bar with ticks and unit for a
continuous field) and the key of the markers (ego, actor boxes or actor frames)."""

from __future__ import annotations

from functools import cache

import numpy as np
from PIL import Image, ImageDraw, ImageFont

from lidar_weather_sim.viz.colors import BOX, CATEGORY_BASE, DIM, EGO, LUT_BASE, LUT_SIZE, PANEL, TEXT, ColorSpec

PANEL_PX = 230


@cache
def font(size: int = 13) -> ImageFont.ImageFont:
    """Pillow's bundled font at ``size`` px (no system font needed)."""
    return ImageFont.load_default(size=size)


def ego_marker(draw: ImageDraw.ImageDraw, col: float, row: float, px: int = 8) -> None:
    """A triangle at (col, row) pointing up the image (the sensor's +x in the bird's-eye view)."""
    draw.polygon([(col, row - px), (col - px * 0.6, row + px * 0.6), (col + px * 0.6, row + px * 0.6)], outline=EGO,
                 fill=EGO)  # fmt: skip


def nice_step(span: float, target: int = 5) -> float:
    """A 1-2-5 step giving about ``target`` ticks over ``span``."""
    raw = max(span, 1e-9) / target
    base = 10.0 ** np.floor(np.log10(raw))
    return float(base * min((m for m in (1, 2, 5, 10) if m * base >= raw), default=10))


def panel(height: int, spec: ColorSpec, lines: list[str], boxes_sized: bool | None) -> Image.Image:
    """The legend panel, ``PANEL_PX`` wide: ``lines`` of text, the colour key, the marker key.
    ``boxes_sized``: True (boxes of known size drawn), False (frame markers only), None (no actor)."""
    image = _key(height, spec, len(lines), boxes_sized).copy()
    draw = ImageDraw.Draw(image)
    draw.fontmode = "1"
    for k, line in enumerate(lines):
        draw.text((10, 8 + 17 * k), line, fill=TEXT, font=font())
    return image


@cache
def _key(height: int, spec: ColorSpec, skip_lines: int, boxes_sized: bool | None) -> Image.Image:
    """The part of the panel that is the same in every frame (drawn once per run)."""
    image = Image.new("P", (PANEL_PX, height), PANEL)
    draw = ImageDraw.Draw(image)
    draw.fontmode = "1"
    y = 14 + 17 * skip_lines
    draw.text((10, y), f"colour: {spec.title}", fill=TEXT, font=font())
    y += 20
    if spec.categorical:
        for k, (code, name, _) in enumerate(spec.categories):
            draw.rectangle((12, y + 2, 24, y + 12), fill=CATEGORY_BASE + k)
            draw.text((32, y), f"{code:>2} {name}" if spec.field == "label" else name, fill=TEXT, font=font())
            y += 16
    else:
        bar = min(220, max(60, height - y - 90))
        ramp = (LUT_BASE + np.linspace(LUT_SIZE - 1, 0, bar)).astype(np.uint8)
        image.paste(Image.fromarray(np.repeat(ramp[:, None], 18, axis=1), "P"), (14, y))
        step = nice_step(spec.vmax - spec.vmin, 4)
        for value in np.arange(np.ceil(spec.vmin / step) * step, spec.vmax + step * 1e-6, step):
            ty = y + (bar - 1) * (1 - (value - spec.vmin) / (spec.vmax - spec.vmin))
            draw.line((32, ty, 37, ty), fill=TEXT)
            draw.text((41, ty - 7), f"{value:g} {spec.unit}".strip(), fill=TEXT, font=font())
        y += bar + 10
    y += 8
    ego_marker(draw, 18, y + 8, 7)
    draw.text((32, y), "ego: sensor origin, +x", fill=TEXT, font=font())
    y += 20
    if boxes_sized is not None:
        if boxes_sized:
            draw.rectangle((12, y + 2, 24, y + 12), outline=BOX)
            draw.text((32, y), "actor box (scenario size)", fill=TEXT, font=font())
        else:
            draw.ellipse((13, y + 3, 23, y + 13), outline=BOX)
            draw.text((32, y), "actor frame (size unknown)", fill=TEXT, font=font())
        y += 20
    if y > height:
        draw.text((10, height - 16), "(legend cut: picture too short)", fill=DIM, font=font())
    return image
