"""The virtual LiDAR against closed-form expectations: ranges, intensities, EPW, echoes, sun, seeds, motion."""

import numpy as np
import pytest

from lidar_weather_sim.core.points import Label
from lidar_weather_sim.scene.mesh import box_mesh
from lidar_weather_sim.sensor.radiometry import FWHM_TO_SIGMA
from lidar_weather_sim.sim.simulator import LidarSimulator
from lidar_weather_sim.testing.fixtures import MATERIALS, LinearPose, one_frame, scene_of, simple_profile, wall


def test_flat_wall_ranges_follow_the_geometry():
    sim = LidarSimulator(simple_profile(), scene_of(wall(20.0, "concrete", 7)), backend="open3d")
    points = one_frame(sim).points
    assert len(points) == 81
    expected = 20.0 / np.cos(points["azimuth"].astype(np.float64))
    np.testing.assert_allclose(points["distance"], expected, atol=1e-3)
    np.testing.assert_allclose(points["x"], 20.0, atol=1e-3)
    assert set(points["object_id"]) == {7} and set(points["label"]) == {Label.STATIC}
    assert set(points["echo"]) == {1}


def _central_point(points):
    return points[np.argmin(np.abs(points["azimuth"]))]


def test_intensity_follows_reflectivity_and_incidence_angle():
    span = 255.0 / np.log(1.0e4)  # intensity per e-fold of received power
    dark = _central_point(one_frame(LidarSimulator(simple_profile(), scene_of(wall(20, "tyre", 1)))).points)
    bright = _central_point(one_frame(LidarSimulator(simple_profile(), scene_of(wall(20, "license_plate", 1)))).points)
    ratio = MATERIALS["license_plate"].reflectivity * (1 - MATERIALS["license_plate"].retro_share) + \
        MATERIALS["license_plate"].retro_share * MATERIALS["license_plate"].reflectivity * 100.0  # fmt: skip
    ratio /= MATERIALS["tyre"].reflectivity
    assert int(bright["intensity"]) - int(dark["intensity"]) == pytest.approx(span * np.log(ratio), abs=1.0)
    straight = _central_point(one_frame(LidarSimulator(simple_profile(), scene_of(wall(20, "concrete", 1)))).points)
    tilted = _central_point(one_frame(LidarSimulator(simple_profile(), scene_of(wall(20, "concrete", 1, tilt_deg=60)))).points)
    assert int(straight["intensity"]) - int(tilted["intensity"]) == pytest.approx(span * np.log(2.0), abs=1.0)


@pytest.mark.parametrize("distance_m, material", [(10.0, "concrete"), (30.0, "concrete"), (30.0, "license_plate")])
def test_epw_matches_the_closed_form_of_the_gaussian_pulse(distance_m, material):
    profile = simple_profile()
    point = _central_point(one_frame(LidarSimulator(profile, scene_of(wall(distance_m, material, 1)))).points)
    m = MATERIALS[material]
    reflectance = m.reflectivity * ((1 - m.retro_share) * 1.0 + m.retro_share * 100.0)
    amplitude = profile.detection.power_constant * reflectance / point["distance"] ** 2
    threshold = 1.0 + 3.0 * 1.0
    s = profile.pulse.fwhm_m * FWHM_TO_SIGMA
    assert point["epw"] == pytest.approx(2 * s * np.sqrt(2 * np.log(amplitude / threshold)), rel=1e-4)


def test_thin_pole_in_front_of_a_wall_gives_two_echoes_the_far_one_weaker():
    # 3 sub-rays across a 10 mrad beam: at 10 m they are 3.3 cm apart, a 3 cm pole takes the middle one.
    profile = simple_profile(optics__divergence_h_mrad=10.0, optics__subrays_h=3)
    pole = box_mesh((0.03, 0.03, 5.0), MATERIALS.index("guard_rail"), 3, z_bottom=-2.0)
    pole = pole.transformed(np.array([[1, 0, 0, 10.0], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]]))
    sim = LidarSimulator(profile, scene_of(pole, wall(25.0, "concrete", 9)))
    points = one_frame(sim).points
    central = points[np.abs(points["azimuth"]) < 1e-6]
    assert list(central["echo"]) == [1, 2]
    assert central["distance"][0] == pytest.approx(10.0 - 0.015, abs=0.1)
    assert central["distance"][1] == pytest.approx(25.0, abs=0.1)
    assert list(central["object_id"]) == [3, 9]
    assert central["intensity"][1] < central["intensity"][0]
    assert central["epw"][1] < central["epw"][0]


def test_background_light_removes_weak_echoes_and_shortens_epw():
    profile = simple_profile(detection__sun_noise_per_w_m2=0.01, scan__columns=401)
    # a wall at 35 m turned by 60 deg: incidence 50-70 deg across the field of view, echoes from
    # 4x the dark threshold down to 2x; sunlight (mu 1 -> 9, threshold 4 -> 12) removes the weaker half
    far_wall = wall(35.0, "concrete", 1, tilt_deg=60.0, half_width=300.0)
    night = one_frame(LidarSimulator(profile, scene_of(far_wall), sun_irradiance_w_m2=0.0)).points
    day = one_frame(LidarSimulator(profile, scene_of(far_wall), sun_irradiance_w_m2=800.0)).points
    assert len(night) > 390  # 401 columns: nearly all above the dark threshold
    assert 0 < len(day) < 0.9 * len(night)
    common = np.intersect1d(night["time_stamp"], day["time_stamp"])
    n = night[np.isin(night["time_stamp"], common)]
    d = day[np.isin(day["time_stamp"], common)]
    assert np.all(d["epw"] < n["epw"])
    assert day["intensity"].min() > night["intensity"].min(), "the weakest echoes are the ones lost"


def test_same_seed_same_cloud_other_seed_other_noise():
    profile = simple_profile(range__noise_sigma_m=0.05, detection__false_alarms_per_beam=0.2)
    scene = scene_of(wall(20.0, "concrete", 1))
    a = one_frame(LidarSimulator(profile, scene, seed=5)).points
    b = one_frame(LidarSimulator(profile, scene, seed=5)).points
    c = one_frame(LidarSimulator(profile, scene, seed=6)).points
    assert a.tobytes() == b.tobytes()
    assert a.tobytes() != c.tobytes()
    assert np.std(a["distance"][a["label"] == Label.STATIC] - 20.0 / np.cos(a["azimuth"][a["label"] == Label.STATIC])) \
        == pytest.approx(0.05, rel=0.4)  # fmt: skip
    assert (a["label"] == Label.NOISE).any()


def test_rolling_shutter_every_point_matches_the_pose_at_its_own_time():
    # 25 m/s towards a wall at x = 60 m: over the 50 ms sweep the sensor moves 1.25 m.
    profile = simple_profile(range__resolution_m=0.01, pulse__fwhm_m=0.3)
    sim = LidarSimulator(profile, scene_of(wall(60.0, "concrete", 1)))
    pose = LinearPose(speed_m_s=25.0)
    frames = []
    for k in range(0, 21):
        frames += sim.advance(0.005 * k, pose)
    assert len(frames) == 1
    frame = frames[0]
    t = frame.stamp_s + frame.points["time_stamp"].astype(np.float64) * 1e-9
    world_x = frame.points["x"] + 25.0 * t
    np.testing.assert_allclose(world_x, 60.0, atol=2e-3)
    assert np.ptp(frame.points["x"]) > 1.0, "the sweep must see the wall come closer"


def test_frames_complete_when_the_sweep_completes():
    sim = LidarSimulator(simple_profile(), scene_of(wall(20.0, "concrete", 1)))
    pose = LinearPose()
    counts = [len(sim.advance(0.01 * k, pose)) for k in range(0, 101)]  # 1 s at 100 Hz
    # frames start every 0.1 s at t = 0, 0.1, ...; a sweep (0.05 s) ends at k*0.1 + 0.05 - one column step
    assert sum(counts) == 10
    assert [k for k, c in enumerate(counts) if c] == [5 + 10 * i for i in range(10)]


def test_time_going_backwards_is_an_error():
    sim = LidarSimulator(simple_profile(), scene_of(wall(20.0, "concrete", 1)))
    sim.advance(1.0, LinearPose())
    with pytest.raises(ValueError, match="time went backwards"):
        sim.advance(0.5, LinearPose())


def test_scala4_sun_calibration_reproduces_the_table_2_first_echo_ratio(thesis_tables):
    from lidar_weather_sim.experiments.rooftop import RooftopPose, rooftop_scene
    from lidar_weather_sim.sensor.profile import load_profile

    table = thesis_tables["background_radiation_clear"]
    profile = load_profile("scala4")

    def first_echoes(sun_w_m2):
        sim = LidarSimulator(profile, rooftop_scene(), sun_irradiance_w_m2=sun_w_m2, seed=1)
        frames = sim.advance(0.0, RooftopPose()) + sim.advance(4 * profile.period_s, RooftopPose())
        return np.mean([np.sum(f.points["echo"] == 1) for f in frames]), np.mean([f.points["epw"].mean() for f in frames])

    night, night_epw = first_echoes(0.0)
    day, day_epw = first_echoes(table["mean_irradiance_w_m2"]["clear"])
    assert day / night == pytest.approx(table["day"]["n_e1"][0] / table["night"]["n_e1"][0], abs=0.03)
    assert day_epw < night_epw
