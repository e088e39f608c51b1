"""Materials (against the thesis tables), static mesh loading, the vehicle model and the scene."""

from pathlib import Path

import numpy as np
import pytest
import yaml

from lidar_weather_sim.core.config import ConfigError
from lidar_weather_sim.core.points import Label
from lidar_weather_sim.scene.materials import MaterialTable
from lidar_weather_sim.scene.mesh import TriangleMesh, box_mesh
from lidar_weather_sim.scene.scene import MeshLoadError, Scene, VehicleShape, load_static_mesh, vehicle_mesh

ROOT = Path(__file__).resolve().parents[3]
THESIS_TABLES = ROOT.parent / "shared" / "data" / "thesis_tables.yaml"


@pytest.fixture(scope="module")
def thesis():
    assert THESIS_TABLES.is_file(), f"{THESIS_TABLES} missing (shared/ must sit beside the workspace)"
    return yaml.safe_load(THESIS_TABLES.read_text())


@pytest.fixture(scope="module")
def materials():
    return MaterialTable.default()


# ---------------------------------------------------------------- materials
def test_thesis_albedos(materials, thesis):
    albedo = thesis["optics_and_materials"]["albedo"]
    assert materials["asphalt_dry"].reflectivity == albedo["dry_asphalt"]
    assert materials["asphalt_wet"].reflectivity == albedo["wet_asphalt_at_46deg"]
    assert materials["snow"].reflectivity == albedo["snow"]
    # paper 3 Table II gives absorption; reflectivity = 1 - absorption
    spray = thesis["spray"]["materials"]
    for name, key in (("car_paint", "car_body"), ("tyre", "wheels"), ("license_plate", "license_plate")):
        assert materials[name].reflectivity == pytest.approx(1.0 - spray[key]["absorption"])


def test_default_table_contents(materials):
    expected = {"asphalt_dry", "asphalt_wet", "snow", "lane_marking", "guard_rail", "concrete", "vegetation",
                "car_paint", "tyre", "glass", "license_plate", "sign"}  # fmt: skip
    assert set(materials.names) == expected
    for retro in ("lane_marking", "license_plate", "sign"):
        assert materials[retro].retro_share > 0
    assert materials["asphalt_dry"].retro_share == 0
    assert materials["car_paint"].label == Label.VEHICLE and materials["guard_rail"].label == Label.STATIC
    i = materials.index("snow")
    assert materials[i].name == "snow" and materials.reflectivity[i] == materials["snow"].reflectivity
    assert materials.labels[materials.index("tyre")] == Label.VEHICLE
    with pytest.raises(KeyError, match="unknown material 'mud'; known: asphalt_dry"):
        materials.index("mud")


@pytest.mark.parametrize(
    "text, expected",
    [
        ("materials:\n  a: {reflectivity: 1.5}\n", "key 'materials.a.reflectivity': value 1.5"),
        ("materials:\n  a: {reflectivity: 0.5, label: CAT}\n", "key 'materials.a.label': value 'CAT'"),
        ("materials:\n  a: {reflectivity: 0.5, shine: 2}\n", "unknown key 'materials.a.shine'"),
        ("materials: {}\n", "key 'materials'"),
    ],
)
def test_bad_materials_yaml(tmp_path, text, expected):
    path = tmp_path / "materials.yaml"
    path.write_text(text)
    with pytest.raises(ConfigError) as err:
        MaterialTable.from_yaml(path)
    assert str(path) in str(err.value) and expected in str(err.value)


# ---------------------------------------------------------------- vehicle
def _closed_and_outward(mesh: TriangleMesh) -> None:
    """Every directed edge once and its reverse once (closed, consistently wound); positive volume."""
    t = mesh.triangles
    directed = np.concatenate([t[:, [0, 1]], t[:, [1, 2]], t[:, [2, 0]]])
    assert len(np.unique(directed, axis=0)) == len(directed)
    forward = {tuple(e) for e in directed.tolist()}
    assert all((b, a) in forward for a, b in forward)
    v = mesh.vertices[t]
    assert np.einsum("ij,ij->i", v[:, 0], np.cross(v[:, 1], v[:, 2])).sum() / 6 > 0


def test_vehicle_dimensions_and_parts(materials):
    mesh = vehicle_mesh(4.6, 1.85, 1.45, object_id=42, materials=materials)
    np.testing.assert_allclose(mesh.vertices.min(axis=0), [-2.3, -0.925, 0.0], atol=1e-12)
    np.testing.assert_allclose(mesh.vertices.max(axis=0), [2.3, 0.925, 1.45], atol=1e-12)
    assert np.all(mesh.object_id == 42)
    _closed_and_outward(mesh)
    assert len(mesh.triangles) == 12 * 8  # body, cabin, 4 wheels, 2 plates
    count = {n: int(np.sum(mesh.material == materials.index(n))) for n in ("car_paint", "glass", "tyre", "license_plate")}
    assert count == {"car_paint": 12 + 2, "glass": 10, "tyre": 48, "license_plate": 24}
    roof = mesh.material == materials.index("car_paint")
    assert mesh.vertices[mesh.triangles[roof]][..., 2].max() == pytest.approx(1.45)
    plates = mesh.vertices[mesh.triangles[mesh.material == materials.index("license_plate")]].reshape(-1, 3)
    assert plates[:, 0].max() == pytest.approx(2.3) and plates[:, 0].min() == pytest.approx(-2.3)
    assert plates[plates[:, 0] > 0, 1].max() == pytest.approx(0.26)  # 520 mm EU plate
    tyres = mesh.vertices[mesh.triangles[mesh.material == materials.index("tyre")]].reshape(-1, 3)
    assert tyres[:, 2].min() == 0.0 and tyres[:, 2].max() == pytest.approx(0.66)


def test_vehicle_shape_wheels_and_validation():
    shape = VehicleShape(length=5.0, width=2.0, height=1.5, wheelbase=3.0, wheel_diameter=0.7, wheel_width=0.25)
    np.testing.assert_allclose(shape.wheel_centres[:, 0], [1.5, 1.5, -1.5, -1.5])
    np.testing.assert_allclose(shape.wheel_centres[:, 1], [0.875, -0.875, 0.875, -0.875])
    np.testing.assert_allclose(shape.wheel_centres[:, 2], 0.35)
    with pytest.raises(ValueError, match="ground_clearance"):
        VehicleShape(height=0.1)


# ---------------------------------------------------------------- mesh files
def test_load_ply_obj_and_gltf_axes(tmp_path):
    import trimesh

    box = trimesh.creation.box(extents=(1.0, 2.0, 3.0))
    for suffix in (".ply", ".obj"):
        box.export(tmp_path / f"box{suffix}")
        mesh = load_static_mesh(tmp_path / f"box{suffix}", material=3, object_id=77)
        assert len(mesh.triangles) == 12 and np.all(mesh.material == 3) and np.all(mesh.object_id == 77)
        np.testing.assert_allclose(np.ptp(mesh.vertices, axis=0), [1.0, 2.0, 3.0])
    # glTF is y-up with the front along +z: extents (x, y, z)_gltf = (1, 2, 3) -> (3, 1, 2) z-up
    box.export(tmp_path / "box.glb")
    mesh = load_static_mesh(tmp_path / "box.glb", material=0, object_id=1)
    np.testing.assert_allclose(np.ptp(mesh.vertices, axis=0), [3.0, 1.0, 2.0])
    _closed_and_outward(mesh)  # the axis change is a rotation: winding stays outward
    shift = np.eye(4)
    shift[:3, 3] = (10.0, 0.0, 0.0)
    moved = load_static_mesh(tmp_path / "box.glb", 0, 1, y_up=False, transform=shift)
    np.testing.assert_allclose(np.ptp(moved.vertices, axis=0), [1.0, 2.0, 3.0])
    assert moved.vertices[:, 0].min() == pytest.approx(9.5)


@pytest.mark.parametrize(
    "name, content, expected",
    [
        ("broken.glb", b"glTF garbage", "broken.glb: cannot read mesh"),
        ("empty.ply", b"ply\nformat ascii 1.0\nelement vertex 0\nelement face 0\nend_header\n", "empty.ply: cannot read mesh"),
        ("model.fbx", b"x", "model.fbx: cannot read mesh: unsupported format '.fbx'"),
        ("absent.obj", None, "absent.obj: cannot read mesh: no such file"),
    ],
)
def test_bad_mesh_file_is_named(tmp_path, name, content, expected):
    path = tmp_path / name
    if content is not None:
        path.write_bytes(content)
    with pytest.raises(MeshLoadError) as err:
        load_static_mesh(path, 0, 1)
    assert expected in str(err.value)


# ---------------------------------------------------------------- scene
def test_scene_from_xodr_with_actor_and_static_mesh(materials):
    scene = Scene.from_xodr(ROOT / "maps" / "highway_straight.xodr", materials)
    assert scene.roads is not None and scene.next_object_id() == 5
    n_static = len(scene.static.triangles)
    scene.add_static(box_mesh((2.0, 2.0, 3.0), materials.index("concrete"), 5), "pillar")
    car = vehicle_mesh(4.6, 1.85, 1.45, object_id=0, materials=materials)
    scene.add_actor(100, car, "lead car")
    assert scene.object_names[5] == "pillar" and scene.object_names[100] == "lead car"
    assert np.all(scene.actors[100].object_id == 100) and scene.actor_labels == {100: Label.VEHICLE}
    with pytest.raises(ValueError, match="already used by"):
        scene.add_actor(3, car)
    # place the car on lane -2 at s = 100 m
    x, y, z, heading = (float(v) for v in scene.roads.lane_pose("1", -2, 100.0))
    pose = np.eye(4)
    pose[:3, :3] = [[np.cos(heading), -np.sin(heading), 0], [np.sin(heading), np.cos(heading), 0], [0, 0, 1]]
    pose[:3, 3] = (x, y, z)
    world = scene.world_mesh({100: pose})
    assert len(world.triangles) == n_static + 12 + len(car.triangles)
    car_v = world.vertices[world.triangles[world.object_id == 100]].reshape(-1, 3)
    np.testing.assert_allclose(car_v.min(axis=0), [97.7, -5.625 - 0.925, 0.0], atol=1e-9)
    # rain: the road turns wet
    dry, wet = materials.index("asphalt_dry"), materials.index("asphalt_wet")
    n_dry = int(np.sum(scene.static.material == dry))
    scene.swap_material("asphalt_dry", "asphalt_wet")
    assert np.sum(scene.static.material == dry) == 0 and np.sum(scene.static.material == wet) == n_dry
