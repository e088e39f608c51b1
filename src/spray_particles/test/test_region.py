"""The `spray` region plugin: ray-sphere intersection, echo order, occlusion, scenarios, seeding."""

import numpy as np
import pytest

from lidar_weather_sim.core.config import ConfigError
from lidar_weather_sim.core.points import Label
from lidar_weather_sim.regions.base import REGISTRY, RegionContext
from lidar_weather_sim.regions.topic_inputs import TopicInputs
from lidar_weather_sim.scenario.schema import load_scenario
from lidar_weather_sim.scenario.world import World
from lidar_weather_sim.sim.simulator import LidarSimulator
from lidar_weather_sim.testing.fixtures import one_frame, scene_of, simple_profile, wall
from spray_particles.sensing.particle_cloud import TOPIC_FIELDS, TOPIC_PARTICLES, particle_cloud
from spray_particles.sensing.raycast import origin_spread, rays_in_cone, sphere_hits
from spray_particles.region import SprayRegion
from spray_particles.model.system import Particles


def test_spray_is_registered_by_entry_point():
    assert "spray" in REGISTRY.names()
    assert REGISTRY.get("spray") is SprayRegion


def test_sphere_hits_equal_brute_force_for_cm_spheres_at_50_m_including_the_azimuth_seam():
    rng = np.random.default_rng(0)
    n_rays, radius = 4000, 0.009
    az = rng.uniform(-np.pi, np.pi, n_rays)
    el = rng.uniform(-0.05, 0.05, n_rays)
    d = np.stack([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)], 1)
    o = rng.normal(0, 0.05, (n_rays, 3))  # origins spread like a rolling shutter
    rng_m = rng.uniform(5, 50, n_rays)
    on_ray = o + rng_m[:, None] * d  # half the spheres near a ray, some across the +-pi seam
    c = np.concatenate([on_ray[:1500] + rng.normal(0, 0.008, (1500, 3)), rng.uniform(-50, 50, (1500, 3))])
    c[:20] = np.array([-30.0, 0.0, 0.0]) + rng.normal(0, 0.3, (20, 3))
    max_range = np.full(n_rays, 1e9)
    hits = sphere_hits(o, d, max_range, c, radius)
    v = c[None, :, :] - o[:, None, :]
    t = np.einsum("rpk,rk->rp", v, d)
    perp2 = np.einsum("rpk,rpk->rp", v, v) - t * t
    entry = t - np.sqrt(np.maximum(radius**2 - perp2, 0))
    brute = np.argwhere((perp2 < radius**2) & (entry > 0))
    got = np.stack([hits.ray, hits.sphere], 1)
    assert len(brute) > 500
    assert {tuple(x) for x in got} == {tuple(x) for x in brute}
    assert hits.range_m == pytest.approx(entry[hits.ray, hits.sphere], abs=1e-9)


def test_the_broad_phase_marks_the_rays_in_a_cone_and_the_origins_spread_as_numpy_computes_them():
    """The region's broad phase (per emitting vehicle, the rays within a cone around its particles' bounds): the
    kernels against the numpy expressions they replaced, on seeded rays (none within 1e-9 of the cone's edge)."""
    rng = np.random.default_rng(4)
    d = rng.normal(size=(20000, 3))
    d /= np.linalg.norm(d, axis=1)[:, None]
    axis = np.array([0.6, 0.0, 0.8])
    cos_half = float(np.cos(0.3))
    d = d[np.abs(d @ axis - cos_half) > 1e-9]
    mask = np.zeros(len(d), bool)
    mask[:5] = True  # marks already set stay set (the mask gathers every vehicle's cone)
    assert rays_in_cone(d, axis, cos_half, mask)
    expected = d @ axis >= cos_half
    expected[:5] = True
    assert np.array_equal(mask, expected) and 200 < expected.sum() < len(d) // 2
    empty = np.zeros(len(d), bool)
    assert not rays_in_cone(d, axis, 1.5, empty) and not empty.any()  # a cone no ray lies in
    origins = rng.normal(0.0, 0.05, (700, 3)) + np.array([10.0, -3.0, 1.5])
    ref, spread = origin_spread(origins)
    assert ref == pytest.approx(origins.mean(axis=0), abs=1e-12)
    assert spread == pytest.approx(np.linalg.norm(origins - origins.mean(axis=0), axis=1).max(), abs=1e-12)


@pytest.mark.parametrize("slice_rad", [0.6, 2 * np.pi])
def test_sphere_hits_of_a_batch_in_a_slice_of_the_circle_are_every_pair_in_azimuth_order(slice_rad):
    """A batch of columns spans a slice (OS1-128's 10 ms: 0.6 rad): its rays' cell table covers that slice. Every
    (ray, sphere) pair the brute force finds, and each sphere's hits in the order of equal azimuth bins, then ray."""
    from spray_particles.sensing.raycast import AZIMUTH_BINS

    rng = np.random.default_rng(7)
    n_rays = 20000
    az = rng.uniform(-slice_rad / 2, slice_rad / 2, n_rays) + 0.3
    el = rng.uniform(-0.3, 0.2, n_rays)
    d = np.stack([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)], 1)
    o = rng.normal(0, 0.02, (n_rays, 3))
    c_az = rng.uniform(-0.5, 0.5, 400) * min(slice_rad, 1.0) + 0.3
    c = np.stack([15 * np.cos(c_az), 15 * np.sin(c_az), rng.uniform(-3, 1, 400)], 1)
    radius = rng.uniform(0.05, 0.3, 400)
    hits = sphere_hits(o, d, np.full(n_rays, 1e9), c, radius)
    v = c[None, :, :] - o[:, None, :]
    t = np.einsum("rpk,rk->rp", v, d)
    perp2 = np.einsum("rpk,rpk->rp", v, v) - t * t
    brute = np.argwhere((perp2 < radius**2) & (t - np.sqrt(np.maximum(radius**2 - perp2, 0)) > 0))
    assert len(brute) > 1000
    assert {tuple(x) for x in np.stack([hits.ray, hits.sphere], 1)} == {tuple(x) for x in brute}
    az_bin = np.floor((np.arctan2(d[:, 1], d[:, 0]) + np.pi) * AZIMUTH_BINS / (2 * np.pi)).astype(np.int64)
    for sphere in np.unique(hits.sphere):
        rays = hits.ray[hits.sphere == sphere]
        key = az_bin[rays] * n_rays + rays
        assert np.all(np.diff(key) > 0)


def _region_with(centres, profile):
    """A spray region whose particle system holds fixed spheres (no emitters)."""
    region = REGISTRY.create("spray", {}, RegionContext(profile))
    n = len(centres)
    region.system.particles = Particles(np.asarray(centres, float), np.zeros((n, 3)), np.zeros(n), np.full(n, 10.0),
                                        np.zeros(n), np.zeros(n), np.zeros(n, np.int64), np.ones(n),
                                        np.zeros(n, np.uint8), np.zeros(n, np.int64), np.full(n, 0.004), np.ones(n), np.zeros(n),
                                        np.ones(n))  # fmt: skip
    region.system.tick_index = 0
    region.system.params = region.system.params.model_copy(update={"tick_s": 1e9})  # no ticks: the spheres stay put
    region._actor_ids = np.array([100], np.uint32)
    return region


def test_sphere_hits_of_flat_ellipsoids_equal_the_quadratic_solution():
    rng = np.random.default_rng(1)
    n_rays = 3000
    az, el = rng.uniform(-0.6, 0.6, n_rays), rng.uniform(-0.1, 0.1, n_rays)
    d = np.stack([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)], 1)
    o = np.zeros((n_rays, 3))
    c = np.stack([rng.uniform(3, 20, 200), rng.uniform(-8, 8, 200), rng.uniform(-1, 1, 200)], 1)
    r, h = rng.uniform(0.2, 0.6, 200), rng.uniform(0.05, 0.2, 200)
    c[:3] = [[0.1, 0.05, 0.01], [-0.1, 0.0, -0.02], [0.0, 0.1, 0.0]]  # around the origin: rays start inside
    hits = sphere_hits(o, d, np.full(n_rays, 1e9), c, r, h)
    # (x - c)^2 / r^2 + (y - c)^2 / r^2 + (z - c)^2 / h^2 = 1 along x = t d: a t^2 - 2 b t + q = 0
    w = np.array([1.0, 1.0, 0.0])[None, None, :] / r[None, :, None] ** 2 + np.array([0, 0, 1.0]) / h[None, :, None] ** 2
    a = np.einsum("rk,rpk->rp", d * d, w)
    b = np.einsum("rk,rpk->rp", d, w * c[None])
    q = np.einsum("pk,rpk->rp", c * c, w) - 1.0
    disc = b * b - a * q
    entry = (b - np.sqrt(np.maximum(disc, 0))) / a
    leave = (b + np.sqrt(np.maximum(disc, 0))) / a
    brute = np.argwhere((disc > 0) & (leave > 0))
    inside = entry <= 0  # the chord from the ray's origin to where it leaves
    assert len(brute) > 100 and inside[brute[:, 0], brute[:, 1]].sum() > 1000
    assert {tuple(x) for x in np.stack([hits.ray, hits.sphere], 1)} == {tuple(x) for x in brute}
    assert hits.range_m == pytest.approx(np.where(inside, 0.0, entry)[hits.ray, hits.sphere], abs=1e-9)
    half_chord = np.where(inside, 0.5 * leave, np.sqrt(np.maximum(disc, 0)) / a)
    assert hits.half_chord_m == pytest.approx(half_chord[hits.ray, hits.sphere], abs=1e-9)


def test_a_particle_on_the_ray_gives_the_first_echo_and_hides_the_vehicle_behind_it():
    profile = simple_profile()
    scene = scene_of(wall(20.0, "car_paint", 100))
    clear = one_frame(LidarSimulator(profile, scene, regions=[])).points
    region = _region_with([[10.0, 0.0, 0.0], [10.0, 0.9, 0.0]], profile)  # on the 0 deg beam; between beams
    frame = one_frame(LidarSimulator(profile, scene, regions=[("spray", region)])).points
    centre = frame[np.abs(frame["azimuth"]) < 1e-6]
    assert list(centre["label"]) == [Label.SPRAY] and centre["object_id"][0] == 100
    assert centre["distance"][0] == pytest.approx(10.0 - 0.009, abs=1e-3)
    assert len(frame) == len(clear)  # one beam's wall return replaced by spray, no other beam touched


def test_spray_occludes_the_vehicle_on_some_subrays_and_keeps_echo_order():
    """scala4-like beams of 3 sub-rays: a particle on one sub-ray gives a first spray echo and the
    vehicle behind it stays as a later echo of the same beam."""
    profile = simple_profile(optics__divergence_v_mrad=14.0, optics__subrays_v=3)
    scene = scene_of(wall(20.0, "car_paint", 100))
    from lidar_weather_sim.sensor.scan import ScanPattern

    table = ScanPattern(profile).direction_table(0)
    column = int(np.argmin(np.abs(np.arctan2(table[:, 0, 1, 1], table[:, 0, 1, 0]))))
    upper = table[column, 0, 2]  # the upper sub-ray of the central beam
    region = _region_with([8.0 * upper], profile)
    frame = one_frame(LidarSimulator(profile, scene, regions=[("spray", region)])).points
    centre = frame[np.abs(frame["azimuth"]) < 1e-6]
    assert list(centre["label"]) == [Label.SPRAY, Label.VEHICLE]  # (car paint)
    assert list(centre["echo"]) == [1, 2] and centre["distance"][0] < centre["distance"][1]


def _packet_region(distance_m: float, cross_section_m2: float, radius_m: float, profile):
    """A spray region holding one drop packet of ``radius_m`` (m, spread over 1 s) on the 0 deg beam."""
    region = _region_with([[distance_m, 0.0, 0.0]], profile)
    p = region.system.particles
    p.population[:] = 1
    p.diameter[:] = 2e-4
    p.weight[:] = cross_section_m2 / (np.pi / 4.0 * 2e-4**2)
    r0 = region.constants.mist.initial_radius_m
    p.diffusivity[:] = (radius_m**2 - r0**2) / 2.0
    p.age[:] = 1.0
    return region


def test_a_drop_packet_is_seen_by_its_optical_depth_near_but_not_far():
    """The same dilute packet (10 cm^2 of drops in a 0.3 m ball: tau 0.0053 through its middle) gives an
    echo 3 m from the sensor, from the middle of its chord, and none at 30 m (1/R^2); a dense one
    (tau 5.3) at 30 m hides the wall behind it."""
    profile = simple_profile()
    scene = scene_of(wall(40.0, "car_paint", 100))
    centre_of = lambda frame: frame[np.abs(frame["azimuth"]) < 1e-6]  # noqa: E731
    near = centre_of(one_frame(LidarSimulator(profile, scene, regions=[("spray", _packet_region(3.0, 1e-3, 0.3, profile))])).points)
    assert list(near["label"]) == [Label.SPRAY, Label.VEHICLE]
    assert near["distance"][0] == pytest.approx(3.0, abs=0.02)
    far = centre_of(one_frame(LidarSimulator(profile, scene, regions=[("spray", _packet_region(30.0, 1e-3, 0.3, profile))])).points)
    assert list(far["label"]) == [Label.VEHICLE]
    dense = centre_of(one_frame(LidarSimulator(profile, scene, regions=[("spray", _packet_region(30.0, 1.0, 0.3, profile))])).points)
    clear = centre_of(one_frame(LidarSimulator(profile, scene, regions=[])).points)
    assert dense["label"][0] == Label.SPRAY
    assert list(clear["label"]) == [Label.VEHICLE] and Label.VEHICLE not in list(dense["label"])


def test_a_sensor_inside_a_dense_drop_packet_loses_what_lies_behind_it():
    """A packet around the sensor (semi-axes 0.5 m, 5 cm high on the ground plane): the optical depth of the
    chord from the sensor to where the beam leaves it dims the wall behind (tau 19 hides it); a dilute one
    (tau 0.01) keeps it, behind the packet's own echo from the chord's middle."""
    profile = simple_profile()
    scene = scene_of(wall(40.0, "car_paint", 100))
    centre_of = lambda frame: frame[np.abs(frame["azimuth"]) < 1e-6]  # noqa: E731
    dense = centre_of(one_frame(LidarSimulator(profile, scene, regions=[("spray", _packet_region(0.0, 2.0, 0.5, profile))])).points)
    dilute = centre_of(one_frame(LidarSimulator(profile, scene, regions=[("spray", _packet_region(0.0, 1e-3, 0.5, profile))])).points)
    assert list(dense["label"]) == [Label.SPRAY] and dense["distance"][0] == pytest.approx(0.25, abs=0.01)
    assert list(dilute["label"]) == [Label.SPRAY, Label.VEHICLE] and dilute["distance"][1] == pytest.approx(40.0, abs=0.05)


def _run(name, seconds=2.0, **spray):
    world = World.build(load_scenario(name))
    regions = world.regions(params={"spray": spray} if spray else None)
    sim = LidarSimulator(world.profile, world.scene, regions=regions, seed=0)
    frames = []
    for t in np.arange(0.0, seconds, 0.01):
        frames += sim.advance(float(t), world.player)
    return frames, dict(regions)["spray"]


def test_more_speed_gives_more_spray_detections():
    counts = {}
    for speed in (39, 60):  # a deep (3 mm) film: at the thesis' 0.5 mm there is < 1 detection per frame
        frames, _ = _run(f"proving_ground_{speed}", 2.5, water_film_mm=3.0)
        counts[speed] = np.mean([np.sum(f.points["label"] == Label.SPRAY) for f in frames[25:]])
    assert counts[60] > 2 * counts[39] > 0


def test_highway_spray_echoes_come_from_the_leading_vehicle_and_in_front_of_it():
    frames, region = _run("highway_spray", 2.0)
    pts = np.concatenate([f.points for f in frames[25:]])
    spray = pts[pts["label"] == Label.SPRAY]
    assert len(spray) > 20 and set(np.unique(spray["object_id"])) == {100}
    vehicle = pts[(pts["label"] == Label.VEHICLE) & (pts["object_id"] == 100)]
    assert np.median(spray["x"]) < np.median(vehicle["x"]) + 1.0  # spray sits behind the car, towards the ego
    assert np.median(spray["y"]) > 1.5  # on the leading vehicle's side (left lane)
    assert region.water_film_mm == 0.7


def test_same_seed_same_frames():
    a, _ = _run("proving_ground_55", 0.5)
    b, _ = _run("proving_ground_55", 0.5)
    c, _ = _run("proving_ground_55", 0.5, seed=9)
    assert all(x.points.tobytes() == y.points.tobytes() for x, y in zip(a, b))
    assert any(x.points.tobytes() != y.points.tobytes() for x, y in zip(a, c))




def _with_road(name: str, **road):
    """Scenario ``name`` with ``weather.road`` set and spray's own film override (if any) removed."""
    scenario = load_scenario(name)
    weather = scenario.weather.model_copy(update={"road": scenario.weather.road.model_copy(update=road)})
    params = {**scenario.region_params, "spray": {k: v for k, v in scenario.region_params["spray"].items()
                                                  if k != "water_film_mm"}}  # fmt: skip
    return scenario.model_copy(update={"weather": weather, "region_params": params})


def test_film_from_rain_by_eq1_when_not_given():
    region = dict(World.build(_with_road("highway_spray", water_film_mm=None)).regions())["spray"]
    assert region.water_film_mm == pytest.approx(0.7, rel=0.01)  # eq. 1 fitted to the highway


def test_film_from_the_road_block_shared_with_the_atmosphere():
    regions = dict(World.build(_with_road("highway_spray", water_film_mm=1.1)).regions())
    assert regions["spray"].water_film_mm == 1.1
    assert regions["atmosphere"].wetness == pytest.approx(1.0 - np.exp(-1.1 / 1.5))
    region = dict(World.build(_with_road("highway_spray", water_film_mm=None, texture_depth_mm=3.0)).regions())["spray"]
    assert region.water_film_mm == pytest.approx(0.7 * 2.0**0.3, rel=0.01)  # eq. 1: h ~ T_s^0.3
    with pytest.raises(ConfigError, match=r"key 'texture_depth_mm' moved to weather.road.texture_depth_mm"):
        REGISTRY.create("spray", {"texture_depth_mm": 1.5}, RegionContext(None))


def test_parameter_errors_name_the_key():
    with pytest.raises(ConfigError, match=r"region 'spray' parameters: key 'water_film_mm': value 7"):
        REGISTRY.create("spray", {"water_film_mm": 7}, RegionContext(None))
    with pytest.raises(ConfigError, match=r"key 'actor_ids': value \[5\]"):
        REGISTRY.create("spray", {"actor_ids": [5]}, RegionContext(None, actors=[]))


def test_topic_source_sees_the_published_particles_as_the_in_process_system_does():
    """source 'topic': the region rebuilds its scatterers from spray_node's message fields alone."""
    world = World.build(load_scenario("highway_spray"))
    internal = dict(world.regions(["spray"]))["spray"]
    inputs = TopicInputs("map")
    topic = dict(world.regions(["spray"], {"spray": {"source": "topic"}}, inputs=inputs))["spray"]
    assert inputs.topics == (TOPIC_PARTICLES,)
    batches = []  # (batch, the particles it saw as published, the effect)
    apply = internal.apply

    def recorded(batch, rng):
        effect = apply(batch, rng)
        batches.append((batch, internal.particle_cloud(float(batch.time_s.mean())), effect))
        return effect

    internal.apply = recorded
    sim = LidarSimulator(world.profile, world.scene, regions=[("spray", internal)], seed=0)
    for t in np.arange(0.0, 1.6, 0.01):
        sim.advance(float(t), world.player)
    assert topic.apply(batches[-1][0], np.random.default_rng(0)).scatterers is None  # nothing received yet
    compared = 0
    for batch, published, own in batches[-10:]:
        inputs.put(TOPIC_PARTICLES, published, float(batch.time_s.mean()), "map")
        got = topic.apply(batch, np.random.default_rng(0)).scatterers
        if own.scatterers is None:
            continue
        a, b = own.scatterers, got
        # a hit is (beam, sub-ray, range to the mm): float32 centres may change grazing hits only
        key_a = {(int(x), int(y), round(float(r), 3)): i for i, (x, y, r) in enumerate(zip(a.beam, a.subray, a.range_m))}
        key_b = {(int(x), int(y), round(float(r), 3)): i for i, (x, y, r) in enumerate(zip(b.beam, b.subray, b.range_m))}
        both = sorted(set(key_a) & set(key_b))
        assert len(both) >= 0.98 * len(a.beam) and len(both) >= 0.98 * len(b.beam)
        ia, ib = [key_a[k] for k in both], [key_b[k] for k in both]
        ra, rb = a.reflectance[ia], b.reflectance[ib]
        # a chord that grazes a packet changes with the float32 rounding of its centre (~1 in 7000 hits)
        assert np.mean(np.isclose(ra, rb, rtol=1e-3, atol=1e-6)) >= 0.999 and np.allclose(ra, rb, rtol=0.02, atol=1e-6)
        assert np.array_equal(a.object_id[ia], b.object_id[ib]) and set(np.unique(b.object_id)) == {100}
        compared += len(both)
    assert compared > 20


def test_topic_inputs_refuse_another_frame_and_missing_fields():
    inputs = TopicInputs("map")
    inputs.want(TOPIC_PARTICLES, TOPIC_FIELDS)
    cloud = particle_cloud(np.zeros((2, 3)), 0.009, np.zeros(2, np.uint8))
    with pytest.raises(ValueError, match="frame_id 'odom' is not the fixed frame 'map'"):
        inputs.put(TOPIC_PARTICLES, cloud, 0.0, "odom")
    with pytest.raises(ValueError, match="lack the field.*cross_section_m2"):
        inputs.put(TOPIC_PARTICLES, cloud[["x", "y", "z", "radius", "population", "vertical", "object_id"]], 0.0, "map")
    assert inputs.latest(TOPIC_PARTICLES) is None
    inputs.put(TOPIC_PARTICLES, cloud, 2.0, "map")
    assert inputs.latest(TOPIC_PARTICLES).stamp_s == 2.0
    with pytest.raises(ConfigError, match="source 'topic' but no topic inputs"):
        REGISTRY.create("spray", {"source": "topic"}, RegionContext(None))


def test_poses_that_arrive_over_time_emit_as_the_whole_track_does():
    """/tf-driven emitters: the pose of the next tick is not known yet when a tick is stepped (backward
    difference for the speed, incomplete ticks asked again), and the spray is the same as with the
    scenario's poses known in advance."""
    world = World.build(load_scenario("highway_spray"))
    known = {"until": 0.0}

    def arriving(t):  # what a /tf buffer holds: poses up to the newest message
        return world.player.actor_poses(t) if t <= known["until"] + 1e-9 else {}

    whole = dict(world.regions(["spray"]))["spray"].system
    live = dict(world.regions(["spray"], pose_source=type("Tf", (), {"actor_poses": staticmethod(arriving)})()))["spray"].system
    for k in range(1, 101):
        known["until"] = 0.01 * k
        whole.advance_to(0.01 * k)
        live.advance_to(0.01 * k)
    assert live.emitted > 1000
    assert abs(live.emitted - whole.emitted) <= 0.02 * whole.emitted
    assert np.median(live.particles.pos[:, 1]) == pytest.approx(np.median(whole.particles.pos[:, 1]), abs=0.3)


def test_a_warm_up_has_the_spray_out_at_the_first_step():
    """highway_spray's car has thrown 0.5 s of spray before the first frame with warmup_s 0.5; without it the
    first step starts with none, and the warmed-up system is where a cold one is 0.5 s later."""
    world = World.build(load_scenario("highway_spray"))
    cold = dict(world.regions())["spray"]
    warm = dict(world.regions(params={"spray": {"warmup_s": 0.5}}))["spray"]
    cold.step(0.0, 0.0), warm.step(0.0, 0.0)
    assert len(cold.system.particles.pos) == 0 and len(warm.system.particles.pos) > 100
    assert warm.system.time_s == pytest.approx(0.0)
    later = dict(world.regions())["spray"]
    later.step(-0.5, 0.0)  # the same ticks from a cold start at -0.5 s
    assert warm.system.particles.pos.tobytes() == later.system.particles.pos.tobytes()


def test_a_region_built_again_with_the_same_memo_takes_the_particles_from_the_earlier_build():
    """The gap search screens the same spray on the same frames every round: with a ``memo`` in the context the
    second build takes each step's particles from the first (no tick simulated again), bit for bit what it would
    have simulated, and goes on from there past the first's last step; another water film is not shared."""
    world = World.build(load_scenario("highway_spray"))
    steps = [(0.0, 0.0), (0.0, 0.04), (0.04, 0.2), (0.2, 0.24)]
    memo: dict = {}

    def run(params: dict | None = None, memo=memo, steps=steps):
        spray = {"spray": {"warmup_s": 0.3, **(params or {})}}
        region = dict(world.regions(["spray"], params=spray, memo=memo))["spray"]
        ticks, tick = [], region.system._tick
        region.system._tick = lambda k: (ticks.append(k), tick(k))
        out = []
        for t0, t1 in steps:
            region.step(t0, t1)
            out.append(region.system.particles.pos.tobytes())
        return out, len(ticks)

    first, first_ticks = run()
    again, again_ticks = run()
    alone, _ = run(memo=None, steps=steps + [(0.24, 0.5)])
    assert first_ticks == 54 and again_ticks == 0  # 0.3 s of warm-up and 0.24 s of steps, 10 ms a tick
    assert again == first == alone[:4]
    longer, longer_ticks = run(steps=steps + [(0.24, 0.5)])
    assert longer == alone and longer_ticks == 26
    wetter, wetter_ticks = run({"water_film_mm": 1.5})
    assert wetter_ticks == 54 and wetter[-1] != first[-1]
