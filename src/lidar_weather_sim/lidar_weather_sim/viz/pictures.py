"""The two pictures of a frame, as paletted Pillow images with the legend panel on the right.

Bird's-eye picture: the cloud from above (:func:`~lidar_weather_sim.viz.raster.bev_image`), range rings
around the sensor, a metre scale bar (bottom left), the ego (a triangle at the sensor origin pointing
along +x) and each actor: its footprint box (with a line to the middle of its front) when its size is
known, else a circle at its frame's origin and a 3 m heading line, with its id.

Range-image picture: rows are channels (0 at the bottom), columns azimuth (degrees ticked below, the
sensor's left on the left); each actor with a size is the rectangle spanning its box's azimuths and
the channels whose mean elevation in this frame lies within its box's elevations, labelled with its id
and distance (m) from the sensor; without a size a vertical line at its origin's azimuth.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cache

import numpy as np
from PIL import Image, ImageDraw

from lidar_weather_sim.viz.colors import BACKGROUND, BOX, DIM, EGO, GRID, TEXT, ColorSpec, color_indices
from lidar_weather_sim.viz.legend import PANEL_PX, ego_marker, font, nice_step, panel
from lidar_weather_sim.viz.raster import BevView, RangeView, bev_image, range_image
from lidar_weather_sim.viz.source import RenderFrame

RANGE_AXIS_PX = 26


@dataclass(frozen=True)
class Style:
    """What a run's pictures share: colouring, the bird's-eye window, point size (px)."""

    spec: ColorSpec
    bev: BevView
    point_px: int
    palette: list[int]


def _caption(frame: RenderFrame) -> list[str]:
    return [f"frame {frame.index}   t = {frame.time_s:.3f} s", f"{len(frame.points)} points ({frame.frame_id} frame)"]


def _sized(frame: RenderFrame) -> bool | None:
    return None if not frame.actors else all(a.size_m is not None for a in frame.actors)


@cache
def _bev_grid(view: BevView) -> Image.Image:
    """Range rings around the sensor, labelled in m (drawn once per view)."""
    image = Image.new("P", (view.size_px, view.size_px), BACKGROUND)
    draw = ImageDraw.Draw(image)
    draw.fontmode = "1"
    col0, row0 = view.origin_px
    step = nice_step(view.x_max_m, 4)
    for r in np.arange(step, 2 * view.x_max_m, step):
        rad = r / view.metres_per_px
        draw.ellipse((col0 - rad, row0 - rad, col0 + rad, row0 + rad), outline=GRID)
        draw.text((col0 + 3, row0 - rad + 2), f"{r:g} m", fill=DIM, font=font(11))
    return image


def bev_picture(frame: RenderFrame, style: Style) -> Image.Image:
    """The bird's-eye picture of ``frame`` (sensor frame, x up, y left)."""
    view = style.bev
    points = bev_image(frame.points, color_indices(frame.points, style.spec), view, style.point_px)
    plot = np.asarray(_bev_grid(view)).copy()
    plot[points != BACKGROUND] = points[points != BACKGROUND]
    image = Image.new("P", (view.size_px + PANEL_PX, view.size_px), BACKGROUND)
    image.paste(Image.fromarray(plot, "P"), (0, 0))
    draw = ImageDraw.Draw(image)
    draw.fontmode = "1"
    for actor in frame.actors:
        _bev_actor(draw, view, actor)
    ego_marker(draw, *view.origin_px)
    bar_m = nice_step(view.x_max_m, 5)
    bar_px, left, base = bar_m / view.metres_per_px, 16, view.size_px - 18
    draw.line((left, base, left + bar_px, base), fill=TEXT, width=3)
    for x in (left, left + bar_px):
        draw.line((x, base - 6, x, base + 4), fill=TEXT)
    draw.text((left + bar_px + 8, base - 8), f"{bar_m:g} m", fill=TEXT, font=font())
    image.paste(panel(view.size_px, style.spec, _caption(frame), _sized(frame)), (view.size_px, 0))
    image.putpalette(style.palette)
    return image


def _bev_actor(draw: ImageDraw.ImageDraw, view: BevView, actor) -> None:
    col, row = view.to_px(actor.pose[0, 3], actor.pose[1, 3])
    if actor.size_m is not None:
        corners = actor.footprint()
        cc, rr = view.to_px(corners[:, 0], corners[:, 1])
        draw.polygon(list(zip(cc.tolist(), rr.tolist())), outline=BOX, width=2)
        front = actor.to_sensor(np.array([[actor.size_m[0] / 2, 0.0, 0.0]]))[0]
    else:
        draw.ellipse((col - 5, row - 5, col + 5, row + 5), outline=BOX, width=2)
        front = actor.to_sensor(np.array([[3.0, 0.0, 0.0]]))[0]
    fc, fr = view.to_px(front[0], front[1])
    draw.line((float(col), float(row), float(fc), float(fr)), fill=BOX, width=2)
    text_at = (float(cc.max()) + 4, float(rr.min())) if actor.size_m is not None else (float(col) + 8, float(row) - 6)
    draw.text(text_at, str(actor.actor_id), fill=BOX, font=font(12))  # beside the box, not inside


def range_picture(frame: RenderFrame, style: Style, view: RangeView, width_px: int) -> Image.Image:
    """The range-image picture of ``frame``: ``view``'s grid stretched to ``width_px`` and about 256 px high."""
    cells = range_image(frame.points, color_indices(frame.points, style.spec), view)
    row_px = max(1, 256 // view.channels)
    columns = (np.arange(width_px) * view.columns // width_px).astype(np.intp)
    plot = np.repeat(cells, row_px, axis=0)[:, columns]
    height = plot.shape[0] + RANGE_AXIS_PX
    legend_h = max(height, 330)
    image = Image.new("P", (width_px + PANEL_PX, legend_h), BACKGROUND)
    image.paste(Image.fromarray(np.ascontiguousarray(plot), "P"), (0, 0))
    draw = ImageDraw.Draw(image)
    draw.fontmode = "1"
    scale = width_px / view.columns  # px per azimuth bin
    span = np.degrees(view.bin_rad * view.columns)
    step = nice_step(span, 8)
    top = np.degrees(view.azimuth_max_rad)
    for deg in np.arange(np.ceil((top - span) / step) * step, top + 1e-6, step):
        x = view.column_of(np.radians(deg)) * scale
        draw.line((x, plot.shape[0], x, plot.shape[0] + 5), fill=TEXT)
        draw.text((x - 10, plot.shape[0] + 7), f"{deg:+g}\N{DEGREE SIGN}", fill=TEXT, font=font(11))
    _range_actors(draw, frame, view, scale, row_px)
    lines = _caption(frame) + [f"rows: channel 0 (bottom) - {view.channels - 1}", "columns: azimuth (left = +y)",
                              "nearest return per cell"]
    image.paste(panel(legend_h, style.spec, lines, _sized(frame)), (width_px, 0))
    image.putpalette(style.palette)
    return image


def _range_actors(draw: ImageDraw.ImageDraw, frame: RenderFrame, view: RangeView, scale: float, row_px: int) -> None:
    p = frame.points
    counts = np.bincount(p["channel"].astype(np.intp), minlength=view.channels)[: view.channels]
    elevation = np.arctan2(p["z"].astype(np.float64), np.hypot(p["x"], p["y"]))
    mean_el = np.bincount(p["channel"].astype(np.intp), elevation, view.channels)[: view.channels] / np.maximum(counts, 1)
    seen = np.flatnonzero(counts)
    order = seen[np.argsort(mean_el[seen])]
    for actor in frame.actors:
        origin = actor.pose[:3, 3]
        label = f"{actor.actor_id}: {np.linalg.norm(origin):.1f} m"
        if actor.size_m is None or len(order) < 2:
            x = view.column_of(np.arctan2(origin[1], origin[0])) * scale
            draw.line((x, 0, x, view.channels * row_px - 1), fill=BOX, width=1)
            draw.text((x + 4, 4), label, fill=BOX, font=font(12))
            continue
        c = actor.corners()
        az = np.arctan2(c[:, 1], c[:, 0])
        if np.ptp(az) > np.pi:
            continue  # straddles the seam behind the sensor (or surrounds it)
        el = np.arctan2(c[:, 2], np.hypot(c[:, 0], c[:, 1]))
        chan = np.interp([el.min(), el.max()], mean_el[order], order.astype(float))
        x0, x1 = np.sort(view.column_of([az.max(), az.min()]) * scale)
        y0, y1 = (view.channels - 1 - chan[1]) * row_px, (view.channels - chan[0]) * row_px
        draw.rectangle((x0, max(0.0, y0), x1, min(y1, view.channels * row_px - 1)), outline=BOX, width=2)
        draw.text((x0, max(0.0, y0) + 3), label, fill=BOX, font=font(12))
    if not frame.actors:
        return
    draw.text((4, view.channels * row_px - 16), "actor id: distance from the sensor", fill=EGO, font=font(11))
