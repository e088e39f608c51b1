"""The fast paths of the particle system give bit for bit what the stage-by-stage numpy code gave.

Same seed, same particles: the fused numba tick (spray_particles.kernels.fused) against the numpy
stages kept for big particle sets, the emitter kernel against eq. 7-10 in numpy, the
per-tick generators against ``np.random.default_rng``.
"""

import numpy as np

from spray_particles.model import system as system_module
from spray_particles.model.constants import load_constants
from spray_particles.model.emitter import ring_emission, vehicle_emitter
from spray_particles.model.seeds import TickGenerators
from spray_particles.model.system import EmittingVehicle, SprayParams, SpraySystem
from spray_particles.model.water import tyre_dimensions

C = load_constants()


def _system(seed=3):
    r, w = tyre_dimensions(C.tyre.size)
    vehicle = EmittingVehicle(100, 4.7, 1.85, 1.45, 0.15, vehicle_emitter(4.7, 1.85, 1.45, r, w))
    prm = SprayParams(water_film_mm=0.7, film_cv=0.57, wind_over_speed=1.0, seed=seed)
    return SpraySystem([vehicle], _Track().actor_poses, prm, C)


class _Track:
    """A car at 89 km/h turning slowly (so the body frame is not the world frame); like the scenario
    player it also gives the poses at many times at once."""

    def actor_poses(self, t):
        m = np.eye(4)
        yaw = 0.05 * t
        m[:2, :2] = [[np.cos(yaw), -np.sin(yaw)], [np.sin(yaw), np.cos(yaw)]]
        m[:3, 3] = (24.7 * t, 0.5 * t * t, 0.0)
        return {100: m}

    def actor_poses_at(self, times):
        return [self.actor_poses(float(t)) for t in times]


def _fields(p):
    return {f: getattr(p, f) for f in p.__dataclass_fields__}


def test_fused_tick_equals_the_numpy_stages(monkeypatch):
    fused = _system()
    fused.advance_to(0.0)
    fused.advance_to(1.5)
    monkeypatch.setattr(system_module, "PARALLEL_FROM", 0)  # every tick through the numpy stages
    staged = _system()
    staged.advance_to(0.0)
    staged.advance_to(1.5)
    a, b = _fields(fused.particles), _fields(staged.particles)
    assert len(fused.particles) > 500 and np.any(a["population"] == 1) and np.any(a["airborne"] < 1.0)
    for name in a:
        assert a[name].dtype == b[name].dtype, name
        assert np.array_equal(a[name], b[name]), name


def test_a_tick_shared_by_threads_moves_the_particles_as_one_call(monkeypatch):
    """The simulator's threads move a tick's particles in chunks of rows: the particles are those of one call."""
    monkeypatch.setattr(system_module, "MOVE_CHUNK_MIN", 10**9)
    whole = _system()
    whole.advance_to(0.0)
    whole.advance_to(1.5)
    monkeypatch.setattr(system_module, "MOVE_CHUNK_MIN", 64)
    monkeypatch.setattr(system_module.workers, "THREADS", 3)  # three chunks, whatever this machine has
    chunked = _system()
    chunked.advance_to(0.0)
    chunked.advance_to(1.5)
    a, b = _fields(whole.particles), _fields(chunked.particles)
    assert len(whole.particles) > 500
    assert all(np.array_equal(a[name], b[name]) for name in a)


def test_emitter_kernel_equals_eq7_10_in_numpy():
    r, w = tyre_dimensions(C.tyre.size)
    em = vehicle_emitter(4.7, 1.85, 1.45, r, w)
    counts = np.array([7, 0, 30, 3])
    pos, vel, side, wheel = em.emit(np.random.default_rng(4), counts, 24.7, 0.01)
    draws = np.random.default_rng(4).random((counts.max(), em.n_wheels, 2))
    u = np.concatenate([draws[:c, k] for k, c in enumerate(counts)])
    vertex = np.minimum((u[:, 0] * em.n_vertices).astype(np.int64), em.n_vertices - 1)
    tread = np.minimum((u[:, 1] * em.treads).astype(np.int64), em.treads - 1)
    px, pz, vx, vz = ring_emission(vertex, em.n_vertices, 24.7, em.radius_m, 0.01)
    w_of = np.repeat(np.arange(4), counts)
    expected = np.stack([em.wheel_xy[w_of, 0] - px, em.wheel_xy[w_of, 1] + em.tread_offsets_m[tread], pz], -1)
    assert np.array_equal(pos, expected)
    assert np.array_equal(vel, np.stack([-vx, np.zeros(len(u)), vz], -1))
    assert np.array_equal(side, np.where(em.wheel_xy[w_of, 1] >= 0, 1.0, -1.0)) and np.array_equal(wheel, w_of)


def test_tick_generators_are_default_rng_of_the_same_words():
    generators = TickGenerators(2)
    rng = np.random.default_rng(0)
    for trial in range(300):
        words = [int(w) for w in rng.integers(0, 2**32, rng.integers(1, 8))] + [0] * (trial % 2)
        expected = np.random.default_rng(words)
        drawn = generators.get(words, trial % 2)
        assert np.array_equal(drawn.random(3), expected.random(3)), words
        assert np.array_equal(drawn.normal(size=3), expected.normal(size=3)) and drawn.gamma(3.0) == expected.gamma(3.0)


def test_hit_returns_equal_the_optical_depth_formula_in_numpy():
    from spray_particles.region import _hit_geometry, _hit_returns

    rng = np.random.default_rng(2)
    n_hits, n_particles = 500, 60
    population = rng.integers(0, 2, n_particles).astype(np.uint8)
    weight, diameter = rng.uniform(1, 1e4, n_particles), rng.uniform(1e-4, 4e-3, n_particles)
    airborne, radius = rng.uniform(0, 1, n_particles), rng.uniform(0.01, 0.8, n_particles)
    vertical = radius * rng.uniform(0.2, 1.0, n_particles)
    rays, idx = rng.permutation(3000)[:400], rng.permutation(n_particles)[:40]
    ray, sphere = rng.integers(0, 400, n_hits), rng.integers(0, 40, n_hits)
    entry, half_chord, cos_incidence = rng.uniform(1, 30, n_hits), rng.uniform(0, 0.8, n_hits), rng.uniform(0, 1, n_hits)
    max_range = np.where(rng.random(400) < 0.3, rng.uniform(1, 40, 400), 1e9)
    beam, sub, particle, range_m, chord, tau, packet = _hit_geometry(
        ray, sphere, entry, half_chord, rays, idx, max_range, 3, population, weight * (np.pi / 4.0) * diameter**2 * airborne,
        radius, vertical)  # fmt: skip
    reflectance, occlusion, range_m = _hit_returns(packet, -np.expm1(-tau), cos_incidence, range_m, chord, 0.53, 0.11)
    # the numpy expressions the region used before its kernels
    i = idx[sphere]
    mist = population[i] == 1
    chord_np = np.minimum(2.0 * half_chord, max_range[ray] - entry)
    cross_section = (weight * (np.pi / 4.0) * diameter**2 * airborne)[i]
    density = cross_section / (4.0 / 3.0 * np.pi * radius[i] ** 2 * vertical[i])
    opacity = np.where(mist, -np.expm1(-density * chord_np), 1.0)
    phase = np.where(mist, 0.11, cos_incidence)
    assert np.array_equal(beam * 3 + sub, rays[ray]) and np.array_equal(particle, i)
    assert np.array_equal(occlusion, opacity) and np.array_equal(reflectance, 0.53 * phase * opacity)
    assert np.array_equal(range_m, entry + np.where(mist, 0.5 * chord_np, 0.0))


def test_region_radii_are_the_packet_axes_of_the_system():
    from lidar_weather_sim.regions.base import REGISTRY, RegionContext
    from lidar_weather_sim.testing.fixtures import simple_profile

    region = REGISTRY.create("spray", {}, RegionContext(simple_profile()))
    region.system = _system()
    region.system.advance_to(0.0)
    region.system.advance_to(0.7)
    packet = region.system.particles.population == 1
    horizontal, vertical = region.system.mist_radii(0.7042)
    fast = region.radii(0.7042)
    assert packet.any() and not packet.all()
    assert np.array_equal(fast[0], np.where(packet, horizontal, region.radius_m))
    assert np.array_equal(fast[1], np.where(packet, vertical, region.radius_m))
