"""render --html: the page is self-contained, holds the subsampled clouds exactly, and headless Chromium
draws them (WebGL through SwiftShader): pixels of the label colour / the colour scale in the plot area,
against a page of empty clouds."""

from __future__ import annotations

import base64
import json
import re
import shutil
import subprocess

import numpy as np
import pytest
from PIL import Image

from lidar_weather_sim.cli import main
from lidar_weather_sim.core.points import Label
from lidar_weather_sim.testing.bags import points_at, write_cloud_bag
from lidar_weather_sim.viz.colors import LABEL_COLORS, make_spec
from lidar_weather_sim.viz.html import subsample

CHROMIUM = shutil.which("chromium") or shutil.which("chromium-browser")
#: Headless Chromium with WebGL on the CPU (SwiftShader through ANGLE); without --enable-unsafe-swiftshader
#: Chromium 156 warns that its automatic software fallback is deprecated; --use-gl=swiftshader gives no WebGL.
CHROMIUM_FLAGS = ["--headless", "--no-sandbox", "--disable-gpu", "--use-angle=swiftshader", "--enable-unsafe-swiftshader",
                  "--hide-scrollbars", "--virtual-time-budget=20000"]  # fmt: skip
WINDOW = (1000, 800)


def _block(n: int, seed: int = 0) -> np.ndarray:
    """``n`` vehicle points filling a 6 x 4 x 2 m block 8-14 m ahead, intensities over 0-255."""
    rng = np.random.default_rng(seed)
    xyz = rng.uniform([8.0, -2.0, -1.0], [14.0, 2.0, 1.0], (n, 3))
    return points_at(xyz, label=Label.VEHICLE, intensity=rng.integers(0, 256, n), channel=rng.integers(0, 4, n),
                     epw=rng.uniform(0.1, 2.0, n))  # fmt: skip


def _page_data(html: str) -> dict:
    return json.loads(re.search(r"const D = (\{.*?\});\n", html).group(1))


def test_page_is_self_contained_and_holds_the_subsampled_clouds(tmp_path):
    clouds = [_block(500, seed=k) for k in range(3)]
    bag = write_cloud_bag(tmp_path / "bag", clouds)
    out = tmp_path / "out"
    assert main(["render", str(bag), "--html", "--max-points", "200", "--frames", "1:3", "--no-animation",
                 "--out", str(out)]) == 0  # fmt: skip
    html = (out / "cloud.html").read_text()
    assert "<script src=" not in html and "Plotly.newPlot" in html and len(html) > 3_000_000  # plotly.js is inside
    data = _page_data(html)
    assert [f["index"] for f in data["frames"]] == [1, 2] and data["color"] == "label"
    assert {s["field"] for s in data["specs"]} == {"label", "echo", "epw", "intensity", "distance"}
    for frame in data["frames"]:
        assert frame["total"] == 500 and frame["n"] == 200
        kept = subsample(clouds[frame["index"]], 200, frame["index"])
        xyz = np.frombuffer(base64.b64decode(frame["xyz"]), "<i2").reshape(-1, 3)
        expected = np.stack([kept["x"], kept["y"], kept["z"]], 1).astype(np.float64)
        assert np.abs(xyz / 100.0 - expected).max() <= 0.005 + 1e-6  # centimetres
        intensity = np.frombuffer(base64.b64decode(frame["fields"]["intensity"]), np.uint8)
        assert (intensity == kept["intensity"]).all()
        epw = np.frombuffer(base64.b64decode(frame["fields"]["epw"]), "<u2") / 1000.0
        assert np.abs(epw - kept["epw"]).max() <= 0.0005 + 1e-6
    bytes_per_point = (len(html) - _empty_page_size(tmp_path)) / (2 * 200)
    assert bytes_per_point < 16  # the docs say about 15 B per point


def _empty_page_size(tmp_path) -> int:
    bag = write_cloud_bag(tmp_path / "empty_bag", [_block(0), _block(0)])
    assert main(["render", str(bag), "--html", "--no-animation", "--out", str(tmp_path / "empty")]) == 0
    return len((tmp_path / "empty" / "cloud.html").read_text())


def test_subsample_keeps_order_and_drops_points_out_of_int16_range():
    points = points_at(np.c_[np.arange(1000.0) - 500.0, np.zeros(1000), np.zeros(1000)])
    kept = subsample(points, 100, seed=3)
    assert len(kept) == 100 and (np.diff(kept["x"]) > 0).all() and np.abs(kept["x"]).max() <= 327.67
    assert (subsample(points, 100, seed=3) == kept).all()
    assert len(subsample(points, 5000, seed=3)) == 655  # -327 .. 327 m


def _screenshot(page, out, fragment: str = "") -> np.ndarray:
    cmd = [CHROMIUM, *CHROMIUM_FLAGS, f"--user-data-dir={out.parent / 'chromium-profile'}",
           f"--window-size={WINDOW[0]},{WINDOW[1]}", f"--screenshot={out}", f"file://{page}{fragment}"]  # fmt: skip
    subprocess.run(cmd, check=True, capture_output=True, timeout=180)
    return np.asarray(Image.open(out).convert("RGB")).astype(np.int32)


def _plot_area(shot: np.ndarray) -> np.ndarray:
    """The 3D scene, clear of the controls (top), the legend and the colour bar (right)."""
    return shot[110: WINDOW[1] - 20, : int(WINDOW[0] * 0.7)]


def _near(area: np.ndarray, colors: np.ndarray, tolerance: int = 30) -> int:
    """Pixels within ``tolerance`` (each channel) of any of ``colors``."""
    close = np.zeros(area.shape[:2], bool)
    for color in colors:
        close |= (np.abs(area - color) <= tolerance).all(axis=-1)
    return int(close.sum())


@pytest.mark.skipif(CHROMIUM is None, reason="no chromium binary (scripts/setup.sh installs Debian's chromium)")
@pytest.mark.slow
def test_headless_chromium_draws_the_points(tmp_path):
    dense = write_cloud_bag(tmp_path / "dense", [_block(20_000)])
    empty = write_cloud_bag(tmp_path / "empty", [_block(0)])
    for bag in (dense, empty):
        assert main(["render", str(bag), "--html", "--no-animation", "--out", str(tmp_path / f"{bag.name}_out")]) == 0
    orange = np.array([LABEL_COLORS[Label.VEHICLE]])
    scale = make_spec("intensity", _block(1), 60.0).lut_rgb().astype(np.int32)[::8]
    page, blank = tmp_path / "dense_out" / "cloud.html", tmp_path / "empty_out" / "cloud.html"
    by_label = _plot_area(_screenshot(page, tmp_path / "label.png"))
    by_intensity = _plot_area(_screenshot(page, tmp_path / "intensity.png", "#color=intensity"))
    nothing = _plot_area(_screenshot(blank, tmp_path / "empty.png"))
    counts = {"label": _near(by_label, orange), "intensity": _near(by_intensity, scale),
              "empty: orange": _near(nothing, orange), "empty: scale": _near(nothing, scale)}
    assert counts["label"] > 2000, counts
    assert counts["intensity"] > 2000, counts
    assert counts["empty: orange"] < 50 and counts["empty: scale"] < 200, counts
    assert _near(by_intensity, orange, 10) < counts["label"] / 10, counts  # the colour choice took effect
