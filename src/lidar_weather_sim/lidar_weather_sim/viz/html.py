"""``lidar-weather-sim render --html``: one self-contained HTML page with the selected frames in 3D.

The page holds plotly.js (from the ``plotly`` wheel, embedded: nothing is fetched when it is viewed),
the clouds, and a small script (:mod:`~lidar_weather_sim.viz.cloud_script`) that draws one frame at a time as a
WebGL ``scatter3d`` (orbit, zoom, pan with the mouse), with a frame slider and a choice of the field
to colour by (those of :data:`~lidar_weather_sim.viz.colors.FIELDS` the clouds have); the legend lists
the categories (label, echo) or shows a colour bar (intensity, EPW in m, distance in m). The ego is a
diamond at the sensor origin with a 2 m line along +x; actors are wire boxes when their size is known
(see :mod:`~lidar_weather_sim.viz.source`), else their frame's origin and a 3 m heading line.

Size: each frame keeps at most ``max_points`` points (a random subset, seeded by the frame number, so
the same page comes out each time); coordinates are stored as int16 centimetres (points farther than
327 m on an axis are left out), label, echo and intensity as uint8, EPW as uint16 millimetres (to
65.5 m), base64-encoded: about 15 bytes per point (measured on OS1 frames), plus 4.8 MB of plotly.js. Geometry is in the
sensor frame (REP-103: x forward, y left, z up; m).
"""

from __future__ import annotations

import base64
import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from lidar_weather_sim.viz.cloud_script import SCRIPT
from lidar_weather_sim.viz.colors import FIELDS, ColorSpec, field_values, make_spec
from lidar_weather_sim.viz.render import default_color
from lidar_weather_sim.viz.source import ActorMarker, FrameSource, RenderFrame

MAX_AXIS_M = 327.67  # int16 centimetres
_BOX_EDGES = [(0, 1), (1, 2), (2, 3), (3, 0), (4, 5), (5, 6), (6, 7), (7, 4), (0, 4), (1, 5), (2, 6), (3, 7)]


@dataclass(frozen=True)
class HtmlPage:
    path: Path
    frames: int
    points: int  # points embedded, all frames


def _b64(array: np.ndarray) -> str:
    return base64.b64encode(np.ascontiguousarray(array).tobytes()).decode("ascii")


def subsample(points: np.ndarray, max_points: int, seed: int) -> np.ndarray:
    """At most ``max_points`` of ``points`` (a seeded random subset, in the original order), without
    points beyond +-327.67 m on an axis."""
    near = np.ones(len(points), bool)
    for axis in "xyz":
        near &= np.abs(points[axis]) <= MAX_AXIS_M
    keep = np.flatnonzero(near)
    if len(keep) > max_points:
        keep = np.sort(np.random.default_rng(seed).choice(keep, max_points, replace=False))
    return points[keep]


def _actor(actor: ActorMarker) -> dict:
    origin = actor.pose[:3, 3]
    ahead = actor.to_sensor(np.array([[actor.size_m[0] / 2 if actor.size_m else 3.0, 0.0, 0.0]]))[0]
    out = {"id": actor.actor_id, "origin": np.round(origin, 3).tolist(), "ahead": np.round(ahead, 3).tolist()}
    if actor.size_m is not None:
        c = actor.corners()
        out["edges"] = [np.round(c[[a, b]], 3).tolist() for a, b in _BOX_EDGES]
    return out


def encode_frame(frame: RenderFrame, fields: list[str], max_points: int) -> dict:
    """One frame as the page's JSON: counts, base64 xyz (int16 cm) and fields, actors."""
    p = subsample(frame.points, max_points, frame.index)
    xyz = np.rint(np.stack([p["x"], p["y"], p["z"]], axis=1).astype(np.float64) * 100).astype("<i2")
    encoded = {}
    for name in fields:
        if name == "distance":
            continue  # the page computes it from x, y, z
        values = field_values(p, name)
        encoded[name] = _b64(np.clip(np.rint(values * 1000), 0, 65535).astype("<u2") if name == "epw"
                             else np.clip(values, 0, 255).astype(np.uint8))  # fmt: skip
    return {"index": frame.index, "time": round(frame.time_s, 6), "total": int(len(frame.points)), "n": int(len(p)),
            "frame_id": frame.frame_id, "xyz": _b64(xyz), "fields": encoded,
            "actors": [_actor(a) for a in frame.actors]}  # fmt: skip


def spec_json(spec: ColorSpec) -> dict:
    """A colouring for the page: categories with CSS colours, or a plotly colour scale over [vmin, vmax]."""
    if spec.categorical:
        cats = [{"code": code, "name": name, "color": f"rgb{rgb}"} for code, name, rgb in spec.categories]
        return {"field": spec.field, "title": spec.title, "categories": cats}
    lut = spec.lut_rgb()
    stops = np.linspace(0, len(lut) - 1, 11).astype(int)
    scale = [[round(k / 10, 2), f"rgb({lut[i][0]},{lut[i][1]},{lut[i][2]})"] for k, i in enumerate(stops)]
    return {"field": spec.field, "title": f"{spec.title} ({spec.unit})" if spec.unit != "-" else spec.title,
            "colorscale": scale, "vmin": spec.vmin, "vmax": spec.vmax}  # fmt: skip


def write_html(source: FrameSource, path: str | Path, *, color: str | None = None, max_points: int = 20_000,
               range_m: float = 60.0) -> HtmlPage:  # fmt: skip
    """Write the page of ``source``'s frames to ``path`` (see the module doc)."""
    import plotly.graph_objects as go

    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    frames, specs = [], []
    for frame in source:
        if not specs:
            names = frame.points.dtype.names or ()
            fields = [f for f in FIELDS if f in names or f == "distance"]
            color = color or default_color(frame.points)
            if color not in fields:
                raise ValueError(f"the clouds have no '{color}' field to colour by (fields: {', '.join(names)})")
            specs = [spec_json(make_spec(f, frame.points, range_m)) for f in fields]
        frames.append(encode_frame(frame, fields, max_points))
    data = {"bag": str(source.path), "topic": source.topic, "color": color, "specs": specs, "frames": frames,
            "max_points": max_points}  # fmt: skip
    script = SCRIPT.replace("__DATA__", json.dumps(data, separators=(",", ":")).replace("</", "<\\/"))
    axis = dict(color="#bbbbbb", gridcolor="#3a3a44", zerolinecolor="#666", backgroundcolor="#141418")
    layout = go.Layout(
        template="plotly_dark", paper_bgcolor="#141418", font=dict(color="#e0e0e0"), uirevision="keep",
        margin=dict(l=0, r=0, t=30, b=0), legend=dict(itemsizing="constant", bgcolor="rgba(30,30,36,0.8)"),
        title=dict(text=f"{source.path.name} {source.topic}", x=0.01, font=dict(size=14)),
        scene=dict(aspectmode="data", bgcolor="#141418", camera=dict(eye=dict(x=-1.5, y=-0.4, z=1.0)),
                   xaxis=dict(title=dict(text="x (m, forward)"), **axis), yaxis=dict(title=dict(text="y (m, left)"), **axis),
                   zaxis=dict(title=dict(text="z (m, up)"), **axis)),
    )  # fmt: skip
    html = go.Figure(layout=layout).to_html(include_plotlyjs=True, full_html=True, div_id="lws-cloud",
                                            post_script=script, default_height="88vh",
                                            config={"displaylogo": False, "responsive": True})  # fmt: skip
    html = html.replace("<head>", f"<head><title>{source.path.name}: {source.topic}</title>", 1)
    path.write_text(html, encoding="utf-8")
    return HtmlPage(path, len(frames), sum(f["n"] for f in frames))
