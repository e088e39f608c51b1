"""Return modes: what each beam reports of its detected echoes (strongest, last, first, dual, all).

The selection on constructed echo sets (ties, a beam with one echo, runs with gaps between them), the
simulator's clouds under each mode against its ``all`` cloud, and the issue's case: a box behind a
car's spray, seen through the drops by ``last`` and lost by ``strongest``.
"""

from __future__ import annotations

import numpy as np
import pytest

from lidar_weather_sim.core.config import ConfigError
from lidar_weather_sim.core.names import RETURN_MODES
from lidar_weather_sim.core.points import Label, ReturnType
from lidar_weather_sim.scenario.schema import Scenario
from lidar_weather_sim.scenario.world import World
from lidar_weather_sim.sensor.echo import select_returns
from lidar_weather_sim.sensor.profile import load_profile
from lidar_weather_sim.sim.simulator import LidarSimulator

R = ReturnType
# beam: peak amplitudes of its echoes in range order (nearest first)
BEAMS = {
    0: [5.0, 9.0, 2.0],  # strongest in the middle
    1: [4.0],  # one echo
    2: [3.0, 7.0],  # the last is the strongest
    3: [6.0, 6.0, 6.0],  # three equal peaks
    4: [8.0, 1.0, 8.0],  # the last ties with the first for the strongest
}
# the reported return type of each echo of each beam, 0 = not reported
EXPECTED = {
    "strongest": {0: [0, R.STRONGEST, 0], 1: [R.STRONGEST], 2: [0, R.STRONGEST], 3: [R.STRONGEST, 0, 0],
                  4: [R.STRONGEST, 0, 0]},
    "last": {0: [0, 0, R.LAST], 1: [R.LAST], 2: [0, R.LAST], 3: [0, 0, R.LAST], 4: [0, 0, R.LAST]},
    "first": {0: [R.FIRST, 0, 0], 1: [R.FIRST], 2: [R.FIRST, 0], 3: [R.FIRST, 0, 0], 4: [R.FIRST, 0, 0]},
    "dual": {0: [0, R.STRONGEST, R.LAST], 1: [R.IDENTICAL], 2: [R.SECOND_STRONGEST, R.LAST_STRONGEST],
             3: [R.STRONGEST, 0, R.LAST], 4: [R.STRONGEST, 0, R.LAST]},
}  # fmt: skip


def _echo_set():
    """The echoes of BEAMS as :func:`detect_echoes` leaves them: two runs (beams 0-2 from index 0, beams 3-4
    from index 10) with unused slots (garbage) between and after them."""
    first = [(b, a) for b in (0, 1, 2) for a in BEAMS[b]]
    second = [(b, a) for b in (3, 4) for a in BEAMS[b]]
    beam = np.full(20, 99, np.int64)
    amp = np.full(20, 1e9)
    beam[: len(first)], amp[: len(first)] = zip(*first)
    beam[10 : 10 + len(second)], amp[10 : 10 + len(second)] = zip(*second)
    runs = (np.array([0, 10], np.int64), np.array([len(first), len(second)], np.int64))
    slots = np.r_[np.arange(len(first)), 10 + np.arange(len(second))]
    return beam, amp, runs, slots


@pytest.mark.parametrize("mode", ["strongest", "last", "first", "dual"])
def test_each_mode_reports_the_expected_echoes_of_constructed_beams(mode):
    beam, amp, runs, slots = _echo_set()
    out = np.full(len(beam), 255, np.uint8)  # slots outside the runs stay untouched
    select_returns(beam, amp, runs, mode, out)
    expected = np.concatenate([EXPECTED[mode][b] for b in sorted(BEAMS)]).astype(np.uint8)
    np.testing.assert_array_equal(out[slots], expected)
    outside = np.setdiff1d(np.arange(len(beam)), slots)
    assert (out[outside] == 255).all()
    per_beam = {b: np.count_nonzero(out[slots][beam[slots] == b]) for b in BEAMS}
    assert per_beam == ({0: 2, 1: 1, 2: 2, 3: 2, 4: 2} if mode == "dual" else dict.fromkeys(BEAMS, 1))


def test_all_selects_nothing_and_an_unknown_mode_is_refused():
    beam, amp, runs, _ = _echo_set()
    for mode in ("all", "nearest"):
        with pytest.raises(ValueError, match="return_mode"):
            select_returns(beam, amp, runs, mode)
    with pytest.raises(ConfigError, match="return_mode 'nearest' is not one of strongest, last, dual, first, all"):
        load_profile("scala4").with_return_mode("nearest")


def _frames(scenario, mode: str | None, n: int, profile: str | None = None):
    world = World.build(scenario, profile, mode)
    sim = LidarSimulator.of_world(world)
    frames, t = [], 0.0
    while len(frames) < n:
        t = round(t + 0.01, 9)
        frames += sim.advance(t, world.player)
    return [f.points for f in frames[:n]]


def box_in_fog(visual_range_m: float) -> Scenario:
    """A 1.5 m wide, 0.8 m high box driving 15 m ahead of the sensor in the ego's lane, in fog."""
    return Scenario.model_validate({
        "name": "box_in_fog", "map": "highway_straight.xodr", "seed": 3,
        "ego": {"road": "1", "lane": -2, "s_m": 40.0, "speed_m_s": 20.0},
        "sensor": {"profile": "scala4", "mount": {"x_m": 3.7, "y_m": 0.0, "z_m": 0.5}},
        "actors": [{"id": 200, "type": "box", "label": "obstacle", "road": "1", "lane": -2, "s_m": 58.7,
                    "speed_m_s": 20.0, "size": {"length_m": 0.6, "width_m": 1.5, "height_m": 0.8}}],
        "weather": {"fog": {"visual_range_m": visual_range_m}, "precipitation": {"type": "dry", "intensity_mm_h": 0.0}},
        "regions": ["atmosphere"],
    })  # fmt: skip


@pytest.fixture(scope="module")
def fog_box():
    """5 frames of scala4 (up to 3 echoes per beam) per mode, the box in fog of 30 m visual range."""
    scenario = box_in_fog(30.0)
    return {mode: _frames(scenario, mode, 5) for mode in (None, *RETURN_MODES)}


def _key(points):
    """A point's beam and echo: channel, firing time, echo rank."""
    return set(zip(points["channel"].tolist(), points["time_stamp"].tolist(), points["echo"].tolist()))


def test_the_profile_default_all_is_the_cloud_of_every_echo_and_the_other_modes_are_subsets_of_it(fog_box):
    fields = [n for n in fog_box["all"][0].dtype.names if n != "return_type"]
    for default, every in zip(fog_box[None], fog_box["all"]):
        assert default.tobytes() == every.tobytes()  # scala4's detection.return_mode is all
    for mode in ("strongest", "last", "first", "dual"):
        expected_types = {"strongest": {R.STRONGEST}, "last": {R.LAST}, "first": {R.FIRST},
                          "dual": {R.LAST, R.STRONGEST, R.LAST_STRONGEST, R.SECOND_STRONGEST, R.IDENTICAL}}[mode]  # fmt: skip
        for every, chosen in zip(fog_box["all"], fog_box[mode]):
            assert set(np.unique(chosen["return_type"]).tolist()) <= {int(r) for r in expected_types}
            beams = chosen[["channel", "time_stamp"]]
            most = 2 if mode == "dual" else 1
            assert np.unique(beams, return_counts=True)[1].max() <= most
            # the same points as in the all cloud (range noise included), only fewer
            index = {k: i for i, k in enumerate(zip(every["channel"].tolist(), every["time_stamp"].tolist(),
                                                    every["echo"].tolist()))}  # fmt: skip
            rows = np.array([index[k] for k in zip(chosen["channel"].tolist(), chosen["time_stamp"].tolist(),
                                                   chosen["echo"].tolist())])  # fmt: skip
            for name in fields:
                np.testing.assert_array_equal(chosen[name], every[name][rows])
    last, first = fog_box["last"], fog_box["first"]
    assert any((f["echo"] > 1).any() for f in last)  # the rank among the detected echoes is kept
    assert all((f["echo"] == 1).all() for f in first)


def _obstacle(frames) -> int:
    return int(sum(np.count_nonzero(f["label"] == Label.OBSTACLE) for f in frames))


def test_last_keeps_the_box_in_fog_that_strongest_loses(fog_box):
    """The issue's test: in fog of 30 m visual range the fog's near-field echo (within 0.2 m of the sensor, on
    the beams' way out) peaks higher than the box 15 m ahead, whose light the fog attenuates both ways: strongest
    reports the near echo and loses the box, last reports the box behind it."""
    counts = {mode: _obstacle(fog_box[mode]) for mode in RETURN_MODES}
    print(f"box points in 5 frames, fog 30 m: {counts}")
    assert counts["last"] == counts["dual"] == counts["all"]  # the box is every beam's last echo that hits it
    assert counts["last"] >= 1.5 * counts["strongest"]
    assert counts["first"] <= counts["strongest"]
    assert counts["strongest"] < counts["all"]
