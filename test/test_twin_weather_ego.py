"""Twins that see through the weather (issue 51, item 3): the weather filter runs on every frame before meshing
(found by entry point, as the regions are), the sensor's own near-field structure becomes a fixed ego part of the
scenario instead of world mesh, and a derived profile's cover zone is what the recording shows."""

from __future__ import annotations

import json
import sys
from pathlib import Path

import numpy as np
import pydantic
import pytest
import yaml

from lidar_weather_sim.cli import main as cli_main
from lidar_weather_sim.core.config import ConfigError
from lidar_weather_sim.core.points import WEATHER_LABELS, Label
from lidar_weather_sim.io.recording import Recording
from lidar_weather_sim.scenario.schema import Scenario, load_scenario
from lidar_weather_sim.scenario.world import World
from lidar_weather_sim.scene.scene import MeshLoadError
from lidar_weather_sim.testing.bags import points_at
from lidar_weather_sim.twin import point_filter
from lidar_weather_sim.twin.ego_part import detect_ego_part, ego_part_mesh
from lidar_weather_sim.twin.point_filter import POINT_FILTERS_GROUP, choose_filter, filter_frames, registered_filters
from lidar_weather_sim.twin.profile_match import COVER_M, cover_zone, derive_profile

WORKSPACE = Path(__file__).resolve().parents[1]
OBJECT_LABELS = [int(Label.STATIC), int(Label.VEHICLE), int(Label.OBSTACLE)]


def _register(tmp_path: Path, monkeypatch, entries: dict[str, str]) -> None:
    """Entry points of :data:`POINT_FILTERS_GROUP` from a distribution installed on sys.path for this test only
    (the venv's metadata holds what its last ``colcon build`` registered)."""
    info = tmp_path / "ep" / "lws_test_point_filters-0.0.dist-info"
    info.mkdir(parents=True)
    (info / "METADATA").write_text("Metadata-Version: 2.1\nName: lws-test-point-filters\nVersion: 0.0\n")
    (info / "entry_points.txt").write_text(f"[{POINT_FILTERS_GROUP}]\n"
                                           + "".join(f"{k} = {v}\n" for k, v in entries.items()))  # fmt: skip
    monkeypatch.syspath_prepend(str(tmp_path / "ep"))


class _KeepSolid:
    """A frame filter that keeps the points not labelled weather, and records what it was given."""

    name = "oracle"

    def __init__(self) -> None:
        self.calls: list[int] = []
        self.resets = 0

    def keep(self, points):
        self.calls.append(len(points))
        return ~np.isin(points["label"], [int(x) for x in WEATHER_LABELS])

    def reset(self):
        self.resets += 1


def test_point_filters_are_found_by_entry_point(tmp_path, monkeypatch):
    module = tmp_path / "ep" / "lws_oracle_filter.py"
    module.parent.mkdir(parents=True)
    module.write_text("from test_twin_weather_ego_helpers import make\n")
    (tmp_path / "ep" / "test_twin_weather_ego_helpers.py").write_text(
        "import numpy as np\n"
        "class F:\n    name = 'oracle'\n    def keep(self, p):\n        return p['label'] < 10\n"
        "    def reset(self):\n        pass\n"
        "def make():\n    return F()\n")  # fmt: skip
    _register(tmp_path, monkeypatch, {"oracle": "lws_oracle_filter:make"})
    assert "oracle" in registered_filters()
    choice = choose_filter("oracle")
    assert choice.filter.name == "oracle" and choice.requested == "oracle"
    pts = points_at([[5.0, 0.0, 0.0], [0.6, 0.0, 0.0]], label=[int(Label.STATIC), int(Label.RAIN)])
    assert choice.filter.keep(pts).tolist() == [True, False]
    assert choose_filter("none").filter is None
    with pytest.raises(LookupError, match=r"--weather-filter nope: no package registers it .*oracle"):
        choose_filter("nope")
    monkeypatch.setattr(point_filter, "registered_filters", lambda: [])
    auto = choose_filter()
    assert auto.filter is None and "no weather filter installed" in auto.note
    sys.modules.pop("lws_oracle_filter", None)
    sys.modules.pop("test_twin_weather_ego_helpers", None)


def test_frames_are_filtered_after_their_previous_frame():
    filt = _KeepSolid()
    a = points_at([[5.0, 0.0, 0.0]] * 3, label=int(Label.STATIC))
    b = points_at([[5.0, 0.0, 0.0], [0.7, 0.0, 0.0]], label=[int(Label.STATIC), int(Label.SNOW)])
    masks, names = filter_frames(filt, [b, b], [a, None])
    assert [m.tolist() for m in masks] == [[True, False]] * 2 and names == ["oracle", "oracle"]
    assert filt.calls == [3, 2, 2] and filt.resets == 2  # frame 0 after its previous frame; frame 1 alone

    class Bad(_KeepSolid):
        def keep(self, points):
            return np.ones(1, bool)

    with pytest.raises(ValueError, match="keep mask of shape"):
        filter_frames(Bad(), [b], [None])


def test_weather_filter_registers_its_point_filter():
    """A fresh `make setup` (colcon build, rerun when a setup.py changes) registers the entry point."""
    text = (WORKSPACE / "src" / "weather_filter" / "setup.py").read_text()
    assert '"lidar_weather_sim.point_filters": ["weather = weather_filter.twin_filter:make"]' in text
    assert "setup.py" in (WORKSPACE / "scripts" / "setup.sh").read_text()


@pytest.fixture(scope="module")
def weather_bag(tmp_path_factory):
    """4 frames of the filter's held-out run (scala4; snow, fog, dirt on the cover, spray; never trained on)."""
    out = tmp_path_factory.mktemp("weather") / "bag"
    assert cli_main(["run", "wf_heldout_mixed", "--frames", "4", "--out", str(out)]) == 0
    return out


@pytest.fixture
def weather_filter_registered(tmp_path, monkeypatch):
    """The real registration when the venv has it, else the same entry point injected."""
    if "weather" not in registered_filters():
        _register(tmp_path, monkeypatch, {"weather": "weather_filter.twin_filter:make"})
    assert "weather" in registered_filters()


def test_the_weather_filter_removes_simulated_weather_before_meshing(weather_bag, weather_filter_registered):
    """The mesh's input (calibration frames 0 and 2) loses >= 90 % of the weather-labelled points and keeps >= 99 %
    of the road's, the cars' and the box's (measured: 99.9-100 % of 1026-1027 weather points removed, 99.5-99.7 %
    of 617-622 object points kept)."""
    from lidar_weather_sim.twin.command import load_input, weather_masks

    inp = load_input(weather_bag, split="frames")
    assert inp.point_filter.requested == "weather"
    used = inp.split.calibration_frames
    keeps, report = weather_masks(inp, used)
    assert report["ran"] == "learned (2 frames)"  # the EPW model: the simulated cloud has EPW and echoes
    for i, keep in zip(used, keeps):
        label = inp.recording.frames[i].points["label"]
        weather = np.isin(label, [int(x) for x in WEATHER_LABELS])
        solid = np.isin(label, OBJECT_LABELS)
        assert weather.sum() > 500 and solid.sum() > 500
        assert (~keep[weather]).mean() >= 0.90
        assert keep[solid].mean() >= 0.99
    assert report["points_removed"] == report["calibration_points"] - sum(int(k.sum()) for k in keeps)
    none = load_input(weather_bag, split="frames", weather_filter="none")
    keeps, report = weather_masks(none, used)
    assert all(k.all() for k in keeps) and report["points_removed"] == 0


def test_twin_says_which_filter_ran(weather_bag, weather_filter_registered, tmp_path, capsys):
    out = tmp_path / "twin"
    assert cli_main(["twin", str(weather_bag), "--split", "frames", "--out", str(out)]) == 0
    line = [ln for ln in capsys.readouterr().out.splitlines() if "weather:" in ln]
    assert len(line) == 1 and "learned (2 frames) removed" in line[0]
    report = json.loads((out / "report.json").read_text())
    assert report["weather_filter"]["requested"] == "weather" and report["weather_filter"]["points_removed"] > 1500
    assert cli_main(["twin", str(weather_bag), "--weather-filter", "nope", "--out", str(tmp_path / "t2")]) == 2
    assert "--weather-filter nope: no package registers it" in capsys.readouterr().err
    assert not (tmp_path / "t2").exists()


# -- the fixed ego part ---------------------------------------------------------------------------------------------


def _frames(positions, local_parts, world_parts, rng):
    local, world = [], []
    for p in positions:
        parts = [x + rng.normal(0.0, 0.01, x.shape) for x in local_parts]
        parts += [w - p + rng.normal(0.0, 0.01, w.shape) for w in world_parts]
        x = np.concatenate(parts)
        local.append(x)
        world.append(x + p)
    return local, world


def test_ego_part_detection_on_synthetic_frames():
    """A plate 0.4 m below the sensor that moves with it is the ego's (the other frames see the floor through its
    old places); a post 1 m from the sensor at the start, the floor, the far scene and a sensor that does not move
    far enough are not."""
    rng = np.random.default_rng(3)
    plate = np.stack([rng.uniform(0.3, 0.9, 400), rng.uniform(-0.3, 0.3, 400), np.full(400, -0.4)], axis=1)
    post = np.stack([np.full(50, 1.0), np.full(50, 0.4), rng.uniform(-0.5, 0.5, 50)], axis=1)
    gx, gy = np.meshgrid(np.arange(-4.0, 8.0, 0.05), np.arange(-2.0, 2.0, 0.05))
    floor = np.stack([gx.ravel(), gy.ravel(), np.full(gx.size, -1.5)], axis=1)
    scene = np.concatenate([rng.uniform(-30.0, 30.0, (3000, 3)), floor])
    driving = np.stack([np.linspace(0.0, 4.0, 10), np.zeros(10), np.zeros(10)], axis=1)
    local, world = _frames(driving, [plate], [post, scene], rng)
    found = detect_ego_part(local, world, driving)
    assert found.travel_m == pytest.approx(4.0)
    for mask in found.masks:
        assert mask[:400].all() and not mask[400:].any()  # every plate point, no post or scene point
    assert found.points == 4000 and 144 <= len(found.voxels) <= 2 * 144 + 50  # 12 x 12 voxels, on two levels and "fixed ego part" in found.note
    centres = (found.voxels + 0.5) * 0.05
    assert np.all(np.abs(centres[:, 2] + 0.4) <= 0.1) and np.all((centres[:, 0] > 0.2) & (centres[:, 0] < 1.0))
    vertices, triangles, reflectivity = ego_part_mesh(found.voxels, np.full(len(found.voxels), 0.3))
    assert len(triangles) == len(reflectivity) > 0 and np.all(np.linalg.norm(vertices, axis=1) < 1.2)

    parked = driving[:, :] * np.array([0.4, 1, 1])  # 1.6 m: not more than 2 m
    local, world = _frames(parked, [plate], [post, scene], rng)
    none = detect_ego_part(local, world, parked)
    assert none.points == 0 and "no ego part looked for" in none.note

    # a flat road under a sensor driving straight stays at one sensor-frame place too, but is seen from afar
    road_local = np.stack([rng.uniform(-1.5, 1.5, 600), rng.uniform(-1.0, 1.0, 600), np.full(600, -1.0)], axis=1)
    road_far = np.stack([rng.uniform(-3.0, 7.0, 20000), rng.uniform(-1.0, 1.0, 20000), np.full(20000, -1.0)], axis=1)
    local, world = _frames(driving, [plate, road_local], [], rng)
    far = [w - p for w, p in zip([road_far] * len(driving), driving)]
    local = [np.concatenate([x, f[np.linalg.norm(f, axis=1) >= 2.0]]) for x, f in zip(local, far)]
    world = [x + p for x, p in zip(local, driving)]
    road = detect_ego_part(local, world, driving)
    assert all(m[:400].all() and not m[400:1000].any() for m in road.masks)  # the plate only
    assert "the other frames see the world there" in road.note


def _room_with_a_part(tmp_path: Path) -> Scenario:
    """A 16 m room, a VLP-16 driving 4 m through it with a plate on its mount 1 m ahead, 0.2 m below."""
    import trimesh

    room = trimesh.creation.box(extents=(16.0, 16.0, 4.0))
    room.apply_translation((0.0, 0.0, 1.0))
    room.export(tmp_path / "room.ply")
    trajectory = [{"t_s": 0.0, "x_m": -2.0, "y_m": 0.0, "z_m": 0.0}, {"t_s": 1.0, "x_m": 2.0, "y_m": 1.0, "z_m": 0.0}]
    return Scenario.model_validate({
        "name": "room", "map": None, "static_meshes": [str(tmp_path / "room.ply")], "duration_s": 1.0,
        "sensor": {"profile": "vlp16", "mount": {"x_m": 0.0, "y_m": 0.0, "z_m": 0.0},
                   "fixed_parts": [{"box": {"x_m": 1.0, "y_m": 0.0, "z_m": -0.2, "length_m": 0.4, "width_m": 0.6,
                                            "height_m": 0.1}}]},
        "trajectory": trajectory})  # fmt: skip


def _on_plate(points) -> np.ndarray:
    return ((np.abs(points["x"] - 1.0) < 0.25) & (np.abs(points["y"]) < 0.35) & (points["z"] < -0.1)
            & (points["z"] > -0.3))  # fmt: skip


def test_the_twin_writes_the_ego_part_into_its_scenario(tmp_path, capsys):
    """Recorded with a plate on the sensor: the twin's mesh holds the room, not the plate smeared along the path;
    its scenario carries the plate as a fixed part, loads, and re-simulates the plate's returns where they were."""
    from lidar_weather_sim.sim.offline import run_scenario
    from lidar_weather_sim.sim.simulator import LidarSimulator
    from lidar_weather_sim.twin.reconstruct import distances_to_mesh
    from lidar_weather_sim.scene.surveyed import read_surveyed_faces

    assert run_scenario(_room_with_a_part(tmp_path), tmp_path / "bag", frames=8).frames == 8
    rec = Recording.load(tmp_path / "bag")
    recorded = [int(_on_plate(f.points).sum()) for f in rec.frames]
    assert min(recorded) > 500 and all(np.all(f.points["object_id"][_on_plate(f.points)] == 2) for f in rec.frames)

    out = tmp_path / "twin"
    assert cli_main(["twin", str(tmp_path / "bag"), "--weather-filter", "none", "--out", str(out)]) == 0
    printed = capsys.readouterr().out
    assert "weather: no weather filter (--weather-filter none)" in printed and "ego part:" in printed
    report = json.loads((out / "report.json").read_text())
    ego = report["ego_part"]
    assert ego["file"] == "ego_part.ply" and ego["sensor_travel_m"] > 2.0
    calibration = report["split"]["frames_used_for_mesh"]
    assert ego["points"] == pytest.approx(sum(recorded[i] for i in calibration), rel=0.01)  # the plate's points

    scenario = load_scenario(out / "scenario.yaml")  # round trip through the loader
    assert [p.mesh for p in scenario.sensor.fixed_parts] == [str((out / "ego_part.ply").resolve())]
    assert read_surveyed_faces(out / "ego_part.ply") is not None

    import trimesh

    mesh = trimesh.load(out / "mesh.ply", force="mesh", process=False)
    from lidar_weather_sim.twin.poses import twin_poses, points_in_map

    poses = twin_poses(rec)
    plate_world = np.concatenate([points_in_map(rec, i, poses)[0][_on_plate(rec.frames[i].points)] for i in calibration])
    d = distances_to_mesh(np.asarray(mesh.vertices), np.asarray(mesh.faces), plate_world)
    assert np.mean(d > 0.1) >= 0.9  # the world mesh does not hold the plate

    world = World.build(scenario)
    sim = LidarSimulator.of_world(world, regions=[])
    frame = sim.cast_frame(7, 0.7, world.player)
    assert abs(int(_on_plate(frame.points).sum()) - recorded[7]) <= 0.1 * recorded[7]


def test_fixed_parts_are_checked(tmp_path):
    base = {"name": "t", "map": None, "static_meshes": ["room.ply"]}
    box = {"x_m": 1.0, "y_m": 0.0, "z_m": -0.2, "length_m": 0.4, "width_m": 0.6, "height_m": 0.1}
    with pytest.raises(pydantic.ValidationError, match="exactly one of 'mesh'"):
        Scenario.model_validate({**base, "sensor": {"fixed_parts": [{}]}})
    with pytest.raises(pydantic.ValidationError, match="exactly one of 'mesh'"):
        Scenario.model_validate({**base, "sensor": {"fixed_parts": [{"mesh": "a.ply", "box": box}]}})
    with pytest.raises(pydantic.ValidationError, match="length_m"):
        Scenario.model_validate({**base, "sensor": {"fixed_parts": [{"box": {**box, "length_m": -1.0}}]}})
    scenario = _room_with_a_part(tmp_path)
    bad = scenario.model_copy(update={"sensor": scenario.sensor.model_copy(update={"fixed_parts": [
        scenario.sensor.fixed_parts[0].model_copy(update={"material": "cheese"})]})})  # fmt: skip
    with pytest.raises(ConfigError, match=r"sensor.fixed_parts\[0\]: unknown material 'cheese'"):
        World.build(bad)
    missing = Scenario.model_validate({**scenario.model_dump(), "sensor": {"fixed_parts": [{"mesh": str(tmp_path / "no.ply")}]}})
    with pytest.raises(MeshLoadError, match="no.ply: cannot read mesh: no such file"):
        World.build(missing)


# -- the cover zone of a derived profile ----------------------------------------------------------------------------


def _ring_frame(near: list[float]) -> np.ndarray:
    """A 24-channel sensor nobody ships (-11.5..11.5 deg), 360 columns, a wall 10 m away, plus returns at ``near``
    (m) in channel 3."""
    elevation = np.radians(np.arange(-11.5, 12.0, 1.0))
    azimuth = np.radians(np.arange(-180.0, 180.0, 1.0) + 0.5)
    e, a = np.meshgrid(elevation, azimuth, indexing="ij")
    channel = np.repeat(np.arange(24), 360)
    xyz = 10.0 * np.stack([np.cos(e) * np.cos(a), np.cos(e) * np.sin(a), np.sin(e)], axis=-1).reshape(-1, 3)
    near_xyz = [[r * np.cos(elevation[3]) * np.cos(0.1 * k), r * np.cos(elevation[3]) * np.sin(0.1 * k),
                 r * np.sin(elevation[3])] for k, r in enumerate(near)]  # fmt: skip
    return points_at(np.concatenate([xyz, np.reshape(near_xyz, (-1, 3))]),
                     channel=np.concatenate([channel, np.full(len(near), 3)]))  # fmt: skip


def test_a_derived_profile_takes_its_cover_zone_from_the_recording():
    """The nearest shipped profile by channels (vlp16) reports from 0.3 m; the derived one from what
    the recording shows: its nearest return below 0.5 m, or nothing below 0.5 m when it shows none there."""
    with_cover = [_ring_frame([0.27, 0.33, 0.41]), _ring_frame([0.36])]
    profile = derive_profile(with_cover[0], 10.0, frames=with_cover)
    assert len(profile.beams) == 24 and profile.range.min_m == pytest.approx(0.27)
    assert "minimum range (0.27 m" in profile.source
    zone = cover_zone(with_cover, profile)
    assert zone["returns"] == 4 and zone["nearest_m"] == pytest.approx(0.27, abs=1e-3)
    assert zone["beams_with_return_share"] == pytest.approx(4 / (2 * 24 * profile.scan.columns))
    clean = [_ring_frame([])]
    assert derive_profile(clean[0], 10.0, frames=clean).range.min_m == COVER_M
    assert cover_zone(clean, profile)["returns"] == 0 and cover_zone(clean, profile)["nearest_m"] is None
