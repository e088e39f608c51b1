"""The simulator's fast paths against the plain numpy formulations they replace, bit for bit:
rotation of the scan pattern, LIDAR-equation candidates, point assembly, chunked (threaded)
runs, batched player poses, padded Mitsuba casts."""

import numpy as np
import pytest

from lidar_weather_sim.core import workers
from lidar_weather_sim.core.geometry import quaternion_matrices
from lidar_weather_sim.core.points import POINT_DTYPE, Label
from lidar_weather_sim.core.scratch import Scratch
from lidar_weather_sim.scene.materials import MaterialTable
from lidar_weather_sim.scene.mesh import TriangleMesh, box_mesh
from lidar_weather_sim.scene.raycast import SceneCaster, available_backends
from lidar_weather_sim.scene.raycast.scene_caster import _padded_size
from lidar_weather_sim.scene.scene import Scene
from lidar_weather_sim.sensor.echo import _beam_order, beam_groups
from lidar_weather_sim.sensor.profile import SensorProfile
from lidar_weather_sim.sensor.radiometry import overlap_factor, peak_amplitude, surface_reflectance
from lidar_weather_sim.sim import kernels
from lidar_weather_sim.sim.kernels import (
    compact_candidates,
    occluded_candidates,
    range_noise,
    surface_returns,
    world_rays,
)
from lidar_weather_sim.sim.simulator import LidarSimulator

MATERIALS = MaterialTable.default()


def profile(**optics) -> SensorProfile:
    """8 beams with azimuth offsets, 64 columns over 90 deg, 3 x 2 sub-rays, biaxial overlap."""
    return SensorProfile.model_validate({
        "name": "kernels",
        "beams": [{"elevation_deg": e, "azimuth_offset_deg": 0.3 * (i % 3 - 1)}
                  for i, e in enumerate(np.linspace(-15, 5, 8))],
        "scan": {"frame_rate_hz": 10.0, "azimuth_min_deg": -45.0, "azimuth_max_deg": 45.0, "columns": 64},
        "range": {"min_m": 0.3, "max_m": 120.0, "resolution_m": 0.05, "noise_sigma_m": 0.02},
        "optics": {"divergence_h_mrad": 3.0, "divergence_v_mrad": 2.0, "subrays_h": 3, "subrays_v": 2,
                   "overlap_start_m": 0.5, "overlap_full_m": 2.0, **optics},
        "pulse": {"fwhm_m": 0.75},
        "detection": {"max_echoes": 2, "power_constant": 5.0e5, "false_alarms_per_beam": 0.05},
    })  # fmt: skip


def street() -> Scene:
    """Ground, a wall, a pole and two box actors (ids 100, 101)."""
    ground = box_mesh((200.0, 200.0, 0.1), MATERIALS.index("asphalt_dry"), 1, z_bottom=-1.6)
    wall = box_mesh((0.3, 60.0, 6.0), MATERIALS.index("concrete"), 2, z_bottom=-1.5)
    wall = wall.transformed(np.array([[1, 0, 0, 30.0], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]]))
    pole = box_mesh((0.05, 0.05, 4.0), MATERIALS.index("guard_rail"), 3, z_bottom=-1.5)
    pole = pole.transformed(np.array([[1, 0, 0, 8.0], [0, 1, 0, 1.0], [0, 0, 1, 0], [0, 0, 0, 1]]))
    scene = Scene(MATERIALS, TriangleMesh.concatenate([ground, wall, pole]))
    for actor_id in (100, 101):
        scene.add_actor(actor_id, box_mesh((4.5, 1.8, 1.5), MATERIALS.index("car_paint"), actor_id, z_bottom=-1.5))
    return scene


class Motion:
    """Sensor moving and yawing; actors driving by (a pose source with non-trivial rotations)."""

    def sensor_poses(self, times):
        t = np.asarray(times, dtype=np.float64)
        yaw = 0.3 * t
        translation = np.stack([12.0 * t, 0.5 * np.sin(t), np.full_like(t, 0.1)], axis=-1)
        return translation, np.stack([np.zeros_like(t), np.zeros_like(t), np.sin(yaw / 2), np.cos(yaw / 2)], axis=-1)

    def actor_poses(self, time_s):
        out = {}
        for actor_id, (x0, y, v) in {100: (15.0, -2.0, 20.0), 101: (10.0, 3.5, 5.0)}.items():
            m = np.eye(4)
            c, s = np.cos(0.05 * time_s), np.sin(0.05 * time_s)
            m[:2, :2] = [[c, -s], [s, c]]
            m[:3, 3] = (x0 + v * time_s, y, 0.0)
            out[actor_id] = m
        return out


def frames(sim: LidarSimulator, steps: int = 23, dt: float = 0.013):
    out = []
    for k in range(steps):
        out += sim.advance(k * dt, Motion())
    return out


@pytest.fixture
def chunked(monkeypatch):
    """Two threads and tiny chunks, so that even these small batches are split."""
    import lidar_weather_sim.scene.raycast.scene_caster as scene_caster
    import lidar_weather_sim.sensor.echo as echo
    import lidar_weather_sim.sim.kernels as kernels

    monkeypatch.setattr(workers, "THREADS", 2)
    monkeypatch.setattr(kernels, "CHUNK_RAYS", 96)
    monkeypatch.setattr(scene_caster, "CHUNK_RAYS", 256)
    monkeypatch.setattr(echo, "CHUNK_CANDIDATES", 40)


def test_quaternion_matrices_match_numpy():
    q = np.random.default_rng(6).normal(size=(50, 4))
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    x, y, z, w = q.T
    expected = np.stack([
        np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)], -1),
        np.stack([2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)], -1),
        np.stack([2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)], -1),
    ], -2)  # fmt: skip
    assert quaternion_matrices(q).tobytes() == expected.tobytes()


def test_world_rays_match_numpy_rotation():
    rng = np.random.default_rng(1)
    q = rng.normal(size=(17, 4))
    rotation = quaternion_matrices(q / np.linalg.norm(q, axis=1, keepdims=True))
    directions = rng.normal(size=(17, 5, 3, 3))
    translation = rng.normal(size=(17, 3)) * 100
    o32, d32, d64 = world_rays(directions, rotation, translation, True)
    world = np.einsum("cij,cbsj->cbsi", rotation, directions).reshape(-1, 3)
    assert d64.tobytes() == world.tobytes()
    assert d32.tobytes() == world.astype(np.float32).tobytes()
    assert o32.tobytes() == np.repeat(translation, 15, axis=0).astype(np.float32).tobytes()


def test_beam_order_matches_numpy_stable_sort():
    """The echo stage's counting sort: numpy's stable order, with empty beams and beams in any order."""
    rng = np.random.default_rng(4)
    beam = rng.integers(0, 500, 1200)
    beam = beam[beam % 7 != 3]
    assert np.array_equal(_beam_order(beam), np.argsort(beam, kind="stable"))
    order, first = beam_groups(beam, 500)
    assert np.array_equal(order, np.argsort(beam, kind="stable"))
    assert np.array_equal(first, np.searchsorted(np.sort(beam), np.arange(501)))


def occluded_reference(surface, scatterers, n_beams, n_sub):
    """Slow form of the occlusion: per sub-ray, candidates in range order (stable; NaN last), each
    scaled by the product of (1 - occlusion)^2 of those before it (scene hits opaque); then per beam
    its sub-rays' hits in sub-ray order and its scatterers as given, those with amplitude > 0."""
    s_range, s_amp, s_label, s_obj = surface
    b, sub, r, a, lab, obj, occ = scatterers
    rows = []  # (beam, position within the beam, range, amplitude, label, object id)
    for beam in range(n_beams):
        mine = np.flatnonzero(b == beam)
        for s in range(n_sub):
            k = beam * n_sub + s
            cand = [(s_range[k], s_amp[k], 1.0, s, s_label[k], s_obj[k])]
            cand += [(r[i], a[i], occ[i], n_sub + q, lab[i], obj[i]) for q, i in enumerate(mine) if sub[i] == s]
            ranked = sorted(range(len(cand)), key=lambda j: (np.isnan(cand[j][0]), cand[j][0], cand[j][3]))
            light = 1.0
            for j in ranked:
                rng_m, amp, o, pos, label, oid = cand[j]
                rows.append((beam, pos, rng_m, amp * light, label, oid))
                light *= max(1.0 - min(max(o, 0.0), 1.0), 1e-30) ** 2
    rows = sorted((row for row in rows if row[3] > 0), key=lambda row: (row[0], row[1]))
    return tuple(np.array([row[k] for row in rows]) for k in (0, 2, 3, 4, 5))


@pytest.mark.parametrize("threads", [1, 2])
def test_occluded_candidates_match_a_per_sub_ray_reference(threads, monkeypatch):
    """Occlusion by what lies in front on the same sub-ray, against a slow per-sub-ray loop: ties,
    misses, NaN, transparent and opaque scatterers, scatterers behind the scene hit, beams without
    scatterers; grouped by beam in the order the echo stage's merging depends on."""
    monkeypatch.setattr(workers, "THREADS", threads)
    monkeypatch.setattr(kernels, "CHUNK_RAYS", 16)
    rng = np.random.default_rng(11)
    n_beams, n_sub, m = 60, 3, 150
    s_range = rng.uniform(2, 40, n_beams * n_sub)
    s_range[rng.random(len(s_range)) < 0.2] = np.inf
    s_amp = np.where(np.isfinite(s_range), rng.uniform(0.5, 5, len(s_range)), 0.0)
    s_amp[rng.random(len(s_amp)) < 0.05] = 0.0  # a hit too weak to count
    surface = (s_range, s_amp, rng.integers(0, 5, len(s_range)).astype(np.uint8),
               rng.integers(0, 9, len(s_range)).astype(np.uint32))  # fmt: skip
    b = rng.integers(0, n_beams // 2, m) * 2  # odd beams: no scatterers
    r = rng.uniform(0, 45, m)
    r[:10] = 7.0  # ties
    r[10:13] = np.nan
    occ = rng.choice([0.0, 0.3, 1.0, 1.4, -0.2], m)
    scatterers = (b, rng.integers(0, n_sub, m), r, rng.uniform(0.1, 3, m), rng.integers(10, 15, m).astype(np.uint8),
                  rng.integers(100, 110, m).astype(np.uint32), occ)  # fmt: skip
    *got, (starts, counts) = occluded_candidates(surface, scatterers, n_beams, n_sub)
    got = tuple(np.concatenate([x[a : a + c] for a, c in zip(starts, counts)]) for x in got)
    want = occluded_reference(surface, scatterers, n_beams, n_sub)
    assert len(starts) > 1 or threads == 1
    for g, w in zip(got, want):
        assert g.dtype.kind == w.dtype.kind or g.dtype.kind in "iu"
        np.testing.assert_allclose(g.astype(np.float64), w.astype(np.float64), rtol=1e-12)
    assert (got[2] < 1e-50).sum() > 0  # scatterers behind a scene hit keep their (vanishing) light


@pytest.mark.parametrize("effects", [False, True])
@pytest.mark.parametrize("overlap", [(0.5, 2.0), (1.0, 1.0)])
def test_surface_returns_match_the_lidar_equation_in_numpy(effects, overlap):
    rng = np.random.default_rng(2)
    n_cols, n_beams, n_sub = 9, 4, 3
    m = n_cols * n_beams * n_sub
    directions = rng.normal(size=(n_cols, n_beams, n_sub, 3))
    directions /= np.linalg.norm(directions, axis=-1, keepdims=True)
    q = rng.normal(size=(n_cols, 4))
    rotation = quaternion_matrices(q / np.linalg.norm(q, axis=1, keepdims=True))
    distance = rng.uniform(0.0, 60.0, m).astype(np.float32)
    distance[rng.random(m) < 0.3] = np.inf
    normal = rng.normal(size=(m, 3)).astype(np.float32)
    material = np.where(np.isfinite(distance), rng.integers(0, len(MATERIALS), m), -1).astype(np.int32)
    actor = np.where(rng.random(m) < 0.2, 1, -1).astype(np.int32)
    object_id = rng.integers(1, 50, m).astype(np.uint32)
    reflectivity = np.append(MATERIALS.reflectivity, 0.0)
    retro = np.append(MATERIALS.retro_share, 0.0)
    material_label = np.append(np.asarray(MATERIALS.labels, np.uint8), np.uint8(Label.UNKNOWN))
    actor_label = np.array([Label.VEHICLE, Label.OBSTACLE], np.uint8)
    weights = np.array([0.2, 0.6, 0.2])
    shape = (n_cols * n_beams, n_sub)
    scale = rng.uniform(0.5, 1.5, shape) if effects else np.ones(shape)
    offset = rng.uniform(-0.2, 0.0, shape) if effects else np.zeros(shape)
    one_way = rng.uniform(0.8, 1.0, shape) if effects else np.ones(shape)
    alpha = rng.uniform(0, 0.01, shape) if effects else np.zeros(shape)

    # the numpy formulation (LidarSimulator._candidates before the kernels)
    world = np.einsum("cij,cbsj->cbsi", rotation, directions).reshape(shape + (3,))
    dist64 = distance.reshape(shape).astype(np.float64)
    hit = np.isfinite(dist64)
    mat = material.reshape(shape)
    cos_inc = np.abs(np.einsum("nsk,nsk->ns", normal.reshape(shape + (3,)), world))
    refl = surface_reflectance(reflectivity[mat], retro[mat], cos_inc) * scale
    rng_m = np.where(hit, dist64 + offset, np.inf)
    two_way = one_way**2 * np.exp(-2.0 * alpha * np.where(hit, rng_m, 0.0))
    amp = peak_amplitude(1.0e5, weights[None, :], refl, rng_m, two_way, overlap_factor(rng_m, *overlap))
    amp = np.where(hit, amp, 0.0)
    label = np.where(actor.reshape(shape) >= 0, actor_label[np.maximum(actor.reshape(shape), 0)], material_label[mat])
    keep = amp.ravel() > 0

    # the caster's form: static hits' attributes in per-triangle tables (here one triangle per ray, normals
    # of either sign: the kernel takes |cos|), the per-ray arrays hold the actor hits only
    static = actor < 0
    triangle = np.where(static & np.isfinite(distance), np.arange(m), -1)
    flip = np.where(rng.random((m, 1)) < 0.5, np.float32(-1), np.float32(1))
    tables = (np.vstack([normal * flip, np.zeros((1, 3), np.float32)]), np.append(material, np.int32(-1)),
              np.append(object_id, np.uint32(0)))  # fmt: skip
    per_ray = [np.where(static[:, None], np.float32(np.nan), normal), np.where(static, 0, material).astype(np.int32),
               np.where(static, 0, object_id).astype(np.uint32)]  # fmt: skip
    hits = (distance, triangle, per_ray[0], per_ray[1], actor, per_ray[2])
    args = (hits, tables, directions, rotation, reflectivity, retro, material_label, actor_label, weights, 1.0e5,
            *map(float, overlap), effects, scale, offset, two_way)  # fmt: skip
    *compact, segments = surface_returns(*args, True)
    beam, got_rng, got_amp, got_label, got_obj = compact_candidates(compact, segments)
    assert got_amp.tobytes() == amp.ravel()[keep].tobytes()
    assert got_rng.tobytes() == rng_m.ravel()[keep].tobytes()
    assert np.array_equal(beam, np.repeat(np.arange(shape[0]), n_sub)[keep])
    assert np.array_equal(got_label, label.ravel()[keep]) and np.array_equal(got_obj, object_id[keep])
    _, full_rng, full_amp, _, _, _ = surface_returns(*args, False)
    assert full_amp.tobytes() == amp.ravel().tobytes() and full_rng.tobytes() == rng_m.ravel().tobytes()


def test_points_match_numpy_assembly():
    sim = LidarSimulator(profile(), street(), backend="open3d", seed=3)
    frame = frames(sim)[0]
    p = frame.points
    assert p.dtype == POINT_DTYPE and len(p) > 500
    pattern = sim.pattern
    col = np.searchsorted(np.round(pattern.column_time_s * 1e9), p["time_stamp"])
    az = pattern.column_azimuth[col] + pattern.azimuth_offset[p["channel"]]
    el = pattern.elevation[p["channel"]]
    r = p["distance"].astype(np.float64)  # float32 of the float64 range: x, y, z agree to float32 rounding
    np.testing.assert_allclose(p["x"], r * np.cos(el) * np.cos(az), rtol=2e-7, atol=1e-6)
    np.testing.assert_allclose(p["z"], r * np.sin(el), rtol=2e-7, atol=1e-6)
    assert p["azimuth"].tobytes() == np.arctan2(np.sin(az), np.cos(az)).astype(np.float32).tobytes()
    assert p["elevation"].tobytes() == el.astype(np.float32).tobytes()
    # return types from echo numbers and beam changes, as Nebula defines them
    beam = col * 100 + p["channel"]
    last = np.append(beam[1:] != beam[:-1], True)
    first = p["echo"] == 1
    expected = np.where(first & last, 6, np.where(first, 2, np.where(last, 1, 7)))
    assert np.array_equal(p["return_type"], expected)


def test_threads_and_chunks_do_not_change_the_cloud(monkeypatch, chunked):
    clouds = []
    for threads in (1, 2):
        monkeypatch.setattr(workers, "THREADS", threads)
        sim = LidarSimulator(profile(), street(), backend="open3d", seed=5)
        clouds.append(b"".join(f.points.tobytes() for f in frames(sim)))
    assert clouds[0] == clouds[1] and len(clouds[0]) > 10000


def _weather_clouds(frames_wanted: int = 2) -> tuple[bytes, int]:
    """highway_spray on a VLP-16 with a dirty cover (cover + rain + spray), advanced every 10 ms: the bytes
    of its clouds and how many batches were detected in the background."""
    from lidar_weather_sim.scenario.schema import load_scenario
    from lidar_weather_sim.scenario.world import World

    data = load_scenario("highway_spray").model_dump()
    data["regions"] = ["cover", "atmosphere", "spray"]
    data["region_params"]["cover"] = {"texture": "3l"}
    world = World.build(type(load_scenario("highway_spray")).model_validate(data), "vlp16")
    sim = LidarSimulator.of_world(world, backend="open3d", seed=4)
    submitted = []
    pool = workers.background()
    real_submit = pool.submit

    def counting_submit(fn, *args):
        submitted.append(fn)
        return real_submit(fn, *args)

    pool.submit = counting_submit
    try:
        got, t = [], 0.0
        while len(got) < frames_wanted:
            t = round(t + 0.01, 9)
            got += sim.advance(t, world.player)
    finally:
        del pool.submit
    assert all(f.points.dtype == POINT_DTYPE for f in got)
    return b"".join(f.points.tobytes() for f in got), len(submitted)


def test_a_weather_cloud_is_the_same_with_regions_side_by_side_and_detection_in_the_background(monkeypatch):
    """Regions applied in parallel and each batch detected behind the next batch's cast (the
    simulator's pipeline, from PARALLEL_MIN_RAYS sub-rays a batch) give the bytes of one thread."""
    import lidar_weather_sim.sim.simulator as simulator

    monkeypatch.setattr(simulator, "PARALLEL_MIN_RAYS", 1000)  # a VLP-16 batch of 10 ms has ~8600 sub-rays
    monkeypatch.setattr(workers, "THREADS", 1)
    serial, background = _weather_clouds()
    assert background == 0
    monkeypatch.setattr(workers, "THREADS", 2)
    pipelined, background = _weather_clouds()
    assert background >= 15  # every batch of the two frames but the ones before the first column
    assert len(serial) > 100_000 and pipelined == serial


def test_an_error_in_a_background_detection_is_raised_by_the_simulator(monkeypatch):
    import lidar_weather_sim.sim.simulator as simulator

    monkeypatch.setattr(simulator, "PARALLEL_MIN_RAYS", 1)
    monkeypatch.setattr(workers, "THREADS", 2)

    def broken(self, *args):
        raise FloatingPointError("detection failed")

    monkeypatch.setattr(LidarSimulator, "_detect", broken)
    with pytest.raises(FloatingPointError, match="detection failed"):
        _weather_clouds(frames_wanted=1)


def test_a_process_forked_with_a_detection_in_the_background_finishes_the_frame(monkeypatch):
    """os.fork (a fork-based DataLoader, multiprocessing's default on Linux) while a batch is being detected in the
    background: the child has none of the parent's threads, yet it completes the frame with the same bytes."""
    import hashlib
    import os
    import signal

    import lidar_weather_sim.sim.simulator as simulator

    monkeypatch.setattr(simulator, "PARALLEL_MIN_RAYS", 1)
    monkeypatch.setattr(workers, "THREADS", 2)
    sim = LidarSimulator(profile(), street(), backend="open3d", seed=5, regions=[("faults", _dropout())])
    sim.advance(0.05, Motion())  # half a frame: its last batch is in the background
    assert sim._detection is not None
    read, write = os.pipe()
    pid = os.fork()
    if pid == 0:  # the child: finish the frame, send its hash, never return into pytest
        try:
            signal.alarm(60)
            frames = sim.advance(0.2, Motion())
            os.write(write, hashlib.sha256(frames[0].points.tobytes()).hexdigest().encode())
        finally:
            os._exit(0)
    os.close(write)
    child = os.read(read, 64).decode()
    os.waitpid(pid, 0)
    assert child == hashlib.sha256(sim.advance(0.2, Motion())[0].points.tobytes()).hexdigest()


def _dropout():
    from lidar_weather_sim.regions.base import REGISTRY, RegionContext

    return REGISTRY.create("faults", {"dropout_probability": 0.1}, RegionContext(profile=profile()))


def test_frames_of_several_batches_keep_the_point_layout():
    sim = LidarSimulator(profile(), street(), backend="open3d")
    got = frames(sim)
    assert len(got) >= 2
    assert all(f.points.dtype == POINT_DTYPE and f.points.flags.c_contiguous for f in got)


@pytest.mark.parametrize("ground_truth", [True, False])
def test_every_byte_of_a_cloud_is_written(monkeypatch, ground_truth):
    """Frame buffers come from np.empty: with garbage in fresh memory the clouds still equal the
    canonical layout (fields copied into zeros), so same seed => same bytes."""
    real_empty = np.empty

    def garbage_empty(shape, dtype=float, *args, **kwargs):
        a = real_empty(shape, dtype, *args, **kwargs)
        a.view(np.uint8)[...] = 0xA5
        return a

    monkeypatch.setattr(np, "empty", garbage_empty)
    sim = LidarSimulator(profile(), street(), backend="open3d", seed=2, ground_truth=ground_truth)
    for frame in frames(sim):
        canonical = np.zeros(len(frame.points), frame.points.dtype)
        for name in frame.points.dtype.names:
            canonical[name] = frame.points[name]
        assert len(frame.points) and frame.points.tobytes() == canonical.tobytes()


def test_workers_run_every_chunk_once_and_reraise(monkeypatch):
    monkeypatch.setattr(workers, "THREADS", 2)
    assert workers.run_chunks(lambda c: c * c, 20) == [c * c for c in range(20)]
    cuts = workers.bounds(1000, 64, align=128)
    assert cuts[0] == 0 and cuts[-1] == 1000 and np.all(cuts[1:-1] % 128 == 0) and np.all(np.diff(cuts) > 0)

    def boom(c):
        if c == 7:
            raise RuntimeError("chunk 7")

    with pytest.raises(RuntimeError, match="chunk 7"):
        workers.run_chunks(boom, 12)


def test_batched_actor_poses_equal_single_time_poses(tmp_path):
    from lidar_weather_sim.core.geometry import rpy_matrix
    from lidar_weather_sim.core.paths import maps_dir
    from lidar_weather_sim.scenario.player import ScenarioPlayer
    from lidar_weather_sim.scenario.schema import load_scenario
    from lidar_weather_sim.scene.opendrive import RoadNetwork

    scenario = load_scenario("highway_clear")
    extra = [
        {"id": 120, "lane": -1, "s_m": 30.0, "speed_m_s": 30.0},
        {"id": 121, "lane": -3, "s_m": 60.0, "speed_m_s": 20.0, "appear_s": 0.4,
         "lane_changes": [{"at_s": 0.2, "to_lane": -2, "duration_s": 1.5}]},
    ]  # fmt: skip
    scenario = scenario.model_validate({**scenario.model_dump(), "actors": scenario.model_dump()["actors"] + extra})
    player = ScenarioPlayer(scenario, RoadNetwork.from_xodr(maps_dir() / scenario.map))
    times = np.linspace(0.0, 2.0, 41)
    many = player.actor_poses_at(times)
    for t, poses in zip(times, many):
        assert list(poses) == list(player.actor_poses(float(t)))
        for actor_id, m in poses.items():
            actor, track = player.actors[actor_id]
            pos, heading = track.poses(np.array([t]))  # the per-actor evaluation
            want = np.eye(4)
            want[:3, :3] = rpy_matrix(0.0, 0.0, float(heading[0]))
            want[:3, 3] = pos[0]
            assert m.tobytes() == want.tobytes()
    assert 121 not in many[0] and 121 in many[-1]


def test_padded_sizes_are_few_and_cover():
    sizes = {_padded_size(n) for n in range(1, 70000)}
    assert all(_padded_size(n) >= n for n in (1, 255, 256, 257, 16384, 16385, 786432, 10**6 + 1))
    assert len(sizes) < 40 and _padded_size(786432) == 786432
    assert all(_padded_size(n) <= 1.125 * n for n in range(16385, 400000, 997))


@pytest.mark.skipif("mitsuba" not in available_backends(), reason="mitsuba unavailable")
def test_padded_mitsuba_casts_equal_unpadded():
    rng = np.random.default_rng(4)
    mesh = box_mesh((4.0, 2.0, 1.5), 0, 9)
    caster = SceneCaster(mesh, {}, backend="mitsuba")
    o = rng.uniform(-8, 8, (1000, 3)).astype(np.float32)
    d = rng.normal(size=(1000, 3))
    d = (d / np.linalg.norm(d, axis=1, keepdims=True)).astype(np.float32)
    part = caster._static
    for n in (3, 300, 1000):
        padded = caster._cast_part(part, o[:n], d[:n], "static")
        plain = part.caster.cast(o[:n], d[:n])
        assert padded[0].tobytes() == plain[0].tobytes() and np.array_equal(padded[1], plain[1])
        assert np.isfinite(padded[0]).any()



@pytest.mark.parametrize("n", [10, 5000])
def test_range_noise_is_numpys_normal_stream(n):
    """Drawn by numpy or numba (many draws): the values of ``rng.normal(0, sigma, n)``."""
    noise = range_noise(np.random.default_rng([1, 2, 3]), 0.01, n, Scratch())
    np.testing.assert_array_equal(noise, np.random.default_rng([1, 2, 3]).normal(0.0, 0.01, n))
