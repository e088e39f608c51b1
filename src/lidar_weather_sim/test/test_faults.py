"""Region ``faults``: a dead channel, a blocked sector, random and periodic output masks, on highway_clear
(scala4 and VLP-16), each against the same run without the fault."""

import numpy as np
import pytest

from lidar_weather_sim.core.config import ConfigError
from lidar_weather_sim.scenario.schema import load_scenario
from lidar_weather_sim.scenario.world import World
from lidar_weather_sim.sim.simulator import LidarSimulator


def _frames(n: int, profile: str = "scala4", seed: int = 3, **faults) -> list[np.ndarray]:
    """Points of the first ``n`` frames of highway_clear, with the faults region when ``faults`` are given."""
    data = load_scenario("highway_clear").model_dump()
    if faults:
        data["regions"] = ["faults"]
        data["region_params"] = {"faults": faults}
    scenario = type(load_scenario("highway_clear")).model_validate(data)
    world = World.build(scenario, profile)
    sim = LidarSimulator.of_world(world, seed=seed)
    out, t = [], 0.0
    while len(out) < n:
        t = round(t + 0.01, 9)
        out += [f.points for f in sim.advance(t, world.player)]
    return out[:n]


@pytest.fixture(scope="module")
def clear():
    return _frames(6, "vlp16")


def test_a_dead_channel_outputs_nothing_and_the_others_are_unchanged(clear):
    dead = _frames(6, "vlp16", dead_channels=[3, 9])
    for before, after in zip(clear, dead):
        assert (before["channel"] == 3).sum() > 500 and not np.isin(after["channel"], [3, 9]).any()
        for c in (0, 5, 12):
            assert (after["channel"] == c).sum() == (before["channel"] == c).sum()


def test_a_blocked_sector_loses_its_returns_and_keeps_the_rest(clear):
    blocked = _frames(6, "vlp16", blocked_sectors_deg=[[150.0, -150.0], [10.0, 30.0]])  # behind (wraps) and front-left
    for before, after in zip(clear, blocked):
        # the beams' own azimuth: atan2 of a point moved by range noise puts a beam at 9.5 deg on either side of 9.5
        az = np.degrees(after["azimuth"].astype(np.float64))
        inside = (np.abs(az) > 150.5) | ((az > 10.5) & (az < 29.5))
        az0 = np.degrees(before["azimuth"].astype(np.float64))
        outside0 = (np.abs(az0) < 149.5) & ~((az0 > 9.5) & (az0 < 30.5))
        assert not inside.any() and ((np.abs(az0) > 150.5) | ((az0 > 10.5) & (az0 < 29.5))).sum() > 1000
        outside = (np.abs(az) < 149.5) & ~((az > 9.5) & (az < 30.5))
        assert outside.sum() == outside0.sum()
    half = _frames(2, "vlp16", blocked_sectors_deg=[[10.0, 30.0]], blocked_transmission=0.5)  # a film: range shrinks
    assert 0 < sum(len(p) for p in half) < sum(len(p) for p in clear[:2])


def test_random_dropout_keeps_its_share_of_beams_and_is_seeded(clear):
    lossy = _frames(6, "vlp16", dropout_probability=0.3)
    kept = sum(len(p) for p in lossy) / sum(len(p) for p in clear)
    assert 0.66 <= kept <= 0.74, kept  # 1 - 0.3 of the beams, over ~170k points
    again = _frames(6, "vlp16", dropout_probability=0.3)
    assert all(np.array_equal(a, b) for a, b in zip(lossy, again))
    other = _frames(6, "vlp16", seed=4, dropout_probability=0.3)
    assert not all(len(a) == len(b) and np.array_equal(a["x"], b["x"]) for a, b in zip(lossy, other))


def test_a_weak_channel_reports_its_returns_weaker_by_its_gain_and_loses_the_faint_ones(clear):
    weak = _frames(6, "vlp16", channel_gains={5: 0.25, 8: 0.05})
    per_byte = np.log(1.0e4) / 255.0  # vlp16's intensity_dynamic_range
    before = np.concatenate([p[p["channel"] == 5] for p in clear])
    after = np.concatenate([p[p["channel"] == 5] for p in weak])
    assert len(after) == len(before) > 5000  # the road near the car: strong enough to survive
    unsaturated = (before["intensity"] < 250) & (before["intensity"] > 60)
    drop = (before["intensity"][unsaturated].astype(float) - after["intensity"][unsaturated]) * per_byte
    assert abs(np.median(drop) - np.log(4.0)) < 0.05, np.median(drop)  # ln(1 / 0.25), within ~1 intensity byte
    n8 = [sum((p["channel"] == 8).sum() for p in frames) for frames in (clear, weak)]
    assert 0.9 * n8[0] < n8[1] < 0.99 * n8[0], n8  # the faintest (far, dark) returns fall below the threshold
    for c in (0, 3, 12):
        assert sum((p["channel"] == c).sum() for p in weak) == sum((p["channel"] == c).sum() for p in clear)


def test_a_periodic_mask_empties_the_first_frames_of_each_period():
    frames = _frames(8, mask_period_frames=4, mask_frames=2)
    assert [len(p) == 0 for p in frames] == [True, True, False, False] * 2
    assert all(len(p) > 500 for p in frames[2:4])


@pytest.mark.parametrize(
    "faults, reason",
    [({"dead_channels": [99]}, "dead_channels [99]: the profile has channels 0..3"),
     ({"blocked_sectors_deg": [[0, 200]]}, "outside -180..180"),
     ({"mask_period_frames": 2, "mask_frames": 2}, "must be below mask_period_frames"),
     ({"dropout_probability": 1.5}, "dropout_probability"),
     ({"channel_gains": {7: 0.5}}, "channel_gains [7]: the profile has channels 0..3"),
     ({"channel_gains": {1: 1.5}}, "channel_gains: {1: 1.5}: channels from 0, gains 0-1")],
)  # fmt: skip
def test_impossible_faults_are_refused_naming_the_key(faults, reason):
    with pytest.raises(ConfigError, match="faults") as err:
        _frames(1, **faults)
    assert reason in str(err.value)
