"""MemoCaster: the hits of rays cast before handed out again, the same bit for bit, and re-simulations through it."""

from dataclasses import fields

import numpy as np
import pytest

from lidar_weather_sim.references.measured import make_measured
from lidar_weather_sim.replay import Resimulator
from lidar_weather_sim.io.recording import Recording
from lidar_weather_sim.scene.mesh import TriangleMesh, box_mesh
from lidar_weather_sim.scene.raycast import SceneCaster, available_backends
from lidar_weather_sim.scene.raycast.memo_caster import MemoCaster
from lidar_weather_sim.scenario.effects import parse_effect
from lidar_weather_sim.scenario.schema import load_scenario

ACTOR = box_mesh((4.0, 1.8, 1.5), 2, 100, 0.05)


def pose(xyz, yaw: float = 0.0) -> np.ndarray:
    """4x4 body->map transform: yaw (rad) about z, then the translation (m)."""
    m = np.eye(4)
    m[:2, :2] = [[np.cos(yaw), -np.sin(yaw)], [np.sin(yaw), np.cos(yaw)]]
    m[:3, 3] = xyz
    return m


def _scene() -> SceneCaster:
    """A ground plane, three boxes and an actor's box."""
    ground = TriangleMesh(np.array([[-100.0, -100, 0], [100, -100, 0], [100, 100, 0], [-100, 100, 0]]),
                          np.array([[0, 1, 2], [0, 2, 3]]), 0, 1)  # fmt: skip
    boxes = [box_mesh((3.0, 2.0, 2.0), 1, 10 + i, 0.05).transformed(pose(xy + (0.0,), 0.3 * i))
             for i, xy in enumerate(((15.0, -4.0), (-10.0, 8.0), (5.0, 20.0)))]  # fmt: skip
    return SceneCaster(TriangleMesh.concatenate([ground, *boxes]), {100: ACTOR}, backend=available_backends()[0])


def random_rays(n: int, seed: int = 2) -> tuple[np.ndarray, np.ndarray]:
    """``n`` rays (float32 origins around the map origin, unit directions)."""
    rng = np.random.default_rng(seed)
    d = rng.normal(size=(n, 3))
    d[:, 2] = -np.abs(d[:, 2]) * 0.3  # mostly level or down: the ground, the boxes and the actor
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    return rng.uniform([-3, -3, 1.0], [3, 3, 2.0], (n, 3)).astype(np.float32), d.astype(np.float32)


def _same(a, b) -> bool:
    return all(np.array_equal(getattr(a, f.name), getattr(b, f.name), equal_nan=True) for f in fields(a))


@pytest.mark.parametrize("gather", [True, False])
def test_rays_cast_again_get_the_hits_of_the_first_cast_and_changing_them_changes_nothing_kept(gather):
    scene, memo = _scene(), MemoCaster(_scene())
    o, d = random_rays(20_000)
    poses = {100: pose((12.0, 3.0, 0.0), 0.4)}
    direct = scene.cast(o, d, poses, 80.0, gather=gather)
    first = memo.cast(o, d, poses, 80.0, gather=gather)
    actor_rows = (direct.triangle == -1) & np.isfinite(direct.distance)
    assert np.isfinite(direct.distance).mean() > 0.3 and actor_rows.any()
    assert (direct.hit_actor[actor_rows] == 100).all()
    # without gather only the actors' rows are set (a static hit has triangle >= 0; the rest is undefined memory)
    kept = actor_rows if not gather else slice(None)
    first.distance[:] = 0.0  # the simulator and the regions change hits in place
    first.normal[:] = 0.0
    again = memo.cast(o, d, poses, 80.0, gather=gather)
    assert memo.hits == 1
    assert np.array_equal(again.distance, direct.distance) and np.array_equal(again.triangle, direct.triangle)
    for name in ("normal", "material", "object_id", "hit_actor"):
        assert np.array_equal(getattr(again, name)[kept], getattr(direct, name)[kept]), name


def test_a_moved_ray_an_actor_moved_or_another_range_is_cast_anew():
    memo = MemoCaster(_scene())
    o, d = random_rays(5_000)
    poses = {100: pose((12.0, 3.0, 0.0))}
    memo.cast(o, d, poses, 80.0)
    tilted = d.copy()
    tilted[0, 2] += np.float32(1e-6)  # one direction one float32 step away (a channel's elevation offset)
    for args in ((o, tilted, poses, 80.0), (o, d, {100: pose((12.0, 3.01, 0.0))}, 80.0), (o, d, {}, 80.0),
                 (o, d, poses, 40.0)):  # fmt: skip
        direct = _scene().cast(*args)
        assert _same(memo.cast(*args), direct)
    assert memo.hits == 0


def test_beyond_its_budget_it_casts_without_keeping():
    o, d = random_rays(1_000)
    memo = MemoCaster(_scene(), max_bytes=1_000 * 64)  # one batch of 1000 rays: 36 bytes of hits a ray, 24 of rays
    memo.cast(o, d, {}, 80.0)
    memo.cast(o[:500], d[:500], {}, 80.0)  # would go over
    assert memo.kept_bytes <= memo.max_bytes
    assert _same(memo.cast(o[:500], d[:500], {}, 80.0), _scene().cast(o[:500], d[:500], {}, 80.0))
    memo.cast(o, d, {}, 80.0)
    assert memo.hits == 1  # the first batch was kept, the second was not


def test_a_resimulation_casts_each_frame_once_and_gives_the_points_of_a_fresh_simulator(tmp_path):
    """The gap search's evaluations: the same recorded frames with other weather, then the first again."""
    scenario = load_scenario("highway_clear")
    make_measured(scenario, [], tmp_path / "measured", frames=4, profile="scala4")
    recording = Recording.load(tmp_path / "measured")
    resim = Resimulator(recording, scenario, "scala4", keep_casts=True)
    weathers = ([], [parse_effect("atmosphere.rain:intensity=10")], [parse_effect("cover.dirt:transmission=0.7")], [])
    runs = [resim.frames(effects, [1, 2]) for effects in weathers]
    memo = resim.sim.caster
    batches = len(memo._kept) / 2  # each batch kept twice: gathered for the regions, and not for the clear runs
    assert batches >= 2 and memo.hits == (len(weathers) - 2) * batches  # the first clear and rain runs cast
    assert not isinstance(Resimulator(recording, scenario, "scala4").sim.caster, MemoCaster)
    for effects, points in zip(weathers, runs):
        expected = Resimulator(recording, scenario, "scala4").frames(effects, [1, 2])  # nothing kept
        assert all(np.array_equal(a, b) for a, b in zip(points, expected))
    assert not np.array_equal(runs[0][0], runs[1][0])  # the rain is in the points
    assert all(np.array_equal(a, b) for a, b in zip(runs[0], runs[3]))
