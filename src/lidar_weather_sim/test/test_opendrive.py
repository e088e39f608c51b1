"""OpenDRIVE reader and road mesh: lane poses, curve geometry, surface, markings, rails, errors."""

import time
import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np
import pytest
from scipy.spatial import cKDTree

from lidar_weather_sim.scene.materials import MaterialTable
from lidar_weather_sim.scene.opendrive import OpenDriveError, RoadNetwork

MAPS = Path(__file__).resolve().parents[3] / "maps"
HIGHWAY = MAPS / "highway_straight.xodr"
CURVE = MAPS / "curved_road.xodr"


@pytest.fixture(scope="module")
def materials():
    return MaterialTable.default()


@pytest.fixture(scope="module")
def highway():
    return RoadNetwork.from_xodr(HIGHWAY)


@pytest.fixture(scope="module")
def curve():
    return RoadNetwork.from_xodr(CURVE)


def _geometries(path):
    return ET.parse(path).getroot().findall("road/planView/geometry")


def _xodr(tmp_path, body: str, name: str = "t.xodr") -> Path:
    """A one-road file; ``body`` is the content of <road> (planView, lanes, ...)."""
    path = tmp_path / name
    path.write_text(f'<?xml version="1.0"?><OpenDRIVE><header revMajor="1" revMinor="6"/>{body}</OpenDRIVE>')
    return path


def _lanes(right="3.5", left=None, marks="", extra=""):
    left_xml = f'<left><lane id="1" type="driving"><width sOffset="0" a="{left}" b="0" c="0" d="0"/></lane></left>' if left else ""
    return (f'<lanes><laneSection s="0">{left_xml}<center><lane id="0" type="none">{marks}</lane></center>'
            f'<right><lane id="-1" type="driving"><width sOffset="0" a="{right}" b="0" c="0" d="0"/></lane>'
            f'{extra}</right></laneSection></lanes>')  # fmt: skip


# ---------------------------------------------------------------- lane poses
def test_highway_lane_centres_and_headings(highway):
    assert highway.road_length("1") == 1000.0
    assert highway.lane_ids("1") == [-4, -3, -2, -1, 1]
    s = np.array([0.0, 250.5, 999.0])
    # lane -1: 0 .. -3.75, lane -2: -3.75 .. -7.5, lane -3: -7.5 .. -11.25, shoulder -11.25 .. -13.75
    for lane, y_expected in ((-1, -1.875), (-2, -5.625), (-3, -9.375), (-4, -12.5)):
        x, y, z, heading = highway.lane_pose("1", lane, s)
        np.testing.assert_allclose(x, s, atol=1e-9)
        np.testing.assert_allclose(y, y_expected, atol=1e-9)
        np.testing.assert_allclose(z, 0.0, atol=1e-12)
        np.testing.assert_allclose(heading, 0.0, atol=1e-12)
    # left lane (inner edge strip 0 .. 0.75): drives against s in right-hand traffic
    x, y, _, heading = highway.lane_pose("1", 1, 10.0)
    assert (float(x), float(y)) == pytest.approx((10.0, 0.375))
    assert abs(float(heading)) == pytest.approx(np.pi)
    assert float(highway.lane_pose("1", 1, 10.0, along_reference=True)[3]) == pytest.approx(0.0)
    np.testing.assert_allclose(highway.lane_width("1", -2, s), 3.75)


def test_lane_pose_rejects_bad_queries(highway):
    with pytest.raises(ValueError, match="outside"):
        highway.lane_pose("1", -1, 1000.5)
    with pytest.raises(KeyError, match="no lane -7"):
        highway.lane_pose("1", -7, 1.0)
    with pytest.raises(KeyError, match="no road '9'"):
        highway.lane_pose("9", -1, 1.0)


def test_lane_pose_with_a_lane_per_s_equals_one_call_per_lane(curve, highway):
    for net, lanes in ((curve, [-1, 1]), (highway, [-1, -2, -3, 1])):
        rng = np.random.default_rng(0)
        s = rng.uniform(0.0, net.road_length("1"), 40)
        lane = rng.choice(lanes, 40)
        for along in (False, True):
            together = net.lane_pose("1", lane, s, along_reference=along)
            for lid in lanes:
                alone = net.lane_pose("1", lid, s[lane == lid], along_reference=along)
                for a, b in zip(together, alone):
                    assert a[lane == lid].tobytes() == b.tobytes()  # the same values to the bit


def test_arc_lane_centres_at_radius_with_tangent_heading(curve):
    arc = next(g for g in _geometries(CURVE) if g.find("arc") is not None)
    s0, x0, y0, h0, length = (float(arc.get(k)) for k in ("s", "x", "y", "hdg", "length"))
    radius = 1.0 / float(arc.find("arc").get("curvature"))
    centre = np.array([x0 - radius * np.sin(h0), y0 + radius * np.cos(h0)])  # left-hand curve
    s = np.linspace(s0, s0 + length, 57)
    for lane, r_expected in ((-1, radius + 1.75), (1, radius - 1.75)):
        x, y, _, heading = curve.lane_pose("1", lane, s, along_reference=True)
        r = np.hypot(x - centre[0], y - centre[1])
        assert np.abs(r - r_expected).max() < 0.01
        tangent = np.arctan2(y - centre[1], x - centre[0]) + np.pi / 2
        assert np.abs(np.angle(np.exp(1j * (heading - tangent)))).max() < 1e-9
    # driving direction of lane 1 is reversed
    h_left = curve.lane_pose("1", 1, s)[3]
    h_right = curve.lane_pose("1", -1, s)[3]
    np.testing.assert_allclose(np.cos(h_left - h_right), -1.0, atol=1e-12)


def test_spiral_curvature_is_linear_in_s(curve):
    spiral = next(g for g in _geometries(CURVE) if g.find("spiral") is not None)
    s0, length = float(spiral.get("s")), float(spiral.get("length"))
    k0, k1 = (float(spiral.find("spiral").get(k)) for k in ("curvStart", "curvEnd"))
    s = np.linspace(s0, s0 + length, 6001)
    x, y, _, heading = curve.reference_pose("1", s)
    ds = s[1] - s[0]
    # curvature from the positions alone (independent of the heading formula)
    dx, dy = np.gradient(x, ds), np.gradient(y, ds)
    ddx, ddy = np.gradient(dx, ds), np.gradient(dy, ds)
    k_pos = (dx * ddy - dy * ddx) / np.hypot(dx, dy) ** 3
    k_lin = k0 + (k1 - k0) * (s - s0) / length
    assert np.abs(k_pos - k_lin)[2:-2].max() < 1e-6
    fit = np.polyfit(s, np.gradient(np.unwrap(heading), ds), 2)
    assert abs(fit[0]) < 1e-9 and fit[1] == pytest.approx((k1 - k0) / length, rel=1e-4)
    # positions agree with numerical integration of the heading
    xi = x[0] + np.concatenate([[0.0], np.cumsum(0.5 * ds * (np.cos(heading[1:]) + np.cos(heading[:-1])))])
    yi = y[0] + np.concatenate([[0.0], np.cumsum(0.5 * ds * (np.sin(heading[1:]) + np.sin(heading[:-1])))])
    assert np.hypot(xi - x, yi - y).max() < 1e-6


def test_curved_map_geometries_join_without_gaps(curve):
    for g in _geometries(CURVE):
        s = float(g.get("s"))
        if s == 0.0:
            continue
        x, y, _, heading = curve.reference_pose("1", s - 1e-9)
        assert np.hypot(float(x) - float(g.get("x")), float(y) - float(g.get("y"))) < 1e-6
        assert float(heading) == pytest.approx(float(g.get("hdg")), abs=1e-9)


def test_sampling_is_finer_on_tight_curves(tmp_path):
    body = ('<road id="7" length="100"><planView><geometry s="0" x="0" y="0" hdg="0" length="50"><line/></geometry>'
            '<geometry s="50" x="50" y="0" hdg="0" length="50"><arc curvature="0.02"/></geometry></planView>'
            f"{_lanes()}</road>")  # fmt: skip
    net = RoadNetwork.from_xodr(_xodr(tmp_path, body))
    s = net.sample_s("7")
    step = np.diff(s)
    assert step[s[:-1] < 50].max() <= 1.0 + 1e-9
    assert step[s[:-1] >= 50].max() <= 0.005 / 0.02 + 1e-9  # heading change per step <= 0.005 rad
    assert s[0] == 0 and s[-1] == 100 and 50.0 in s


def test_elevation_superelevation_and_poly_geometries(tmp_path):
    body = ('<road id="e" length="100"><planView>'
            '<geometry s="0" x="0" y="0" hdg="0" length="50"><paramPoly3 aU="0" bU="50" cU="0" dU="0" '
            'aV="0" bV="0" cV="0" dV="0" pRange="normalized"/></geometry>'
            '<geometry s="50" x="50" y="0" hdg="0" length="50"><poly3 a="0" b="0" c="0.004" d="0"/></geometry>'
            '</planView><elevationProfile><elevation s="0" a="1" b="0.02" c="0" d="0"/></elevationProfile>'
            '<lateralProfile><superelevation s="0" a="0.05" b="0" c="0" d="0"/></lateralProfile>'
            f"{_lanes()}</road>")  # fmt: skip
    net = RoadNetwork.from_xodr(_xodr(tmp_path, body))
    x, y, z, h = net.reference_pose("e", np.array([25.0, 50.0]))
    np.testing.assert_allclose([x, y, z], [[25, 50], [0, 0], [1.5, 2.0]], atol=1e-9)
    # superelevation rolls the cross-section about the reference line: the right lane dips
    _, y1, z1, _ = net.lane_pose("e", -1, 25.0)
    assert float(y1) == pytest.approx(-1.75 * np.cos(0.05))
    assert float(z1) == pytest.approx(1.5 - 1.75 * np.sin(0.05))
    # the poly3 part is arc-length parametrised: 50 m of s are 50 m of path
    s = np.linspace(50.0, 100.0, 5001)
    x, y, _, _ = net.reference_pose("e", s)
    assert np.hypot(np.diff(x), np.diff(y)).sum() == pytest.approx(50.0, abs=1e-3)
    u = x[-1] - 50.0
    assert float(y[-1]) == pytest.approx(0.004 * u * u, abs=1e-6)  # end point lies on v = c u^2


# ---------------------------------------------------------------- mesh
def _part(mesh, names, word):
    oids = [i for i, n in names.items() if word in n]
    return np.isin(mesh.object_id, oids)


def _area(mesh, sel):
    v = mesh.vertices[mesh.triangles[sel]]
    return 0.5 * np.linalg.norm(np.cross(v[:, 1] - v[:, 0], v[:, 2] - v[:, 0]), axis=1).sum()


@pytest.fixture(scope="module")
def highway_mesh(highway, materials):
    names = {}
    return highway.to_mesh(materials, names=names), names


def test_highway_surface_faces_up_and_has_the_right_area(highway_mesh, materials):
    mesh, names = highway_mesh
    surface = _part(mesh, names, "surface")
    assert np.all(mesh.material[surface] == materials.index("asphalt_dry"))
    assert mesh.face_normals[surface, 2].min() > 0.99
    width = 0.75 + 3 * 3.75 + 2.5  # border strip + 3 lanes + hard shoulder
    assert _area(mesh, surface) == pytest.approx(1000.0 * width, rel=0.005)
    v = mesh.vertices[mesh.triangles[surface]].reshape(-1, 3)
    assert v[:, 1].min() == pytest.approx(-13.75) and v[:, 1].max() == pytest.approx(0.75)


def test_curved_surface_area_per_lane(curve, materials):
    names = {}
    mesh = curve.to_mesh(materials, names=names)
    surface = _part(mesh, names, "surface")
    assert mesh.face_normals[surface, 2].min() > 0.99
    assert _area(mesh, surface) == pytest.approx(520.0 * 7.0, rel=0.005)
    # the outer (right) lane of the left-hand curve: 3.5 L + 3.5^2 / 2 * total heading change (1.3 rad)
    s = np.linspace(0, 520, 52001)
    x, y, _, h = curve.reference_pose("1", s)
    centroid = mesh.vertices[mesh.triangles[surface]].mean(axis=1)
    i = cKDTree(np.column_stack([x, y])).query(centroid[:, :2])[1]
    t = (centroid[:, 0] - x[i]) * -np.sin(h[i]) + (centroid[:, 1] - y[i]) * np.cos(h[i])
    right = surface.copy()
    right[surface] = t < 0
    assert _area(mesh, right) == pytest.approx(3.5 * 520 + 0.5 * 3.5**2 * 1.3, rel=1e-3)


def test_highway_markings(highway_mesh, materials):
    mesh, names = highway_mesh
    marks = _part(mesh, names, "marking")
    assert np.all(mesh.material[marks] == materials.index("lane_marking"))
    assert materials["lane_marking"].retro_share > 0
    v = mesh.vertices[mesh.triangles[marks]]
    np.testing.assert_allclose(v[..., 2], 0.002, atol=1e-12)  # 2 mm above the flat road
    assert mesh.face_normals[marks, 2].min() > 0.99
    centroid_y = v[..., 1].mean(axis=1)
    # broken 0.15 m lane line at t = -3.75: 6 m line / 12 m gap from the file -> 56 dashes of 6 m
    lane_line = marks.copy()
    lane_line[marks] = np.abs(centroid_y + 3.75) < 0.2
    assert _area(mesh, lane_line) == pytest.approx(56 * 6.0 * 0.15, rel=1e-6)
    yv = mesh.vertices[mesh.triangles[lane_line]][..., 1]
    assert yv.min() == pytest.approx(-3.825) and yv.max() == pytest.approx(-3.675)
    # solid 0.30 m edge line at t = -11.25 over the whole length
    edge = marks.copy()
    edge[marks] = np.abs(centroid_y + 11.25) < 0.2
    assert _area(mesh, edge) == pytest.approx(1000.0 * 0.30, rel=1e-6)


def test_default_broken_pattern_is_3_on_9(curve, materials):
    names = {}
    mesh = curve.to_mesh(materials, names=names)
    marks = _part(mesh, names, "marking")
    total = _area(mesh, marks)
    # centre line: ceil(520 / 12) = 44 dashes of 3 m, 0.12 m wide; two solid 0.12 m edge lines
    # along t = +-3.5 (length (1 -+ k t) ds integrated: 520 -+ 3.5 * 1.3)
    expected = 44 * 3.0 * 0.12 + 0.12 * (520 - 3.5 * 1.3) + 0.12 * (520 + 3.5 * 1.3)
    assert total == pytest.approx(expected, rel=1e-3)


def test_guard_rails(highway_mesh, materials):
    mesh, names = highway_mesh
    rail_ids = [i for i, n in names.items() if "guard rail" in n]
    assert len(rail_ids) == 2
    for oid, y_face in zip(rail_ids, (1.25, -14.25)):
        sel = mesh.object_id == oid
        assert np.all(mesh.material[sel] == materials.index("guard_rail"))
        v = mesh.vertices[mesh.triangles[sel]].reshape(-1, 3)
        assert v[:, 2].max() == pytest.approx(0.9) and v[:, 2].min() == pytest.approx(0.0)  # posts on the ground
        beam = v[np.abs(v[:, 1] - y_face) < 1e-9]  # road-facing face of the W-beam
        assert beam[:, 2].min() == pytest.approx(0.6) and beam[:, 2].max() == pytest.approx(0.9)
        assert beam[:, 0].min() == pytest.approx(0.0) and beam[:, 0].max() == pytest.approx(1000.0)
        # posts every 2 m behind the beam: count the distinct post bottoms
        bottoms = v[v[:, 2] == 0.0]
        assert len(np.unique(np.round(bottoms[:, 0], 6))) == 2 * 500
        assert np.all(np.abs(bottoms[:, 1]) > abs(y_face))  # behind the beam, away from the road
        # the road-facing side of the beam faces the road
        tri = mesh.triangles[sel]
        face = np.all(np.abs(mesh.vertices[tri][..., 1] - y_face) < 1e-9, axis=1)
        assert np.all(np.sign(mesh.face_normals[sel][face, 1]) == -np.sign(y_face))


def test_object_ids_and_labels(highway_mesh, materials):
    mesh, names = highway_mesh
    assert sorted(names) == sorted(np.unique(mesh.object_id).tolist()) == [1, 2, 3, 4]
    assert len(set(names.values())) == 4
    assert set(materials.labels[mesh.material].tolist()) == {1}  # Label.STATIC


def test_highway_mesh_builds_fast(highway, materials):
    start = time.perf_counter()
    highway.to_mesh(materials)
    assert time.perf_counter() - start < 0.5


def test_other_guard_rail_forms(tmp_path, materials):
    plan = '<planView><geometry s="0" x="0" y="0" hdg="0" length="100"><line/></geometry></planView>'
    objects = ('<objects>'
               '<object id="a" type="barrier" name="guardRail" s="10" t="-5" zOffset="0" height="0.75">'
               '<outline><cornerRoad s="10" t="-5" dz="0" height="0.75"/><cornerRoad s="30" t="-6" dz="0" '
               'height="0.75"/></outline></object>'
               '<object id="b" type="barrier" name="guardRail" s="50" t="-5" zOffset="0.6" height="0.3" hdg="0">'
               '<outline><cornerLocal u="-5" v="0" z="0" height="0"/><cornerLocal u="5" v="0" z="0" height="0"/>'
               '</outline></object>'
               '<object id="c" type="barrier" name="jersey" s="50" t="5" length="10"/>'
               '</objects><userData code="guardRail" value="left" offset="0.25"/>')  # fmt: skip
    net = RoadNetwork.from_xodr(_xodr(tmp_path, f'<road id="r" length="100">{plan}{_lanes(left="3.5")}{objects}</road>'))
    names = {}
    mesh = net.to_mesh(materials, names=names)
    rails = {n: mesh.vertices[mesh.triangles[mesh.object_id == i]].reshape(-1, 3) for i, n in names.items() if "rail" in n}
    assert len(rails) == 3  # the jersey barrier is not a guard rail
    a, b = rails["road r guard rail a"], rails["road r guard rail b"]
    edge = rails["road r left edge guard rail"]
    # cornerRoad: zOffset 0 + height 0.75 -> beam 0.45 .. 0.75, from (10, -5) to (30, -6)
    assert a[:, 2].max() == pytest.approx(0.75) and a[:, 0].min() == pytest.approx(10.0, abs=0.02)  # sloped ends
    assert np.isin(np.round(a[:, 1], 9), [-5.0]).any() and a[:, 1].min() < -6.0
    assert np.unique(np.round(a[:, 2], 9)).tolist() == [0.0, 0.45, 0.75]  # post bottoms, beam bottom and top
    # cornerLocal around (50, -5) +-5 m; height 0 -> default beam 0.6 .. 0.9
    assert b[:, 0].min() == pytest.approx(45.0) and b[:, 0].max() == pytest.approx(55.0)
    assert b[:, 2].max() == pytest.approx(0.9)
    # road-edge rail: outer border of lane 1 (3.5) + offset 0.25
    assert edge[:, 1].min() == pytest.approx(3.75)
    assert edge[:, 0].min() == pytest.approx(0.0) and edge[:, 0].max() == pytest.approx(100.0)


def test_lane_sections_and_width_changes(tmp_path):
    plan = '<planView><geometry s="0" x="0" y="0" hdg="0" length="200"><line/></geometry></planView>'
    lanes = ('<lanes><laneSection s="0"><center><lane id="0"/></center><right>'
             '<lane id="-1" type="driving"><width sOffset="0" a="3" b="0" c="0" d="0"/>'
             '<width sOffset="50" a="3" b="0" c="0.0024" d="-0.000032"/><width sOffset="100" a="3.5" b="0" c="0" d="0"/>'
             '</lane></right></laneSection><laneSection s="150"><center><lane id="0"/></center><right>'
             '<lane id="-1" type="driving"><width sOffset="0" a="3.5" b="0" c="0" d="0"/></lane>'
             '<lane id="-2" type="shoulder"><width sOffset="0" a="2" b="0" c="0" d="0"/></lane>'
             '</right></laneSection></lanes>')  # fmt: skip
    net = RoadNetwork.from_xodr(_xodr(tmp_path, f'<road id="w" length="200">{plan}{lanes}</road>'))
    assert net.lane_ids("w") == [-2, -1]
    np.testing.assert_allclose(net.lane_width("w", -1, [10, 100, 120, 160]), [3, 3.5, 3.5, 3.5], atol=1e-9)
    assert float(net.lane_pose("w", -2, 170.0)[1]) == pytest.approx(-4.5)
    with pytest.raises(KeyError, match="no lane -2"):
        net.lane_pose("w", -2, [100.0, 170.0])
    # widening lane centre heads slightly to the right (dt/ds < 0) mid-transition
    assert float(net.lane_pose("w", -1, 75.0)[3]) < -1e-3


# ---------------------------------------------------------------- errors
@pytest.mark.parametrize(
    "body, expected",
    [
        ('<road id="1" length="10"><planView><geometry s="0" x="0" y="0" length="10"><line/></geometry>'
         '</planView></road>', "element road[id=1]/planView/geometry[1]: missing attribute 'hdg'"),
        ('<road id="1" length="10"><planView><geometry s="0" x="0" y="0" hdg="0" length="10"><clothoid/>'
         '</geometry></planView></road>', "element road[id=1]/planView/geometry[1]: expected one of"),
        ('<road id="1" length="10"><planView><geometry s="0" x="0" y="0" hdg="zero" length="10"><line/>'
         '</geometry></planView></road>', "attribute 'hdg'='zero' is not a number"),
        ('<road id="2" length="10"><planView><geometry s="0" x="0" y="0" hdg="0" length="10"><line/></geometry>'
         '</planView><lanes><laneSection s="0"><center><lane id="0"/></center><right><lane id="-1">'
         '<border sOffset="0" a="3" b="0" c="0" d="0"/></lane></right></laneSection></lanes></road>',
         "element road[id=2]/lanes/laneSection[1]/right/lane[1]: lane -1 has no <width> (<border> is not supported"),
        ('<road id="3" length="10"><planView><geometry s="0" x="0" y="0" hdg="0" length="10"><line/></geometry>'
         '</planView><lanes><laneSection s="0"><center><lane id="0"/></center><right><lane id="1">'
         '<width sOffset="0" a="3" b="0" c="0" d="0"/></lane></right></laneSection></lanes></road>',
         "right/lane[1]: lane id 1 does not belong in <right>"),
        ('<road id="4" length="10"><planView><geometry s="0" x="0" y="0" hdg="0" length="10"><line/></geometry>'
         f'</planView>{_lanes()}<objects><object id="g" type="barrier" name="guardRail" s="0" t="2"/></objects></road>',
         "element road[id=4]/objects/object[1]: guard rail object has no <repeat>"),
        ("", "element OpenDRIVE: no <road>"),
        ('<road id="1" length="10"><planView><geometry', "not well-formed XML"),
    ],
)
def test_bad_xodr_names_file_and_element(tmp_path, body, expected):
    path = _xodr(tmp_path, body, "broken_map.xodr")
    with pytest.raises(OpenDriveError) as err:
        RoadNetwork.from_xodr(path)
    assert str(path) in str(err.value)
    assert expected in str(err.value)


def test_missing_file_is_named(tmp_path):
    with pytest.raises(OpenDriveError, match="nope.xodr: cannot read"):
        RoadNetwork.from_xodr(tmp_path / "nope.xodr")
