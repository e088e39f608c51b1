"""lidar-weather-sim render: points land on the expected pixels, colours, frame selection, actors, errors."""

from __future__ import annotations

import numpy as np
import pytest
from PIL import Image

from lidar_weather_sim.cli import main
from lidar_weather_sim.core.points import Label
from lidar_weather_sim.testing.bags import points_at, write_cloud_bag
from lidar_weather_sim.viz.colors import (
    BACKGROUND,
    BOX,
    CATEGORY_BASE,
    LABEL_COLORS,
    LUT_BASE,
    color_indices,
    make_spec,
)
from lidar_weather_sim.viz.pictures import bev_picture
from lidar_weather_sim.viz.raster import BevView, RangeView, bev_image, range_image, zbuffer
from lidar_weather_sim.viz.render import run_style
from lidar_weather_sim.viz.source import FrameSource, parse_selection


def test_bev_points_land_on_their_pixels_and_the_highest_wins():
    view = BevView(-10.0, 30.0, 20.0, 400)  # 0.1 m per pixel; sensor at column 200, row 300
    points = points_at([[9.95, 4.95, 0.0], [-0.05, -0.05, 0.0], [-5.05, -15.05, 1.0], [9.98, 4.98, 2.0]])
    colors = np.array([40, 41, 42, 43], np.uint8)
    image = bev_image(points, colors, view, point_px=1)
    assert view.origin_px == (200.0, 300.0)
    assert image[200, 150] == 43  # x 9.95 m ahead -> row 200, y 4.95 m left -> column 150; z 2 m is above z 0
    assert image[300, 200] == 41
    assert image[350, 350] == 42  # x -5.05 m -> row 350, y -15.05 m (right) -> column 350
    assert np.count_nonzero(image != BACKGROUND) == 3
    grown = bev_image(points, colors, view, point_px=3)
    assert np.count_nonzero(grown != BACKGROUND) == 27
    assert (grown[200:203, 150:153] == 43).all()


def test_zbuffer_keeps_one_point_per_cell():
    cells, kept = zbuffer(np.array([5, 5, 2, 5]), np.array([1.0, 3.0, 0.0, 2.0]), "max")
    assert cells.tolist() == [2, 5] and kept.tolist() == [2, 1]
    cells, kept = zbuffer(np.array([5, 5, 2, 5]), np.array([1.0, 3.0, 0.0, 2.0]), "min")
    assert cells.tolist() == [2, 5] and kept.tolist() == [2, 0]


def test_range_image_rows_are_channels_and_the_nearest_echo_wins():
    view = RangeView(channels=4, azimuth_max_rad=np.radians(40), bin_rad=np.radians(1), columns=80)
    az = np.radians([30.5, 30.5, -20.5, 0.5])
    dist = np.array([10.0, 5.0, 20.0, 7.0])
    xyz = np.c_[dist * np.cos(az), dist * np.sin(az), np.zeros(4)]
    points = points_at(xyz, channel=[1, 1, 3, 0])
    image = range_image(points, np.array([50, 51, 52, 53], np.uint8), view)
    assert image.shape == (4, 80)
    assert image[2, 9] == 51  # channel 1 -> row 2; 30.5 deg -> column 9; the 5 m echo hides the 10 m one
    assert image[0, 60] == 52  # channel 3 (top row), -20.5 deg -> column 60
    assert image[3, 39] == 53  # channel 0 is the bottom row
    assert np.count_nonzero(image != BACKGROUND) == 3


def test_colours_by_field():
    points = points_at(np.zeros((5, 3)), label=[Label.STATIC, Label.VEHICLE, Label.SPRAY, 99, Label.NOISE],
                       echo=[1, 2, 3, 4, 7], intensity=[0, 255, 128, 10, 20])  # fmt: skip
    label = make_spec("label", points, 60.0)
    pal = np.array(label.palette()).reshape(256, 3)
    rgb = pal[color_indices(points, label)]
    assert [tuple(c) for c in rgb] == [LABEL_COLORS[Label.STATIC], LABEL_COLORS[Label.VEHICLE],
                                      LABEL_COLORS[Label.SPRAY], LABEL_COLORS[Label.UNKNOWN], LABEL_COLORS[Label.NOISE]]
    echo = color_indices(points, make_spec("echo", points, 60.0))
    assert (echo - CATEGORY_BASE).tolist() == [0, 1, 2, 3, 3]
    intensity = color_indices(points, make_spec("intensity", points, 60.0))
    assert intensity[0] == LUT_BASE and intensity[1] == 255 and LUT_BASE < intensity[2] < 255
    with pytest.raises(ValueError, match="'nope'"):
        make_spec("nope", points, 60.0)


@pytest.mark.parametrize("text, expected", [(None, range(6)), ("2:4", range(2, 4)), (":3", range(3)), ("4:", range(4, 6)),
                                            ("5", range(5, 6)), ("3:100", range(3, 6))])  # fmt: skip
def test_frame_selection(text, expected):
    assert parse_selection(text, 6) == expected


@pytest.mark.parametrize("text", ["4:2", "6:", "9", "a:b", "1:2:3", "-1:2"])
def test_frame_selection_refuses_what_selects_nothing(text):
    with pytest.raises(ValueError, match="--frames"):
        parse_selection(text, 6)


def _scene(k: int = 0) -> np.ndarray:
    """A 1 m patch of vehicle points 20 m ahead, 5 m left (moving 1 m per frame), static points 10 m ahead."""
    g = np.stack(np.meshgrid(np.linspace(0, 1, 6), np.linspace(0, 1, 6)), -1).reshape(-1, 2)
    vehicle = points_at(np.c_[20.0 + k + g[:, 0], 5.0 + g[:, 1], np.zeros(len(g))], label=Label.VEHICLE, channel=1)
    static = points_at(np.c_[np.full(len(g), 10.0), -10.0 + g[:, 1], -1 + g[:, 0]], label=Label.STATIC, channel=0)
    return np.concatenate([vehicle, static])


def test_render_writes_pictures_whose_pixels_have_the_label_colours(tmp_path):
    bag = write_cloud_bag(tmp_path / "bag", [_scene(k) for k in range(6)])
    out = tmp_path / "out"
    assert main(["render", str(bag), "--frames", "2:4", "--range", "40", "--size", "400", "--out", str(out)]) == 0
    assert sorted(p.name for p in out.iterdir()) == ["animation.gif", "bev_00002.png", "bev_00003.png",
                                                     "range_00002.png", "range_00003.png"]  # fmt: skip
    with Image.open(out / "animation.gif") as gif:
        assert gif.n_frames == 2
    view = BevView.ahead(40.0, 400)  # 0.15 m per pixel
    picture = np.asarray(Image.open(out / "bev_00002.png").convert("RGB"))
    col, row = (int(v[0]) for v in view.to_px(np.array([22.5]), np.array([5.5])))  # frame 2: the patch at x 22-23 m
    assert tuple(picture[row, col]) == LABEL_COLORS[Label.VEHICLE]
    col, row = (int(v[0]) for v in view.to_px(np.array([10.0]), np.array([-9.5])))
    assert tuple(picture[row, col]) == LABEL_COLORS[Label.STATIC]
    plot = picture[:, : view.size_px]
    vehicle = np.all(plot == LABEL_COLORS[Label.VEHICLE], axis=-1)
    rows, cols = np.nonzero(vehicle)
    assert 20 < vehicle.sum() < 200  # 36 points on a 7 x 7 px patch, 3 px dots
    assert view.to_px(np.array([23.5]), 0)[1][0] <= rows.min() and rows.max() <= view.to_px(np.array([21.5]), 0)[1][0]
    for other in (Label.OBSTACLE, Label.SPRAY, Label.RAIN):  # labels the cloud does not have: only in the legend
        assert not np.all(plot == LABEL_COLORS[other], axis=-1).any()


def test_actors_from_tf_are_boxes_with_a_size_and_markers_without(tmp_path):
    bag = write_cloud_bag(tmp_path / "bag", [_scene(), _scene()], actors={100: (20.0, -4.0, np.pi / 2), 101: (30.0, 3.0, 0.0)})
    source = FrameSource(bag, sizes={100: (4.0, 2.0, 1.5)})
    frame = next(iter(source))
    actors = {a.actor_id: a for a in frame.actors}
    assert actors[101].size_m is None and np.allclose(actors[101].pose[:3, 3], [30.0, 3.0, 0.0])
    corners = actors[100].footprint()  # 4 m long along y (yaw 90 deg), 2 m wide along x
    assert np.allclose(np.sort(corners[:, 0]), [19, 19, 21, 21]) and np.allclose(np.sort(corners[:, 1]), [-6, -6, -2, -2])
    view = BevView.ahead(40.0, 400)
    indices = np.asarray(bev_picture(frame, run_style(frame, None, 40.0, 400, None)))[:, :400]
    col, row = view.to_px(np.array([19.0, 21.0]), np.array([-2.0, -6.0]))
    box = indices[int(row[1]) - 2: int(row[0]) + 3, int(col[0]) - 2: int(col[1]) + 3] == BOX
    assert box.sum() > 40  # the outline of a 13 x 27 px rectangle (2 px wide) and the heading line
    col, row = view.to_px(np.array([19.7, 19.3]), np.array([-2.5, -5.5]))  # inside, clear of the heading line
    assert not (indices[int(row[0]) + 1: int(row[1]), int(col[0]) + 1: int(col[1])] == BOX).any()  # hollow
    col, row = view.to_px(np.array([30.0]), np.array([3.0]))  # actor 101: a 10 px circle around its origin
    ring = indices[int(row[0]) - 6: int(row[0]) + 7, int(col[0]) - 6: int(col[0]) + 7] == BOX
    assert ring.sum() > 20 and not ring[5:8, 5:8].all()


def _error_lines(capsys) -> list[str]:
    return [line for line in capsys.readouterr().err.splitlines() if line.strip() and not line.startswith("note: ")]


def test_bad_input_exits_non_zero_with_one_line(tmp_path, capsys):
    bag = write_cloud_bag(tmp_path / "bag", [_scene(), _scene()])
    out = str(tmp_path / "out")
    assert main(["render", str(bag), "--topic", "/nope", "--out", out]) == 2
    (line,) = _error_lines(capsys)
    assert "/nope" in line and line.startswith("lidar-weather-sim render: error:")
    assert main(["render", str(bag), "--frames", "5:9", "--out", out]) == 2
    (line,) = _error_lines(capsys)
    assert "--frames 5:9 selects no frame" in line and "2 clouds" in line
    (tmp_path / "notabag").mkdir()
    (tmp_path / "notabag" / "data.txt").write_text("hello")
    assert main(["render", str(tmp_path / "notabag"), "--out", out]) == 2
    (line,) = _error_lines(capsys)
    assert "is not a bag" in line
    assert main(["render", str(tmp_path / "missing"), "--out", out]) == 2
    (line,) = _error_lines(capsys)
    assert "bag not found" in line
    no_truth = write_cloud_bag(tmp_path / "real", [_scene()[["x", "y", "z", "intensity", "channel"]]])
    assert main(["render", str(no_truth), "--color", "label", "--out", out]) == 2
    (line,) = _error_lines(capsys)
    assert "'label'" in line and "intensity" in line
