"""Spray physics: eq. 1-3, emission eq. 7-10, forces eq. 11-23, integrator, seeding."""

import numpy as np
import pytest
from scipy.integrate import solve_ivp

from lidar_weather_sim.physics.road import FILM_CONSTANT_K_S, water_film_mm
from lidar_weather_sim.regions.weather import Road
from spray_particles.model import calibration
from spray_particles.model.constants import load_constants
from spray_particles.model.emitter import ring_emission, vehicle_emitter
from spray_particles.model.forces import CurlNoise, drag_rates, thesis_drag_constant, thesis_wind_constant
from spray_particles.model.integrator import analytic_fall, integrate
from spray_particles.model.system import EmittingVehicle, SprayParams, SpraySystem
from spray_particles.model.water import (
    drop_mass_kg,
    mean_drop_diameter_m,
    tread_pickup_m3_s,
    tyre_dimensions,
)

C = load_constants()
G = C.physics.gravity_m_s2


# -- eq. 1-3 and the constants of config/spray.yaml --------------------------------------------
def test_config_constants_are_the_fits_to_the_thesis_tables(thesis_tables):
    spray = thesis_tables["spray"]
    ph = C.physics
    assert C.water.drop_size_k == pytest.approx(
        calibration.fit_drop_constant(spray, ph.water_surface_tension_n_m, ph.water_density_kg_m3), rel=2e-3)
    assert ph.drag_coefficient == pytest.approx(
        calibration.fit_drag_coefficient(spray, ph.air_density_kg_m3, ph.water_density_kg_m3), rel=5e-3)
    gain, v0 = calibration.fit_emission(spray)
    assert (C.emission.gain_per_mm_m_s, C.emission.threshold_speed_m_s) == pytest.approx((gain, v0), rel=1e-3)
    slope, v0 = calibration.fit_lateral_wind(spray)
    assert (C.lateral_wind.slope, C.lateral_wind.threshold_speed_m_s) == pytest.approx((slope, v0), rel=2e-3)
    road = Road()
    k_s = calibration.fit_film_constant(spray, 2.0, road.drainage_length_m, road.cross_slope)
    assert FILM_CONSTANT_K_S == pytest.approx(k_s, rel=2e-3)
    assert C.particles.diameter_m == pytest.approx(spray["particle_diameter_mm"] * 1e-3)
    assert C.particles.mesh_diameter_m == pytest.approx(spray["mesh_diameter_cm"] * 1e-2)
    assert C.particles.single_scattering_albedo == spray["single_scattering_albedo_water"]
    assert 1 - C.particles.single_scattering_albedo == pytest.approx(spray["materials"]["particles"]["absorption"])
    assert list(C.particles.lateral_field_range_m) == spray["lateral_wind_field_range_m"]
    assert C.tyre.size == spray["tyre"]


def test_eq1_film_grows_with_rain_and_texture_and_hits_the_highway_value(thesis_tables):
    road = Road(texture_depth_mm=thesis_tables["spray"]["highway"]["params"]["T_s"])
    h = road.film_mm(2.0)
    assert h == pytest.approx(thesis_tables["spray"]["highway"]["water_film_mm"][0], rel=2e-3)
    assert water_film_mm(8.0, 1.5, 11.25, 0.025, 1.0) / water_film_mm(2.0, 1.5, 11.25, 0.025, 1.0) == pytest.approx(2.0)
    assert water_film_mm(2.0, 1.644, 11.25, 0.025, 1.0) > water_film_mm(2.0, 0.208, 11.25, 0.025, 1.0)
    assert water_film_mm(0.0, 1.5, 11.25, 0.025, 1.0) == 0.0
    with pytest.raises(ValueError, match="slope"):
        water_film_mm(1.0, 1.5, 11.25, 0.0, 1.0)


def test_eq2_pickup_is_linear_in_film_and_speed():
    base = tread_pickup_m3_s(0.5, 10.0, 4, 0.01, 0.011)
    assert base == pytest.approx(0.5 / 3 * 10.0 * 4 * 0.01 * 0.011)
    assert tread_pickup_m3_s(1.0, 10.0, 4, 0.01, 0.011) == pytest.approx(2 * base)
    assert tread_pickup_m3_s(0.5, 20.0, 4, 0.01, 0.011) == pytest.approx(2 * base)
    assert tread_pickup_m3_s(5.0, 10.0, 4, 0.01, 0.011) == pytest.approx(tread_pickup_m3_s(3.0, 10.0, 4, 0.01, 0.011))


def test_eq3_reproduces_the_thesis_drop_size_example(thesis_tables):
    ex = thesis_tables["spray"]["drop_size_example"]
    d = mean_drop_diameter_m(ex["speed_kmh"] / 3.6, ex["tread_height_mm"] * 1e-3, C.water.drop_size_k)
    assert d * 1e6 == pytest.approx(ex["d_mean_um"], rel=2e-3)
    assert drop_mass_kg(d) == pytest.approx(ex["mass_kg"], rel=0.05)  # the thesis rounds
    assert mean_drop_diameter_m(2 * ex["speed_kmh"] / 3.6, 0.011, C.water.drop_size_k) == pytest.approx(d / 2)


def test_tyre_size_255_40_r19():
    r, w = tyre_dimensions("255/40R19")
    assert r == pytest.approx(0.5 * (19 * 0.0254 + 2 * 0.102))
    assert w == 0.255
    with pytest.raises(ValueError, match="'255-40'"):
        tyre_dimensions("255-40")


def test_eq19_eq23_give_the_table_constants(thesis_tables):
    """K_D (eq. 19) and K_Wx (eq. 23) of the 4 mm particle at the Tables' wind speeds."""
    spray = thesis_tables["spray"]
    ph = C.physics
    kappa, _ = drag_rates(spray["particle_diameter_mm"] * 1e-3, ph.drag_coefficient, ph.air_density_kg_m3,
                          ph.water_density_kg_m3, ph.air_viscosity_pa_s)  # fmt: skip
    cases = [(spray["proving_ground"]["by_speed"][s], s) for s in (39, 55)]
    cases.append((spray["highway"]["params"], spray["highway"]["speed_kmh"][0]))
    for p, speed_kmh in cases:
        assert thesis_drag_constant(kappa, p["L"]) == pytest.approx(p["K_D"], rel=0.01)
        v_w = p["wind_over_speed"] * speed_kmh / 3.6
        assert thesis_wind_constant(kappa, v_w) == pytest.approx(p["K_Wx"], rel=0.03)


# -- emission, eq. 7-10 ----------------------------------------------------------------------
def test_eq7_10_emission_vectors():
    n, v, r = 36, 15.0, 0.3433
    i = np.arange(n)
    px, pz, vx, vz = ring_emission(i, n, v, r, 0.0)
    assert (px[0], pz[0], vx[0], vz[0]) == pytest.approx((0, 0, 0, 0), abs=1e-12)  # vertex 0: contact, at rest
    assert np.hypot(px, pz - r) == pytest.approx(np.full(n, r))  # on the ring, centre at height r
    assert np.hypot(vx, vz) == pytest.approx(v * i / n)  # speed grows as v_c i / N
    assert px * vx + (pz - r) * vz == pytest.approx(np.zeros(n), abs=1e-9)  # tangential
    assert np.all((px * vz - (pz - r) * vx)[1:] > 0)  # counter-clockwise (thesis frame, car towards -x)
    q = n // 4  # explicit points: theta = 0 at i = N/4 (no phase advance)
    assert (px[q], pz[q], vx[q], vz[q]) == pytest.approx((r, r, 0.0, v / 4), abs=1e-9)
    assert (px[2 * q], pz[2 * q], vx[2 * q], vz[2 * q]) == pytest.approx((0.0, 2 * r, -v / 2, 0.0), abs=1e-9)
    # the phase advance v_c dt i / (N r) of eq. 7-10
    dt = 0.01
    px2, pz2, _, _ = ring_emission(q, n, v, r, dt)
    assert np.arctan2(pz2 - r, px2) == pytest.approx(v * dt * q / (n * r))


def test_body_frame_emitter_throws_backwards_from_behind_the_contact_point():
    r, w = tyre_dimensions("255/40R19")
    em = vehicle_emitter(4.7, 1.85, 1.45, r, w)
    rng = np.random.default_rng(0)
    pos, vel, side, wheel = em.emit(rng, np.array([500, 500, 500, 500]), 15.0, 0.0)
    assert len(pos) == 2000 and set(np.unique(side)) == {-1.0, 1.0}
    low_rear = np.zeros(len(pos), bool)
    for (wx, wy) in em.wheel_xy:
        m = (np.abs(pos[:, 1] - wy) < w) & (np.abs(pos[:, 0] - wx) <= r + 1e-9)
        low_rear |= m & (pos[:, 0] < wx) & (pos[:, 2] < r)  # behind the contact point, lower half
    assert np.all(vel[low_rear, 0] < 1e-9) and np.all(vel[low_rear, 2] >= -1e-9)  # thrown back and up
    assert len(np.unique(np.round(pos[:, 1], 6))) == 2 * em.treads  # 3 treads per side
    assert np.array_equal(np.bincount(wheel), [500] * 4)


# -- forces and integration ------------------------------------------------------------------
def test_release_without_wind_follows_the_analytic_fall_with_drag():
    kappa = 0.225
    t = np.arange(0, 1.0001, 0.01)
    _, _, track = integrate([[0, 0, 10.0]], [[0, 0, 0]], kappa, 0.0, G, 1.0, 0.01, samples=1)
    assert track[:, 0, 2] == pytest.approx(analytic_fall(10.0, kappa, G, t), abs=1e-5)
    assert np.all(track[:, 0, :2] == 0)


def test_stokes_drop_relaxes_to_its_settling_speed():
    kappa, lam = drag_rates(1e-4, 0.0, 1.225, 1000.0, 1.81e-5)  # linear drag only: exact exponential
    pos, vel = integrate([[0, 0, 1.0]], [[5.0, 0, 0]], 0.0, lam, G, 0.5, 0.01)
    t = 0.5
    assert vel[0, 0] == pytest.approx(5.0 * np.exp(-lam * t), rel=1e-6, abs=1e-9)
    assert vel[0, 2] == pytest.approx(-G / lam * (1 - np.exp(-lam * t)), rel=1e-6)


def _rhs(kappa, lam, air):
    def f(_, y):
        v = y[3:]
        rel = v - air
        a = -(kappa * np.linalg.norm(rel) + lam) * rel
        a[2] -= G
        return np.concatenate([v, a])

    return f


@pytest.mark.parametrize("speed_kmh", [40, 50, 60])
@pytest.mark.parametrize("k_d", [0.2, 0.5, 1.0])
def test_trajectories_match_solve_ivp_rk45_over_the_fig16_cases(thesis_tables, speed_kmh, k_d):
    """Thesis Fig. 16: a ring of 36 vertices (255/40R19), mass 1 and size 1 (kappa = K_D), 1 s of
    flight: every trajectory within 1 cm of scipy's RK45 (tight tolerances)."""
    cases = thesis_tables["spray"]["trajectory_check_cases"]
    assert speed_kmh in cases["speeds_kmh"] and k_d in cases["K_D"]
    r, _ = tyre_dimensions("255/40R19")
    v = speed_kmh / 3.6
    px, pz, vx, vz = ring_emission(np.arange(36), 36, v, r, 0.0)
    pos = np.stack([px, np.zeros(36), pz], 1)
    vel = np.stack([vx, np.zeros(36), vz], 1)
    _, _, track = integrate(pos, vel, k_d, 0.0, G, 1.0, 0.01, samples=1)
    t_eval = np.arange(101) * 0.01
    worst = 0.0
    for j in range(36):
        sol = solve_ivp(_rhs(k_d, 0.0, np.zeros(3)), (0, 1.0), np.concatenate([pos[j], vel[j]]), method="RK45",
                        t_eval=t_eval, rtol=1e-10, atol=1e-12)  # fmt: skip
        worst = max(worst, float(np.max(np.linalg.norm(track[:, j] - sol.y[:3].T, axis=1))))
    assert worst <= 0.01


def test_stiff_fine_drop_with_wind_stays_within_1_cm_of_solve_ivp():
    d = mean_drop_diameter_m(24.7, 0.011, C.water.drop_size_k)
    ph = C.physics
    kappa, lam = drag_rates(d, ph.drag_coefficient, ph.air_density_kg_m3, ph.water_density_kg_m3, ph.air_viscosity_pa_s)
    air = np.array([3.0, -1.0, 0.0])
    y0 = np.array([0, 0, 0.3, 24.7, 0, 4.0])
    pos, _ = integrate(y0[None, :3], y0[None, 3:], kappa, lam, G, 1.0, 0.01, air=air)
    sol = solve_ivp(_rhs(kappa, lam, air), (0, 1.0), y0, method="Radau", rtol=1e-10, atol=1e-12)
    assert np.linalg.norm(pos[0] - sol.y[:3, -1]) <= 0.01


def test_curl_noise_is_divergence_free_seeded_and_unit_rms():
    noise = CurlNoise(3, 1.0)
    rng = np.random.default_rng(1)
    x = rng.uniform(-5, 5, (2000, 3))
    h = 1e-5
    div = sum((noise.velocity(x + h * e, 0.2) - noise.velocity(x - h * e, 0.2))[:, k] / (2 * h)
              for k, e in enumerate(np.eye(3)))  # fmt: skip
    assert np.max(np.abs(div)) < 1e-5
    u = noise.velocity(x, 0.2)
    assert np.sqrt(np.mean(np.sum(u * u, 1))) == pytest.approx(1.0, rel=0.25)
    assert np.array_equal(u, CurlNoise(3, 1.0).velocity(x, 0.2))
    assert not np.array_equal(u, CurlNoise(4, 1.0).velocity(x, 0.2))


# -- the system ---------------------------------------------------------------------------------
def _car(speed=20.0, y=0.0):
    r, w = tyre_dimensions(C.tyre.size)
    vehicle = EmittingVehicle(100, 4.7, 1.85, 1.45, 0.15, vehicle_emitter(4.7, 1.85, 1.45, r, w))

    def poses(t):
        m = np.eye(4)
        m[:3, 3] = (speed * t, y, 0.0)
        return {100: m}

    return vehicle, poses


def _run(duration=2.0, speed=20.0, **params):
    vehicle, poses = _car(speed)
    system = SpraySystem([vehicle], poses, SprayParams(**{"water_film_mm": 0.7, **params}))
    system.advance_to(0.0)
    system.advance_to(duration)
    return system


def test_same_seed_same_particles_and_independent_of_how_time_is_split():
    a = _run(seed=5)
    b = _run(seed=5)
    vehicle, poses = _car()
    c = SpraySystem([vehicle], poses, SprayParams(water_film_mm=0.7, seed=5))
    c.advance_to(0.0)
    for t in np.linspace(0.013, 2.0, 37):
        c.advance_to(t)
    d = _run(seed=6)
    assert len(a.particles) > 100
    assert np.array_equal(a.particles.pos, b.particles.pos) and np.array_equal(a.particles.pos, c.particles.pos)
    assert len(d.particles) != len(a.particles) or not np.array_equal(a.particles.pos, d.particles.pos)


def test_spray_lies_behind_the_emitting_wheels_and_low():
    s = _run(speed=20.0, mist_packets_per_wheel_per_tick=0.0, turbulence_intensity=0.0)
    p = s.particles
    body = p.pos - np.array([20.0 * s.time_s, 0, 0])
    wheel_x = s.vehicles[0].emitter.wheel_xy[p.wheel, 0]
    assert len(p) > 50
    settled = p.age > 0.1  # fresh particles from the front of the tread still travel down and back
    assert np.mean(body[settled, 0] < wheel_x[settled]) > 0.95  # behind the wheel that threw them
    assert np.all(body[:, 0] < wheel_x + s.vehicles[0].emitter.radius_m + 0.3)
    assert np.all(body[:, 2] >= 0) and np.percentile(body[:, 2], 95) < 1.5
    far = body[:, 0] < -2.35 - 1.0  # beyond the rear bumper: in the two wheel tracks
    assert far.sum() > 10 and np.all(np.abs(body[far, 1]) < 1.85)


def test_spray_drifts_with_lateral_wind():
    calm = _run(speed=15.0, turbulence_intensity=0.0)
    windy = _run(speed=15.0, turbulence_intensity=0.0, ambient_wind_m_s=(0.0, -4.0, 0.0))
    behind = lambda s: s.particles.pos[s.particles.pos[:, 0] < 15.0 * s.time_s - 3.0]  # noqa: E731
    assert np.mean(behind(windy)[:, 1]) < np.mean(behind(calm)[:, 1]) - 0.3


def test_lateral_fields_pull_the_wheel_tracks_together():
    wide = _run(speed=24.7, lateral_wind_scale=0.0, turbulence_intensity=0.0, mist_packets_per_wheel_per_tick=0.0)
    pulled = _run(speed=24.7, lateral_wind_scale=1.0, turbulence_intensity=0.0, mist_packets_per_wheel_per_tick=0.0)

    def spread(s):
        p = s.particles
        x = p.pos[:, 0] - 24.7 * s.time_s
        m = (x < -2.35 - 1.0) & (x > -2.35 - 6.0)
        return np.mean(p.pos[m & (p.side > 0), 1]) - np.mean(p.pos[m & (p.side < 0), 1])

    assert spread(pulled) < spread(wide) - 0.1


def test_more_speed_more_particles_emitted():
    assert _run(speed=10.0).emitted < _run(speed=15.0).emitted < _run(speed=25.0).emitted
    # no inertial particles below the fitted threshold speed (drop packets carry the water of any speed)
    assert _run(speed=7.0, mist_packets_per_wheel_per_tick=0.0).emitted == 0


def test_inertial_scale_zero_leaves_the_same_drop_packets_alone():
    """``inertial_scale`` 0 (the droplet reference's like, which has no inertial particles): no population 0,
    and the drop packets those of the full system bit for bit (each population draws from its own generator)."""
    full, packets = _run(seed=3), _run(seed=3, inertial_scale=0.0)
    keep = full.particles.population == 1
    assert (full.particles.population == 0).sum() > 50
    assert (packets.particles.population == 1).all() and keep.sum() > 50
    assert np.array_equal(full.particles.pos[keep], packets.particles.pos)
    assert np.array_equal(full.particles.airborne[keep], packets.particles.airborne)


def test_particles_die_on_the_ground_the_body_and_at_their_lifetime():
    s = _run(duration=3.0, lifetime_s=0.3, mist_lifetime_s=0.3)
    assert np.all(s.particles.age < 0.3 + 1e-9)
    p = s.particles
    body = p.pos - np.array([20.0 * s.time_s, 0, 0])
    inside = (np.abs(body[:, 0]) < 2.35) & (np.abs(body[:, 1]) < 0.925) & (body[:, 2] > 0.15) & (body[:, 2] < 1.45)
    arch = np.zeros(len(p), bool)
    for wx in (1.41, -1.41):
        arch |= (body[:, 0] - wx) ** 2 + (body[:, 2] - 0.3433) ** 2 < 0.3933**2
    assert not np.any(inside & ~arch)


def test_ball_share_above_the_ground_is_the_spherical_cap_volume():
    from spray_particles.model.system import ball_share_above

    r = np.array([1.0, 1.0, 1.0, 1.0, 0.5])
    share = ball_share_above(np.array([2.0, 0.0, -2.0, 0.5, 0.25]), r)
    # cap h = 0.5 below a unit ball: pi h^2 (3r - h) / 3 = 0.6545 of 4.1888 (the same share at half size)
    assert share == pytest.approx([1.0, 0.5, 0.0, 1.0 - 0.6545 / 4.1888, 1.0 - 0.6545 / 4.1888], abs=1e-4)


def test_drop_packets_deposit_what_reaches_the_ground_and_lose_it_for_good():
    s = _run(duration=1.5, turbulence_intensity=0.0)
    p = s.particles
    packets = p.population == 1
    assert packets.any() and np.all(p.airborne[packets] <= 1.0) and np.any(p.airborne[packets] < 0.99)
    assert np.all(p.airborne[~packets] == 1.0)


def test_drop_packets_are_flattened_only_near_the_ground():
    """In free flight a packet spreads alike in every direction; near the ground its height is capped at the
    settling layer K / w_s, or at its centre's height where that is more."""
    from spray_particles.model.system import _packet_axes

    g, r0, k = 9.81, 0.05, 0.2  # K = 0.2 m^2/s at 0.5 s: horizontal sqrt(r0^2 + 2 K t) = 0.45 m
    kappa = g / 2.0**2  # settling at w_s = 2 m/s (no Stokes drag): K / w_s = 0.1 m
    above = np.array([1.0, 0.3, 0.05, -0.2])
    n = len(above)
    horizontal, vertical = _packet_axes(r0, np.full(n, k), np.full(n, 0.5), np.full(n, kappa), np.zeros(n), above, g)
    assert horizontal == pytest.approx(np.full(n, 0.45), abs=1e-12)
    assert vertical == pytest.approx([0.45, 0.3, 0.1, 0.1], abs=1e-12)

    s = _run(duration=1.5)  # the system's packets: their own heights above the ground plane
    packets = s.particles.population == 1
    h, v = s.mist_radii(s.time_s)
    above = s.heights_above_ground(s.particles.pos)
    free, flat = packets & (above >= h), packets & (v < h)
    assert free.sum() > 20 and flat.sum() > 20 and np.all(v[packets] <= h[packets])
    assert np.array_equal(v[free], h[free]) and np.all(v[flat] >= np.maximum(above[flat], 0.05))


def test_air_velocity_kernel_equals_the_numpy_reference():
    s = _run(duration=1.0, speed=24.7)
    rot, org, vel, _ = s._vehicle_state(s.tick_index)
    assert len(s.particles) > 100
    fast = s.air_velocity(s.particles, s.time_s, rot, org, vel)
    assert fast == pytest.approx(s.air_velocity_reference(s.particles, s.time_s, rot, org, vel), abs=1e-9)
