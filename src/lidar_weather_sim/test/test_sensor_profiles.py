"""Sensor profiles: the thesis' scala4 and the profiles generated from measured calibrations."""

import numpy as np
import pytest

from lidar_weather_sim.core.config import ConfigError
from lidar_weather_sim.sensor.profile import load_profile
from lidar_weather_sim.sensor.scan import ScanPattern


def test_scala4_matches_thesis_table_2_3(thesis_tables):
    scala = thesis_tables["sensor_scala"]
    p = load_profile("scala4")
    assert p.scan.azimuth_max_deg - p.scan.azimuth_min_deg == pytest.approx(scala["hfov_deg"])
    elevations = sorted(b.elevation_deg for b in p.beams)
    assert len(elevations) == scala["layers"]
    assert np.diff(elevations) == pytest.approx([scala["layer_spacing_deg"]] * (scala["layers"] - 1))
    assert elevations[-1] - elevations[0] + scala["layer_spacing_deg"] == pytest.approx(scala["vfov_deg"])
    assert p.scan.frame_rate_hz == pytest.approx(scala["mirror_hz"])
    assert p.detection.max_echoes == scala["max_echoes"]
    assert p.range.resolution_m <= scala["range_resolution_m_max"]
    assert p.optics.overlap_start_m == pytest.approx(thesis_tables["optics_and_materials"]["sender_receiver_overlap_min_m"])
    assert (p.scan.azimuth_max_deg - p.scan.azimuth_min_deg) / p.scan.columns == pytest.approx(0.25)


def test_scala4_refresh_40_ms_middle_80_ms_outer_layers(thesis_tables):
    pattern = ScanPattern(load_profile("scala4"))
    refresh_ms = thesis_tables["sensor_scala"]["refresh_ms"]
    frames = [set(pattern.active_channels(k).tolist()) for k in range(8)]
    assert all(len(f) == 3 for f in frames)
    period_ms = 1000.0 / pattern.profile.scan.frame_rate_hz
    for channel in range(4):
        seen = [k for k, f in enumerate(frames) if channel in f]
        assert np.diff(seen) * period_ms == pytest.approx(
            [refresh_ms[0] if channel in (1, 2) else refresh_ms[1]] * (len(seen) - 1)
        )


@pytest.mark.parametrize(
    "name, beams, lowest, highest",
    [("vlp16", 16, -15.0, 15.0), ("vlp32c", 32, -25.0, 15.0), ("hdl64e", 64, -23.95, 2.81),
     ("os1_128_1024", 128, -21.82, 20.95), ("os1_128_2048", 128, -21.82, 20.95)],
)  # fmt: skip
def test_generated_profiles_carry_the_calibrated_beams(name, beams, lowest, highest):
    p = load_profile(name)
    elevations = np.array([b.elevation_deg for b in p.beams])
    assert len(elevations) == beams
    assert elevations.min() == pytest.approx(lowest, abs=0.1)
    assert elevations.max() == pytest.approx(highest, abs=0.1)
    pattern = ScanPattern(p)
    assert np.all(np.diff(pattern.elevation) >= 0), "channel 0 is the lowest beam"


def test_vlp16_beams_are_2_deg_apart_and_interleaved():
    p = load_profile("vlp16")
    elevations = [b.elevation_deg for b in p.beams]
    assert elevations[:4] == pytest.approx([-15.0, 1.0, -13.0, 3.0], abs=1e-4)  # laser ids 0..3 as calibrated
    assert np.diff(sorted(elevations)) == pytest.approx([2.0] * 15, abs=1e-4)


def test_os1_azimuth_offsets_are_ouster_angles_negated():
    p = load_profile("os1_128_2048")
    # the recording's first beam_azimuth_angles entry is +4.21 deg (clockwise), i.e. -4.21 deg in REP-103
    assert p.beams[0].azimuth_offset_deg == pytest.approx(-4.21)
    assert p.scan.columns == 2048


def test_unknown_profile_lists_the_known_ones():
    with pytest.raises(ConfigError, match=r"unknown sensor profile 'nope' \(known: .*scala4"):
        load_profile("nope")


def test_scan_pattern_columns_times_and_subray_weights():
    p = load_profile("scala4")
    pattern = ScanPattern(p)
    assert pattern.n_columns == 580 and pattern.n_subrays == 3
    assert pattern.subray_weight.sum() == pytest.approx(1.0)
    assert pattern.subray_weight[1] > pattern.subray_weight[0] == pytest.approx(pattern.subray_weight[2])
    # clockwise: from the left edge (+72.5 deg) to the right edge, 0.25 deg steps
    assert np.rad2deg(pattern.column_azimuth[[0, -1]]) == pytest.approx([72.375, -72.375])
    assert pattern.column_time_s[-1] < p.period_s * p.scan.sweep_fraction
    batch = pattern.batch(0, np.array([0, 290]))
    assert batch.directions.shape == (2, 3, 3, 3)
    np.testing.assert_allclose(np.linalg.norm(batch.directions, axis=-1), 1.0)
    assert list(pattern.columns_between(0.0, pattern.column_time_s[3])) == [0, 1, 2]


def test_elevation_offsets_move_a_channel_in_the_cast_and_the_points_and_restart_takes_them_back():
    from lidar_weather_sim.scenario.schema import load_scenario
    from lidar_weather_sim.scenario.world import World
    from lidar_weather_sim.sim.simulator import LidarSimulator

    world = World.build(load_scenario("highway_clear"), "vlp16")

    def channel_elevation_and_range(sim, channel):
        sim.restart()
        points = sim.cast_frame(0, 0.0, world.player).points
        mine = points[points["channel"] == channel]
        el = np.degrees(np.arctan2(mine["z"], np.hypot(mine["x"], mine["y"])))
        return float(np.median(el)), float(np.median(mine["distance"]))

    sim = LidarSimulator.of_world(world, elevation_offsets_deg={3: 0.5})
    raised, raised_range = channel_elevation_and_range(sim, 3)
    sim.restart(elevation_offsets_deg={})
    nominal, nominal_range = channel_elevation_and_range(sim, 3)
    assert abs(nominal - (-9.0)) < 1e-3 and abs(raised - (-8.5)) < 1e-3, (nominal, raised)
    # the road seen 0.5 deg higher from 1.9 m: farther, as 1 / sin(elevation)
    assert raised_range / nominal_range == pytest.approx(np.sin(np.radians(9.0)) / np.sin(np.radians(8.5)), rel=0.02)
    with pytest.raises(ConfigError, match=r"channels 2 and 3 would cross \(-11 and -11.5 deg\)"):
        world.profile.with_elevation_offsets({3: -2.5})
    with pytest.raises(ConfigError, match="channels \\[16\\] do not exist"):
        world.profile.with_elevation_offsets({16: 0.1})


def test_a_beams_origin_off_the_point_frame_moves_the_cast_and_is_read_back_off_the_points():
    """Beams fired from 36 mm above and 16 mm out of the frame the points are reported in (as a real Ouster's):
    the points' elevations give both back within 1 mm, no channel offsets; the road seen from 36 mm higher
    lies farther, and restart puts the origin back."""
    from lidar_weather_sim.gap.channels import beam_origin, elevation_offsets
    from lidar_weather_sim.scenario.schema import load_scenario
    from lidar_weather_sim.scenario.world import World
    from lidar_weather_sim.sim.simulator import LidarSimulator

    world = World.build(load_scenario("highway_clear"), "vlp16")
    nominal = np.array([b.elevation_deg for b in world.profile.beams])[world.profile.channel_order]
    sim = LidarSimulator.of_world(world, beam_origin_m=(0.016, 0.036))
    moved = sim.cast_frame(0, 0.0, world.player).points
    up, radial = beam_origin([moved], nominal)
    assert abs(up - 0.036) < 1e-3 and abs(radial - 0.016) < 1e-3, (up, radial)
    assert elevation_offsets([moved], nominal) == {}
    sim.restart(beam_origin_m=(0.0, 0.0))
    plain = sim.cast_frame(0, 0.0, world.player).points
    assert beam_origin([plain], nominal) == (0.0, 0.0)
    lowest = [np.median(p["distance"][p["channel"] == 0]) for p in (moved, plain)]
    assert lowest[0] > lowest[1] + 0.05, lowest  # -15 deg from ~1.9 m: the road ~0.14 m farther (less the 16 mm)
