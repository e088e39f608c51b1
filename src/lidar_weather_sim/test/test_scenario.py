"""Scenario files: schema, shipped scenarios, the player's poses."""

import numpy as np
import pydantic
import pytest
import yaml

from lidar_weather_sim.core.config import ConfigError, load_yaml, validate
from lidar_weather_sim.core.paths import maps_dir
from lidar_weather_sim.scenario.player import ScenarioPlayer
from lidar_weather_sim.scenario.schema import Scenario, known_scenarios, load_scenario, scenarios_dir
from lidar_weather_sim.scene.opendrive import RoadNetwork


def test_every_shipped_scenario_validates():
    names = list(known_scenarios())
    assert {"highway_clear", "curved_clear", "example_all_keys", "wf_train_fog", "wf_heldout_mixed"} <= set(names)
    for name in names:
        assert load_scenario(name).name == name


def _keys(model: type[pydantic.BaseModel], prefix="") -> set[str]:
    out = set()
    for name, field in model.model_fields.items():
        out.add(prefix + name)
        ann = field.annotation
        inner = getattr(ann, "__args__", (ann,))
        for t in inner:
            if isinstance(t, type) and issubclass(t, pydantic.BaseModel):
                out |= _keys(t, prefix + name + ".")
    return out


def _used(data, prefix="") -> set[str]:
    out = set()
    if isinstance(data, dict):
        for k, v in data.items():
            out.add(prefix + k)
            out |= _used(v, prefix + k + ".")
    elif isinstance(data, list):
        for item in data:
            out |= _used(item, prefix)
    return out


def test_example_scenario_uses_every_key():
    """Every key but ``trajectory`` (mesh-only scenarios only; the example has a map) and ``sensor.fixed_parts``
    (a part in the example would change its golden clouds): test/test_twin_parts.py, test/test_twin_ego.py and the
    scenarios ``lidar-weather-sim twin`` writes use them."""
    data = yaml.safe_load((scenarios_dir() / "example_all_keys.yaml").read_text())
    assert {k for k in _keys(Scenario) - _used(data) if not k.startswith(("trajectory", "sensor.fixed_parts"))} == set()


def test_highway_clear_is_the_thesis_highway_setup():
    """Paper 3: the car ahead's rear middle (17.5 +- 0.3, 3.7 +- 0.1) m from the ego's LiDAR (thesis
    lines 2176, 2868): in its ground-truth pose and in the points the sensor returns from it."""
    from lidar_weather_sim.core.geometry import quaternion_matrices
    from lidar_weather_sim.scenario.world import World
    from lidar_weather_sim.sim.simulator import LidarSimulator

    s = load_scenario("highway_clear")
    assert s.ego.speed_m_s * 3.6 == pytest.approx(89.0, abs=0.1)
    lead = s.actors[0]
    assert (lead.id, lead.lead_gap_m, lead.lead_offset_y_m) == (100, 17.5, 3.7)
    world = World.build(s)
    translation, quaternion = world.player.sensor_poses(np.array([0.0]))
    sensor = np.eye(4)
    sensor[:3, :3], sensor[:3, 3] = quaternion_matrices(quaternion)[0], translation[0]
    pose = np.linalg.inv(sensor) @ world.player.actor_poses(0.0)[lead.id]  # the car in the sensor frame
    rear_middle = pose @ [-0.5 * lead.size.length_m, 0.0, 0.0, 1.0]
    assert rear_middle[0] == pytest.approx(17.5, abs=0.1) and rear_middle[1] == pytest.approx(3.7, abs=0.1)
    sim = LidarSimulator.of_world(world, regions=[])
    frames = sim.advance(0.0, world.player) + sim.advance(sim.profile.period_s, world.player)
    car = frames[0].points[frames[0].points["object_id"] == lead.id]
    assert len(car) > 50
    assert np.percentile(car["x"], 2) == pytest.approx(17.5, abs=0.3)


def test_a_lead_gap_resolves_to_the_lane_and_position_of_the_rear_middle():
    s = load_scenario("highway_clear")
    network = RoadNetwork.from_xodr(maps_dir() / s.map)
    extra = [{"id": 140, "lead_gap_m": 30.0, "lead_offset_y_m": -3.7, "speed_m_s": 20.0,
              "size": {"length_m": 10.0, "width_m": 2.5, "height_m": 3.0}},
             {"id": 141, "lead_gap_m": 15.5, "lead_offset_y_m": 0.0, "speed_m_s": 20.0}]  # fmt: skip
    scenario = Scenario.model_validate({**s.model_dump(exclude_unset=True), "actors": extra})
    player = ScenarioPlayer(scenario, network)
    sensor_s = s.ego.s_m + s.sensor.mount.x_m
    truck, car = player.actors[140][0], player.actors[141][0]
    assert (truck.lane, truck.s_m) == (-3, pytest.approx(sensor_s + 30.0 + 5.0))  # right of the ego's lane
    assert (car.lane, car.s_m) == (s.ego.lane, pytest.approx(sensor_s + 15.5 + 0.5 * car.size.length_m))
    off_road = {**s.model_dump(exclude_unset=True), "actors": [{"id": 150, "lead_gap_m": 20.0, "lead_offset_y_m": 9.0}]}
    with pytest.raises(ConfigError, match=r"actor 150: lead_gap_m 20.0 m, lead_offset_y_m 9.0 m: the rear middle is on no lane"):
        ScenarioPlayer(Scenario.model_validate(off_road), network)


def test_player_moves_the_ego_along_its_lane_and_through_a_lane_change():
    s = load_scenario("example_all_keys")
    player = ScenarioPlayer(s, RoadNetwork.from_xodr(maps_dir() / s.map))
    t = np.array([0.0, 1.0, 2.5, 4.0])
    pos, _ = player.base_link_poses(t)
    np.testing.assert_allclose(np.diff(pos[:, 0]), 25.0 * np.diff(t), atol=1e-6)
    assert pos[0, 1] == pytest.approx(-9.375) and pos[1, 1] == pytest.approx(-9.375)
    assert pos[2, 1] == pytest.approx(-7.5)  # halfway through the 3 s lane change to lane -2
    assert pos[3, 1] == pytest.approx(-5.625)
    sensor, _ = player.sensor_poses(np.array([0.0]))
    np.testing.assert_allclose(sensor[0], pos[0] + [3.7, 0.0, 0.5], atol=1e-9)
    assert 200 not in player.actor_poses(1.0) and 200 in player.actor_poses(2.0)


def test_speed_command_changes_the_ego_speed_from_then_on():
    s = load_scenario("highway_clear")
    player = ScenarioPlayer(s, RoadNetwork.from_xodr(maps_dir() / s.map))
    player.ego.command_speed(1.0, 10.0)
    x = player.base_link_poses(np.array([0.0, 1.0, 2.0]))[0][:, 0]
    assert x[1] - x[0] == pytest.approx(24.72) and x[2] - x[1] == pytest.approx(10.0)


@pytest.mark.parametrize(
    "patch, message",
    [
        ({"weather": {"precipitation": {"type": "dry", "intensity_mm_h": 3.0}}}, "precipitation type 'dry'"),
        ({"weather": {"fog": {"visual_range_km": 3}}}, "unknown key 'weather.fog.visual_range_km'"),
        ({"actors": [{"id": 5, "lane": -1}]}, "key 'actors.0.id': value 5"),
        ({"region_params": {"spray": {}}}, "region_params for regions not in 'regions'"),
        ({"actors": [{"id": 100, "lane": -1, "s_m": 70.0, "lead_gap_m": 17.5}]}, "'lead_gap_m' places the actor; remove ['lane', 's_m']"),
        ({"actors": [{"id": 100, "s_m": 70.0}]}, "actor 100: give 'lane' and 's_m', or 'lead_gap_m'"),
        ({"actors": [{"id": 100, "lane": -1, "lead_offset_y_m": 3.7}]}, "actor 100: 'lead_offset_y_m' needs 'lead_gap_m'"),
    ],
)
def test_bad_scenarios_name_the_key(tmp_path, patch, message):
    data = yaml.safe_load((scenarios_dir() / "highway_clear.yaml").read_text())
    data.update(patch)
    path = tmp_path / "bad.yaml"
    path.write_text(yaml.safe_dump(data))
    with pytest.raises(ConfigError) as err:
        load_yaml(path, Scenario)
    assert message in str(err.value) and str(path) in str(err.value)


def test_batched_actor_poses_match_each_track_to_the_bit():
    """Steady actors (evaluated together), a commanded one and a left-lane one (against s)."""
    from lidar_weather_sim.core.geometry import rpy_matrix

    scenario = load_scenario("highway_clear")
    extra = [
        {"id": 130, "lane": -2, "s_m": 80.0, "speed_m_s": 25.0, "appear_s": 0.3},
        {"id": 131, "lane": 1, "s_m": 400.0, "speed_m_s": 30.0},
        {"id": 132, "lane": -1, "s_m": 10.0, "speed_m_s": 31.0},
    ]  # fmt: skip
    scenario = scenario.model_validate({**scenario.model_dump(), "actors": scenario.model_dump()["actors"] + extra})
    player = ScenarioPlayer(scenario, RoadNetwork.from_xodr(maps_dir() / scenario.map))
    player.actors[132][1].command_speed(0.5, 12.0)
    times = np.linspace(0.0, 1.5, 16)
    many = player.actor_poses_at(times)
    for t, poses in zip(times, many):
        assert list(poses) == [i for i, (a, _) in player.actors.items() if t >= a.appear_s]
        for actor_id, m in poses.items():
            pos, heading = player.actors[actor_id][1].poses(np.array([t]))
            want = np.eye(4)
            want[:3, :3] = rpy_matrix(0.0, 0.0, float(heading[0]))
            want[:3, 3] = pos[0]
            assert m.tobytes() == want.tobytes()


@pytest.mark.parametrize("key", ["azimuth_deg", "elevation_deg"])
def test_a_removed_key_is_refused_with_one_line_naming_where_it_went(key):
    data = yaml.safe_load((scenarios_dir() / "highway_clear.yaml").read_text())
    data["weather"]["sun"] = {"irradiance_w_m2": 200.0, key: 30.0}
    with pytest.raises(ConfigError) as err:
        validate(data, Scenario, "s.yaml")
    message = str(err.value)
    assert message == f"s.yaml: key 'weather.sun.{key}' was removed: sunlight acts through weather.sun.irradiance_w_m2 only (the noise floor)"
