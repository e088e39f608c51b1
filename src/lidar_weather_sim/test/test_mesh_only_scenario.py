"""Mesh-only scenarios (``map: null``): schema, ``cache:`` mesh paths, World, casting from external poses,
and ``run`` refusing them. The real street (config/scenarios/ouster_street.yaml) needs the mesh that
``make setup`` imports into ``.venv/cache/ouster_real``; those tests skip without it."""

import numpy as np
import pydantic
import pytest
import trimesh

from lidar_weather_sim.cli import main as cli_main
from lidar_weather_sim.core.paths import cache_dir, resolve_data_path
from lidar_weather_sim.scenario.player import NoEgoError
from lidar_weather_sim.scenario.schema import Scenario, load_scenario
from lidar_weather_sim.scenario.world import World
from lidar_weather_sim.sim.simulator import LidarSimulator

STREET_MESH = "ouster_real/os1_128_street_mesh.ply"
STREET_BAG = "ouster_real/os1_128_street"


class FixedPose:
    """An external pose source: the sensor at ``xyz`` (map, m), axes along the map's, no actors."""

    def __init__(self, xyz) -> None:
        self.xyz = np.asarray(xyz, dtype=np.float64)

    def sensor_poses(self, times_s):
        n = len(np.atleast_1d(times_s))
        return np.tile(self.xyz, (n, 1)), np.tile([0.0, 0.0, 0.0, 1.0], (n, 1))

    def actor_poses(self, time_s):
        return {}


@pytest.fixture(scope="module")
def room(tmp_path_factory) -> str:
    """A closed 20 x 20 x 6 m box (normals inwards do not matter to the caster) as a PLY."""
    path = tmp_path_factory.mktemp("mesh") / "room.ply"
    box = trimesh.creation.box(extents=(20.0, 20.0, 6.0))
    box.apply_translation((0.0, 0.0, 3.0))
    box.export(path)
    return str(path)


def _mesh_only(meshes, **extra) -> Scenario:
    return Scenario.model_validate({"name": "mesh_only", "map": None, "static_meshes": meshes,
                                    "sensor": {"profile": "vlp16"}, **extra})  # fmt: skip


def test_the_shipped_street_scenario_is_mesh_only():
    s = load_scenario("ouster_street")
    assert s.mesh_only and s.map is None and s.ego is None and s.actors == []
    assert s.static_meshes == [f"cache:{STREET_MESH}"] and s.sensor.profile == "os1_128_1024"
    assert s.weather.precipitation.type == "dry" and s.weather.fog.visual_range_m >= 1e4 and s.regions == []


@pytest.mark.parametrize(
    "data, message",
    [
        ({"map": "highway_straight.xodr"}, "'ego' is required"),
        ({"static_meshes": []}, "needs 'static_meshes'"),
        ({"ego": {"lane": -1}}, "cannot have an 'ego'"),
        ({"actors": [{"id": 100, "lane": -1}]}, r"actors \[100\] need a 'trajectory'"),
    ],
)
def test_mesh_only_schema_errors(data, message):
    base = {"name": "x", "static_meshes": ["room.ply"]}
    with pytest.raises(pydantic.ValidationError, match=message):
        Scenario.model_validate({**base, **data})


def test_existing_scenarios_still_have_a_map_and_an_ego():
    s = load_scenario("highway_clear")
    assert not s.mesh_only and s.ego is not None


def test_cache_paths(tmp_path, monkeypatch):
    monkeypatch.setenv("LWS_CACHE_DIR", str(tmp_path))
    assert cache_dir() == tmp_path
    with pytest.raises(FileNotFoundError, match="run make setup to import it"):
        resolve_data_path("cache:ouster_real/none.ply")
    (tmp_path / "sub").mkdir()
    (tmp_path / "sub" / "m.ply").write_text("ply")
    assert resolve_data_path("cache:sub/m.ply") == tmp_path / "sub" / "m.ply"
    assert resolve_data_path("m.ply", tmp_path / "maps") == tmp_path / "maps" / "m.ply"


def test_a_missing_cached_mesh_fails_world_build_with_a_hint(tmp_path, monkeypatch):
    monkeypatch.setenv("LWS_CACHE_DIR", str(tmp_path))
    with pytest.raises(FileNotFoundError, match="make setup"):
        World.build(_mesh_only(["cache:ouster_real/os1_128_street_mesh.ply"]))


def test_world_of_a_mesh_only_scenario(room):
    world = World.build(_mesh_only([room]))
    assert world.scene.roads is not None and not world.scene.roads.roads  # an empty road network
    assert len(world.scene.static.triangles) == 12 and world.scene.actors == {}
    assert world.player.actor_poses(1.0) == {} and world.player.actor_poses_at([0.0, 1.0]) == [{}, {}]
    with pytest.raises(NoEgoError, match="has no ego"):
        world.player.sensor_poses(np.array([0.0]))
    with pytest.raises(NoEgoError):
        world.player.base_link_poses(np.array([0.0]))


def test_a_frame_is_cast_against_the_mesh_from_external_poses(room):
    world = World.build(_mesh_only([room]))
    sim = LidarSimulator(world.profile, world.scene, regions=world.regions(pose_source=FixedPose((0, 0, 1.5))), seed=0)
    points = sim.cast_frame(0, 0.0, FixedPose((0.0, 0.0, 1.5))).points
    assert len(points) > 0.9 * len(world.profile.beams) * world.profile.scan.columns
    # every return lies on the box: |x| or |y| = 10 m (walls) or z = -1.5 / +4.5 m in the sensor frame
    x, y, z = (points[k].astype(np.float64) for k in "xyz")
    on_wall = np.isclose(np.maximum(abs(x), abs(y)), 10.0, atol=0.05)
    on_floor_or_ceiling = np.isclose(z, -1.5, atol=0.05) | np.isclose(z, 4.5, atol=0.05)
    assert np.mean(on_wall | on_floor_or_ceiling) > 0.99


def test_run_refuses_a_mesh_only_scenario(room, tmp_path, capsys):
    path = tmp_path / "mesh_only.yaml"
    path.write_text(f"name: mesh_only\nmap: null\nstatic_meshes: ['{room}']\nsensor: {{profile: vlp16}}\n")
    assert cli_main(["run", str(path), "--frames", "2", "--out", str(tmp_path / "out")]) == 2
    err = [line for line in capsys.readouterr().err.splitlines() if "error" in line]
    assert len(err) == 1 and "has no ego" in err[0] and "cannot be run" in err[0]
    assert not (tmp_path / "out").exists()


def _street_cache():
    if not (cache_dir() / STREET_MESH).is_file() or not (cache_dir() / STREET_BAG).is_dir():
        pytest.skip(f"{cache_dir() / 'ouster_real'} not imported (make setup, step 3c)")


def test_the_real_street_is_cast_from_the_recorded_poses():
    _street_cache()
    from lidar_weather_sim.replay import RecordedPoses
    from lidar_weather_sim.io.recording import Recording

    world = World.build(load_scenario("ouster_street"))
    recording = Recording.load(cache_dir() / STREET_BAG)
    poses = RecordedPoses(recording, world)
    assert poses.actor_poses(0.0) == {}
    sim = LidarSimulator(world.profile, world.scene, seed=0)
    frame = recording.frames[0]
    index = recording.scan_index(frame, world.profile.period_s)
    simulated = sim.cast_frame(index, recording.time_s(frame.stamp_ns), poses).points
    measured = frame.points
    # the mesh misses ~9 % of the returns and adds some where the sensor saw nothing (ouster_import)
    assert 0.7 < len(simulated) / len(measured) < 1.3
    assert np.median(simulated["distance"]) == pytest.approx(np.median(measured["distance"]), rel=0.2)


def test_the_beams_origin_read_off_the_real_points_is_ousters_own():
    """The real OS1-128's points are in Ouster's sensor frame: its beams fire from 36.18 mm above it
    (lidar_to_sensor_transform) and 15.8 mm off the axis (lidar_origin_to_beam_origin_mm). Read off the points'
    elevations alone (gap.channels.beam_origin), both come back within 1 mm, against the unit's own metadata;
    with them taken out no channel shows an elevation offset (the profile's table is the unit's)."""
    _street_cache()
    import json

    from lidar_weather_sim.gap.channels import beam_origin, elevation_offsets
    from lidar_weather_sim.io.ouster_import import MEMBERS, _read_members, default_sdist
    from lidar_weather_sim.io.ouster_pcap import OusterMetadata
    from lidar_weather_sim.io.recording import Recording
    from lidar_weather_sim.sensor.profile import load_profile

    meta = OusterMetadata.from_json(json.loads(_read_members(default_sdist())["metadata"]), MEMBERS["metadata"])
    recording = Recording.load(cache_dir() / STREET_BAG)
    profile = load_profile("os1_128_1024")
    nominal = np.array([b.elevation_deg for b in profile.beams])[profile.channel_order]
    points = [frame.points for frame in recording.frames]
    up, radial = beam_origin(points, nominal)
    assert abs(up - meta.lidar_to_sensor[2, 3] / 1000.0) < 1e-3, (up, meta.lidar_to_sensor[2, 3])
    assert abs(radial - meta.beam_origin_mm[0] / 1000.0) < 1e-3, (radial, meta.beam_origin_mm)
    assert elevation_offsets(points, nominal) == {}
