"""``augment --kinds``: vehicle, pedestrian and tyre-debris meshes drawn and raycast like paper 4's boxes."""

from __future__ import annotations

import math

import numpy as np
import pytest

from lidar_weather_sim.core.points import Label, empty_points
from lidar_weather_sim.augment.obstacles import OBJECT_ID_BASE, ObstacleAugmenter
from lidar_weather_sim.augment.boxes import Box, Footprint, ObstacleError, Roi, footprints_overlap
from lidar_weather_sim.augment.cast import ObstacleCaster
from lidar_weather_sim.augment.kinds import KINDS, kind_ranges, parse_kinds, tyre_reflectivity
from lidar_weather_sim.augment.meshes import obstacle_mesh
from lidar_weather_sim.sensor.profile import load_profile

ROAD_Z = -1.8  # a roof-mounted OS1-128 1.8 m above the road
SIZES = {"box": (1.0, 1.0, 1.0), "vehicle": (4.5, 1.8, 1.5), "pedestrian": (0.3, 0.5, 1.75), "debris": (1.0, 0.2, 0.08)}


@pytest.fixture(scope="module")
def os1():
    return load_profile("os1_128_1024")


@pytest.fixture(scope="module")
def caster(os1):
    return ObstacleCaster(os1)


def _obstacle(kind, x=13.0, yaw=0.0, refl=0.5):
    return Box(x, 0.0, ROAD_Z, *SIZES[kind], yaw, refl, 1, OBJECT_ID_BASE, kind)


@pytest.mark.parametrize("kind", KINDS)
def test_meshes_fill_their_bounding_box_on_the_ground(kind):
    mesh, materials = obstacle_mesh(Box(0.0, 0.0, 0.0, *SIZES[kind], 0.0, 0.5, 1, 7, kind))
    lo, hi = mesh.vertices.min(axis=0), mesh.vertices.max(axis=0)
    length, width, height = SIZES[kind]
    assert hi[0] - lo[0] == pytest.approx(length, abs=0.01)  # a tread strip's slant adds < 1 cm
    assert hi[1] - lo[1] == pytest.approx(width, abs=1e-9) and hi[2] == pytest.approx(height, abs=1e-3)
    assert lo[2] == pytest.approx(0.0, abs=1e-9)  # standing on the road
    np.testing.assert_allclose(0.5 * (lo[:2] + hi[:2]), 0.0, atol=1e-3)  # centred on the ground contact
    assert {m.label for m in materials} == {Label.OBSTACLE} and set(mesh.object_id.tolist()) == {7}
    assert mesh.material.max() == len(materials) - 1


def test_a_car_is_the_simulators_car_with_its_paint_drawn():
    mesh, materials = obstacle_mesh(Box(0.0, 0.0, 0.0, *SIZES["vehicle"], 0.0, 0.2, 1, 7, "vehicle"))
    refl = {m.name: m.reflectivity for m in materials}
    assert refl["obstacle_7_car_paint"] == 0.2  # the drawn reflectivity
    assert refl["obstacle_7_tyre"] == pytest.approx(tyre_reflectivity())  # the others from materials.yaml
    assert max(m.retro_share for m in materials) > 0  # retro-reflective number plates


def _in_body(points, box):
    """Points in ``box``'s body frame (along, across, up; m)."""
    c, s = math.cos(box.yaw), math.sin(box.yaw)
    dx, dy = points["x"] - box.x, points["y"] - box.y
    return c * dx + s * dy, -s * dx + c * dy, points["z"] - box.z_bottom


def test_a_pedestrian_spans_its_height(caster):
    ped = _obstacle("pedestrian")
    p = caster.cast([ped], 0, 1)
    _, v, z = _in_body(p, ped)
    assert len(p) > 50 and set(p["label"].tolist()) == {Label.OBSTACLE}
    assert 1.6 < z.max() - z.min() <= 1.75 + 0.03  # 1.75 m tall, OS1-128 rings 8 cm apart at 13 m
    assert z.max() == pytest.approx(1.75, abs=0.05)
    assert 0.4 < v.max() - v.min() < 0.5 + 0.1  # 0.5 m wide, columns 8 cm apart at 13 m


def test_a_car_shows_its_rear_width_and_roof(caster):
    car = _obstacle("vehicle")
    p = caster.cast([car], 0, 1)
    u, v, z = _in_body(p, car)
    assert len(p) > 300
    assert v.max() - v.min() == pytest.approx(1.8, abs=0.1)
    assert z.max() == pytest.approx(1.5, abs=0.05)
    assert u.min() == pytest.approx(-2.25, abs=0.1)  # the rear face, 4.5 m / 2 behind the centre
    assert (p["epw"] > 0).all()


def test_tyre_debris_lies_flat_on_the_road(caster):
    strip = _obstacle("debris", yaw=math.pi / 2)  # 1 m across the lane
    p = caster.cast([strip], 0, 1)
    u, v, z = _in_body(p, strip)
    assert len(p) >= 3
    assert z.min() > -0.03 and z.max() < 0.08 + 0.03
    assert 0.7 < u.max() - u.min() < 1.0 + 0.1


@pytest.mark.parametrize("kind", ["vehicle", "pedestrian", "debris"])
def test_each_kind_inserted_by_the_augmenter_lies_in_its_own_box(os1, kind):
    """Every label-3 point of a frame lies in the mesh of its object id (within noise and one column)."""
    aug = ObstacleAugmenter(os1, objects=2, seed=21, kinds=(kind,))
    wall = empty_points(0)
    counts = []
    for frame in range(4):
        out, boxes = aug.frame(wall, frame, ROAD_Z)
        assert {b.kind for b in boxes} == {kind}
        obstacle = out[out["label"] == Label.OBSTACLE]
        assert set(obstacle["object_id"].tolist()) <= {b.object_id for b in boxes}
        for b in boxes:
            u, v, z = _in_body(obstacle[obstacle["object_id"] == b.object_id], b)
            tol = 0.2  # 5 cm range noise x 3 and a column at 20 m
            assert (np.abs(u) <= 0.5 * b.length + tol).all() and (np.abs(v) <= 0.5 * b.width + tol).all()
            assert ((z >= -tol) & (z <= b.height + tol)).all()
            counts.append(len(u))
    assert sum(counts) > (5 if kind == "debris" else 200)


def test_kinds_are_drawn_in_equal_shares_inside_the_roi_and_off_the_car_ahead(os1):
    roi, car = Roi.paper(), Footprint(17.0, 0.0, 0.0, 4.7, 1.85)
    aug = ObstacleAugmenter(os1, objects=1, seed=5, kinds=KINDS)
    seen = {}
    for _ in range(600):
        (b,) = aug.boxes(ROAD_Z, (car,))
        seen[b.object_id] = b
    shares = np.array([sum(b.kind == k for b in seen.values()) for k in KINDS]) / len(seen)
    assert np.abs(shares - 0.25).max() < 0.08
    for b in seen.values():
        c = b.footprint.corners()
        assert roi.contains(c[:, 0], c[:, 1]).all() and not footprints_overlap(b.footprint, car)
        (low, high) = kind_ranges(b.kind).dims_m
        assert all(lo <= d <= hi for lo, d, hi in zip(low, (b.length, b.width, b.height), high))
        lo, hi = kind_ranges(b.kind).reflectivity
        assert lo <= b.reflectivity <= hi


def test_ranges_come_from_the_tables():
    assert kind_ranges("debris").reflectivity == pytest.approx((0.5 * tyre_reflectivity(), 2 * tyre_reflectivity()))
    assert kind_ranges("box").dims_m == ((0.2,) * 3, (2.0,) * 3)
    assert kind_ranges("vehicle").durations == (1, 2, 3)


def test_boxes_alone_draw_what_they_always_drew(os1):
    """The default kind keeps the draws of the box-only augmenter (pinned from before kinds existed)."""
    (b,) = ObstacleAugmenter(load_profile("vlp16"), seed=3).boxes(-1.5)
    assert b.kind == "box"
    np.testing.assert_allclose([b.x, b.y, b.length, b.width, b.height, b.yaw, b.reflectivity],
                               PINNED_BOX, atol=1e-9)  # fmt: skip
    assert b.duration == PINNED_DURATION


def test_same_seed_same_output_with_every_kind(os1):
    def run(seed):
        aug = ObstacleAugmenter(os1, objects=2, seed=seed, kinds=KINDS)
        return [aug.frame(empty_points(0), i, ROAD_Z) for i in range(3)]

    a, b, c = run(4), run(4), run(5)
    for (pa, ba), (pb, bb) in zip(a, b):
        assert ba == bb
        np.testing.assert_array_equal(pa, pb)
    assert [x[1] for x in a] != [x[1] for x in c]


def test_an_unknown_kind_is_refused():
    assert parse_kinds("vehicle, Box,vehicle") == ("vehicle", "box")
    with pytest.raises(ObstacleError, match="unknown obstacle kind 'tank'"):
        parse_kinds("box,tank")
    with pytest.raises(ObstacleError, match="no kind given"):
        parse_kinds(",")
    with pytest.raises(ObstacleError, match="unknown obstacle kind"):
        ObstacleAugmenter(load_profile("vlp16"), kinds=("tank",))


# ObstacleAugmenter(vlp16, seed=3).boxes(-1.5) before kinds existed (commit cd9dcbb)
PINNED_BOX = (18.55791339200956, 5.0927833676937855, 1.6784388252154623, 1.703903530952321, 1.591331437279757,
              0.7693788987983228, 0.49071090881467294)  # fmt: skip
PINNED_DURATION = 1
