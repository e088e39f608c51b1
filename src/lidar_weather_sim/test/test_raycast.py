"""Ray casting: exact hits, backend agreement, actor instancing, small far actors, range."""

import importlib.util

import numpy as np
import pytest

from lidar_weather_sim.scene.mesh import TriangleMesh, box_mesh
from lidar_weather_sim.scene.raycast import (
    BackendUnavailableError,
    MeshCaster,
    SceneCaster,
    available_backends,
    make_caster,
    unavailable_backends,
)

BACKENDS = available_backends()


def pose(xyz, yaw=0.0, pitch=0.0) -> np.ndarray:
    """4x4 body->map transform: yaw about z, then pitch about y, then translation (m, rad)."""
    cy, sy, cp, sp = np.cos(yaw), np.sin(yaw), np.cos(pitch), np.sin(pitch)
    m = np.eye(4)
    m[:3, :3] = np.array([[cy, -sy, 0], [sy, cy, 0], [0, 0, 1]]) @ np.array([[cp, 0, sp], [0, 1, 0], [-sp, 0, cp]])
    m[:3, 3] = xyz
    return m


def plane(half_size: float, z: float, material: int, object_id: int) -> TriangleMesh:
    """Square at height z (m), normal +z."""
    h = half_size
    v = np.array([[-h, -h, z], [h, -h, z], [h, h, z], [-h, h, z]])
    return TriangleMesh(v, np.array([[0, 1, 2], [0, 2, 3]]), material, object_id)


def world(seed: int = 1) -> TriangleMesh:
    """Ground plane + 8 yawed boxes 8-30 m from the map origin + a guard rail.

    Boxes float 5 cm above the ground: no coplanar faces, so every nearest hit is unambiguous.
    """
    rng = np.random.default_rng(seed)
    parts = [plane(100.0, 0.0, 0, 1), box_mesh((60.0, 0.1, 0.8), 4, 2, 0.05).transformed(pose((0, -7, 0)))]
    for i in range(8):
        size = tuple(rng.uniform([1.0, 1.0, 0.5], [5.0, 2.5, 3.0]))
        r, a = rng.uniform(8, 30), rng.uniform(-np.pi, np.pi)
        where = (r * np.cos(a), r * np.sin(a), 0.0)
        parts.append(box_mesh(size, 1 + i % 3, 10 + i, 0.05).transformed(pose(where, rng.uniform(-np.pi, np.pi))))
    return TriangleMesh.concatenate(parts)


def unit(v) -> np.ndarray:
    v = np.asarray(v, dtype=np.float64)
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


def same_hit(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Per ray: both distances miss (inf), or both hit within 1e-4 m."""
    with np.errstate(invalid="ignore"):
        return np.where(np.isfinite(a), np.abs(a - b) <= 1e-4, ~np.isfinite(b))


def random_rays(n: int, seed: int = 2) -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    o = rng.uniform([-30, -30, 0.3], [30, 30, 3.0], (n, 3))
    return o.astype(np.float32), unit(rng.normal(size=(n, 3))).astype(np.float32)


BOX = box_mesh((2.0, 2.0, 2.0), 3, 42).transformed(pose((10, 0, 0)))  # x- face at x = 9, z in [0, 2]


def test_backends_expected_here():
    assert "open3d" in BACKENDS
    for name, module in (("embree", "embreex"), ("mitsuba", "mitsuba")):
        if importlib.util.find_spec(module):
            assert name in BACKENDS, unavailable_backends().get(name)


@pytest.mark.parametrize("backend", BACKENDS)
def test_backend_known_distance_and_miss(backend):
    caster = make_caster(backend, BOX.vertices, BOX.triangles)
    assert isinstance(caster, MeshCaster)
    o = np.array([[0, -0.5, 1.5], [0, 0.5, 0.5], [0, 0, 1], [0, 0, 3]], np.float32)
    d = np.array([[1, 0, 0], [1, 0, 0], [-1, 0, 0], [1, 0, 0]], np.float32)
    dist, tri = caster.cast(o, d)
    assert dist.dtype == np.float32 and tri.dtype == np.int64
    np.testing.assert_allclose(dist[:2], 9.0, atol=1e-5)
    assert tri[:2].tolist() == [8, 9]  # x- face: (0, 4, 6) holds the -y/top corner, (0, 6, 2) the +y/bottom
    assert np.isinf(dist[2:]).all() and tri[2:].tolist() == [-1, -1]
    empty_dist, empty_tri = caster.cast(np.zeros((0, 3)), np.zeros((0, 3)))
    assert empty_dist.shape == empty_tri.shape == (0,)


@pytest.mark.parametrize("backend", BACKENDS)
def test_scene_known_hit_normal_material_object(backend):
    static = TriangleMesh.concatenate([BOX, plane(50.0, -1.0, 5, 7)])
    sc = SceneCaster(static, {}, backend=backend)
    o = np.array([[0, -0.5, 1.5], [0, 0, -3], [0, 0, 5]], np.float32)
    d = np.array([[1, 0, 0], [0, 0, 1], [0, 0, 1]], np.float32)
    hits = sc.cast(o, d, {}, max_range_m=100.0)
    np.testing.assert_allclose(hits.distance[:2], [9.0, 2.0], atol=1e-5)
    np.testing.assert_allclose(hits.normal[:2], [[-1, 0, 0], [0, 0, -1]], atol=1e-6)  # plane seen from below: flipped
    assert hits.material[:2].tolist() == [3, 5] and hits.object_id[:2].tolist() == [42, 7]
    assert hits.hit_actor.tolist() == [-1, -1, -1]
    assert np.isinf(hits.distance[2]) and hits.material[2] == -1 and hits.object_id[2] == 0
    assert not hits.normal[2].any() and hits.hit.tolist() == [True, True, False]


def test_backends_agree_on_random_rays():
    if len(BACKENDS) < 2:
        pytest.skip(f"only {BACKENDS} available: {unavailable_backends()}")
    mesh = world()
    o, d = random_rays(100_000)
    ref_dist, ref_tri = make_caster("open3d", mesh.vertices, mesh.triangles).cast(o, d)
    ref_hit = np.isfinite(ref_dist)
    assert 0.3 < ref_hit.mean() < 0.9  # both hits and misses are exercised
    for name in BACKENDS:
        dist, tri = make_caster(name, mesh.vertices, mesh.triangles).cast(o, d)
        hit = np.isfinite(dist)
        assert same_hit(dist, ref_dist).mean() >= 0.999, name
        both = hit & ref_hit
        assert (tri[both] == ref_tri[both]).mean() >= 0.999, name
        assert (tri[~hit] == -1).all()


@pytest.mark.skipif("mitsuba" not in BACKENDS, reason="mitsuba unavailable")
def test_mitsuba_casts_leave_no_worker_threads():
    """Dr.Jit's workers spin for ~25 ms after a kernel: a cast stops them, large or small."""
    import drjit as dr

    from lidar_weather_sim.scene.raycast.backend_mitsuba import PARALLEL_RAYS

    caster = make_caster("mitsuba", BOX.vertices, BOX.triangles)
    for n in (10, PARALLEL_RAYS):
        o, d = random_rays(n)
        dist, _ = caster.cast(o, d)
        assert len(dist) == n and dr.thread_count() == 1


def car() -> TriangleMesh:
    """Body-frame vehicle: a body box and a cabin box, object id 100."""
    return TriangleMesh.concatenate([box_mesh((4.5, 1.8, 0.9), 2, 100, 0.3), box_mesh((2.2, 1.6, 0.6), 6, 100, 1.2)])


@pytest.mark.parametrize("backend", BACKENDS)
def test_instanced_actor_matches_rebuilt_world(backend):
    static, actor = world(), car()
    sc = SceneCaster(static, {7: actor}, backend=backend)
    # lidar-ordered rays (50 beams x 2000 columns, as SceneCaster's block culling expects)
    # from origins jittered by a few cm (a moving sensor's rays do not share one origin)
    el, az = np.meshgrid(np.linspace(-0.5, 0.2, 50), np.linspace(-np.pi, np.pi, 2000, endpoint=False), indexing="ij")
    d = np.stack([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)], -1).reshape(-1, 3).astype(np.float32)
    o = (np.array([0.5, -0.2, 1.8]) + np.random.default_rng(3).uniform(-0.05, 0.05, d.shape)).astype(np.float32)
    for p in (pose((8, 3, 0), 0.3), pose((-12, -4, 0.1), 2.5, 0.05), pose((3, 14, 0), -1.2)):
        got = sc.cast(o, d, {7: p}, max_range_m=200.0)
        ref = SceneCaster(TriangleMesh.concatenate([static, actor.transformed(p)]), {}, backend=backend).cast(
            o, d, {}, max_range_m=200.0
        )
        on_actor = got.object_id == 100
        assert on_actor.sum() > 300  # the actor is in view and hit
        assert (got.hit_actor[on_actor] == 7).all() and (got.hit_actor[~on_actor] == -1).all()
        assert same_hit(got.distance, ref.distance).mean() >= 0.999
        assert (got.object_id == ref.object_id).mean() >= 0.999
        assert (got.material == ref.material).mean() >= 0.999
        both = got.hit & ref.hit
        assert (np.einsum("ij,ij->i", got.normal[both], ref.normal[both]) > 0.9999).mean() >= 0.999
        # without the gather: the same hits, static attributes by triangle from the static tables
        lean = sc.cast(o, d, {7: p}, max_range_m=200.0, gather=False)
        assert lean.distance.tobytes() == got.distance.tobytes() and np.array_equal(lean.triangle, got.triangle)
        assert (got.triangle[on_actor | ~got.hit] == -1).all()
        t = got.triangle[got.triangle >= 0]
        normals, material, object_id = sc.static_tables
        assert np.array_equal(np.abs(normals[t]), np.abs(got.normal[got.triangle >= 0]))
        assert np.array_equal(material[t], got.material[got.triangle >= 0])
        assert np.array_equal(object_id[t], got.object_id[got.triangle >= 0])
        for name in ("normal", "material", "object_id", "hit_actor"):
            assert np.array_equal(getattr(lean, name)[on_actor], getattr(got, name)[on_actor])
    absent = sc.cast(o, d, {}, max_range_m=200.0)
    assert not (absent.object_id == 100).any() and (absent.hit_actor == -1).all()


@pytest.mark.parametrize("backend", BACKENDS)
def test_centimetre_actor_at_50_m_is_hit(backend):
    origin = np.array([3.1, -2.2, 1.9])
    u = unit([0.9, 0.3, -0.05])
    centre = origin + 50.0 * u
    yaw = np.arctan2(u[1], u[0])
    tiny = box_mesh((0.02, 0.02, 0.02), 1, 9, z_bottom=-0.01)  # centred 2 cm cube
    sc = SceneCaster(TriangleMesh.empty(), {3: tiny}, backend=backend)
    rng = np.random.default_rng(4)
    body_to_map = pose(centre, yaw)[:3, :3]
    # 1. 256 rays (two culling blocks, narrow cones) from 0.8 m beside `origin`, aimed
    # at points inside the cube: the block cull must allow for the origins' spread
    side_o = origin + 0.8 * np.array([-np.sin(yaw), np.cos(yaw), 0.0])
    side_d = unit(centre + rng.uniform(-0.009, 0.009, (256, 3)) @ body_to_map.T - side_o)
    # 2. a horizontal fan across the cube from `origin` (lateral offsets at the cube, m)
    lateral = np.array([-np.sin(yaw), np.cos(yaw), 0.0])
    offsets = np.linspace(-0.03, 0.03, 61)
    fan = unit(centre + offsets[:, None] * lateral - origin)
    # 3. 5000 rays from origins spread over a metre, each aimed at a point inside the
    # cube: a float32 |v|^2 - (v.d)^2 sphere test drops several per cent of them at 50 m
    spread_o = origin + rng.uniform(-0.5, 0.5, (5000, 3))
    aimed = unit(centre + rng.uniform(-0.009, 0.009, (5000, 3)) @ body_to_map.T - spread_o)
    # 4. 20000 random rays
    other_o = origin + rng.uniform(-0.5, 0.5, (20_000, 3))
    other_d = unit(rng.normal(size=(20_000, 3)))
    o = np.vstack([np.tile(side_o, (256, 1)), np.tile(origin, (61, 1)), spread_o, other_o]).astype(np.float32)
    d = np.vstack([side_d, fan, aimed, other_d]).astype(np.float32)
    hits = sc.cast(o, d, {3: pose(centre, yaw)}, max_range_m=200.0)
    side, fan_, aimed_ = slice(0, 256), slice(256, 317), slice(317, 5317)
    assert (hits.hit_actor[side] == 3).all() and (hits.hit_actor[aimed_] == 3).all()
    assert (np.abs(hits.distance[aimed_] - np.linalg.norm(centre - spread_o, axis=1)) < 0.02).all()
    fan_hit = hits.hit[fan_]
    assert fan_hit[np.abs(offsets) <= 0.009].all()
    assert not fan_hit[np.abs(offsets) >= 0.011].any()
    # the centre ray meets the -x face (x_body = -0.01) at t = 50 - 0.01 / horizontal part of u
    mid = 256 + 30
    np.testing.assert_allclose(hits.distance[mid], 50.0 - 0.01 / np.hypot(u[0], u[1]), atol=1e-4)
    assert hits.hit_actor[mid] == 3 and hits.object_id[mid] == 9
    np.testing.assert_allclose(hits.normal[mid], -np.array([np.cos(yaw), np.sin(yaw), 0]), atol=1e-5)


@pytest.mark.parametrize("backend", BACKENDS)
def test_max_range(backend):
    static = TriangleMesh.concatenate([BOX, box_mesh((1, 20, 20), 1, 5).transformed(pose((30.5, 0, -10)))])
    sc = SceneCaster(static, {4: box_mesh((1, 1, 1), 2, 8)}, backend=backend)
    o = np.float32([[0, 0, 1], [0, 5, 0.5]])  # at the box (9 m); past it to the wall (30 m)
    d = np.float32([[1, 0, 0], [1, 0, 0]])
    assert np.isinf(sc.cast(o, d, {}, max_range_m=8.99).distance).all()
    np.testing.assert_allclose(sc.cast(o, d, {}, max_range_m=9.01).distance, [9.0, np.inf], atol=1e-5)
    actor_at_20 = {4: pose((20.5, 5, 0))}  # its x- face at 20 m, in front of the wall on the second ray
    near = sc.cast(o, d, actor_at_20, max_range_m=19.99)
    assert np.isinf(near.distance[1]) and near.hit_actor[1] == -1 and near.object_id[1] == 0
    mid = sc.cast(o, d, actor_at_20, max_range_m=25.0)
    np.testing.assert_allclose(mid.distance, [9.0, 20.0], atol=1e-5)
    assert mid.hit_actor.tolist() == [-1, 4] and mid.object_id.tolist() == [42, 8]
    far = sc.cast(o, d, {}, max_range_m=35.0)
    np.testing.assert_allclose(far.distance, [9.0, 30.0], atol=1e-5)


def test_unknown_backend_lists_available():
    for bad in ("nope", lambda: SceneCaster(BOX, {}, backend="nope")):
        with pytest.raises(BackendUnavailableError) as err:
            make_caster(bad, BOX.vertices, BOX.triangles) if isinstance(bad, str) else bad()
        msg = str(err.value)
        assert "'nope'" in msg and all(name in msg for name in BACKENDS)
    assert isinstance(err.value, ValueError)


def test_env_default_and_pose_checks(monkeypatch):
    monkeypatch.setenv("LWS_RAYCAST_BACKEND", "open3d")
    sc = SceneCaster(BOX, {1: box_mesh((1, 1, 1), 0, 3)})
    assert sc.backend == "open3d"
    o, d = np.zeros((1, 3), np.float32), np.float32([[1, 0, 0]])
    with pytest.raises(KeyError, match="2"):
        sc.cast(o, d, {2: np.eye(4)}, 10.0)
    with pytest.raises(ValueError, match="rotation"):
        sc.cast(o, d, {1: np.diag([2.0, 1, 1, 1])}, 10.0)
