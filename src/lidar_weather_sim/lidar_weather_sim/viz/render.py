"""``lidar-weather-sim render``: per selected frame a bird's-eye PNG and a range-image PNG, and an
animated GIF of the run (each GIF frame the bird's-eye picture above the range-image picture).

Outputs in DIR: ``bev_NNNNN.png``, ``range_NNNNN.png`` (NNNNN: the frame's number in the topic) and
``animation.gif`` (played at the recording's frame rate: the median gap between header stamps).
Clouds without a ``channel`` field get no range image. All geometry is in the cloud's frame (the
sensor frame; REP-103: x forward, y left, z up; metres). See :mod:`~lidar_weather_sim.viz.pictures`
for what each picture draws and :mod:`~lidar_weather_sim.viz.source` for where actors come from.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Callable, Iterator

import numpy as np
from PIL import Image

from lidar_weather_sim.viz.colors import make_spec
from lidar_weather_sim.viz.pictures import Style, bev_picture, range_picture
from lidar_weather_sim.viz.raster import BevView, RangeView
from lidar_weather_sim.viz.source import FrameSource, RenderFrame

SPARSE_POINTS = 30_000  # frames with fewer points are drawn with 3 px dots, denser ones with 2 px


@dataclass
class RenderReport:
    """What :func:`render_run` wrote, and its wall-clock seconds per frame (rendering and writing)."""

    out: Path
    frames: list[int] = field(default_factory=list)
    bev: list[Path] = field(default_factory=list)
    range: list[Path] = field(default_factory=list)
    animation: Path | None = None
    seconds_per_frame: float = 0.0
    notes: list[str] = field(default_factory=list)


def default_color(points: np.ndarray) -> str:
    """``label`` for clouds with ground truth, else ``distance``."""
    return "label" if "label" in (points.dtype.names or ()) else "distance"


def run_style(first: RenderFrame, color: str | None, range_m: float, size_px: int, point_px: int | None) -> Style:
    """The style every picture of a run shares, fixed from its first frame."""
    spec = make_spec(color or default_color(first.points), first.points, range_m)
    px = point_px or (3 if len(first.points) < SPARSE_POINTS else 2)
    return Style(spec, BevView.ahead(range_m, size_px), px, spec.palette())


def render_run(source: FrameSource, out: str | Path, *, color: str | None = None, range_m: float = 60.0,
               size_px: int = 800, point_px: int | None = None, animation: bool = True,
               progress: Callable[[int, int], None] | None = None) -> RenderReport:  # fmt: skip
    """Draw every frame of ``source`` into ``out`` (created); see the module doc for the files."""
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    report = RenderReport(out)
    style = range_view = None
    stamps = []
    started = time.perf_counter()
    for frame in source:
        if style is None:
            style = run_style(frame, color, range_m, size_px, point_px)
            has_channel = "channel" in (frame.points.dtype.names or ())
            range_view = RangeView.of(frame.points) if has_channel else None  # an empty frame: a full turn
            if not has_channel:
                report.notes.append("the clouds have no 'channel' field: no range image")
        if range_view is not None and len(frame.points):  # alternating layers: a channel may show up later
            channels = max(range_view.channels, int(frame.points["channel"].max()) + 1)
            range_view = replace(range_view, channels=channels)
        bev = out / f"bev_{frame.index:05d}.png"
        bev_picture(frame, style).save(bev, compress_level=1)
        report.bev.append(bev)
        if range_view is not None:
            rng = out / f"range_{frame.index:05d}.png"
            range_picture(frame, style, range_view, size_px).save(rng, compress_level=1)
            report.range.append(rng)
        report.frames.append(frame.index)
        stamps.append(frame.stamp_ns)
        if progress:
            progress(len(report.frames), len(source))
    if animation and report.frames:
        report.animation = out / "animation.gif"
        write_gif(report.animation, report.bev, report.range, _period_ms(stamps))
    report.seconds_per_frame = (time.perf_counter() - started) / max(1, len(report.frames))
    return report


def _period_ms(stamps: list[int]) -> int:
    gaps = np.diff(np.sort(np.asarray(stamps, np.int64)))
    return int(round(np.median(gaps) / 1e6)) if len(gaps) and np.median(gaps) > 0 else 100


def _stacked(bev: list[Path], rng: list[Path]) -> Iterator[Image.Image]:
    for k, path in enumerate(bev):
        top = Image.open(path)
        if not rng:
            yield top
            continue
        bottom = Image.open(rng[k])
        both = Image.new("P", (max(top.width, bottom.width), top.height + bottom.height), 0)
        both.paste(top, (0, 0))
        both.paste(bottom, (0, top.height))
        both.putpalette(top.getpalette())
        yield both


def write_gif(path: Path, bev: list[Path], rng: list[Path], period_ms: int) -> None:
    """An endless GIF of the pictures (read back one at a time: memory stays one frame)."""
    frames = _stacked(bev, rng)
    first = next(frames)
    first.save(path, save_all=True, append_images=frames, duration=max(20, period_ms), loop=0, optimize=False)
