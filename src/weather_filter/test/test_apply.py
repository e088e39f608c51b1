"""``weather-filter apply``: a recording filtered offline with the node's defaults, every other topic kept."""

from __future__ import annotations

import subprocess
import sys

import numpy as np
import pytest

from lidar_weather_sim.core.points import Label
from lidar_weather_sim.io.bags import BagWriter, read_clouds, read_raw
from lidar_weather_sim.scenario.schema import load_scenario
from lidar_weather_sim.sim.offline import run_scenario
from weather_filter.apply import apply_bag
from weather_filter.cli import main
from weather_filter.filter_methods import make_filter_with_fallback

WEATHER = [int(Label.RAIN), int(Label.SPRAY)]
FRAMES = 6


@pytest.fixture(scope="module")
def spray_bag(tmp_path_factory):
    """6 scala4 frames of highway_spray (rain and the spray of the car ahead) with /clock, /tf, /tf_static."""
    path = tmp_path_factory.mktemp("apply") / "spray"
    run_scenario(load_scenario("highway_spray"), path, frames=FRAMES, seed=3)
    return path


def test_apply_filters_every_cloud_as_the_library_does_and_copies_every_other_message(spray_bag, tmp_path):
    out = tmp_path / "filtered"
    report = apply_bag(spray_bag, out, removed_topic="/lidar/points/removed")
    assert (report.topic, report.clouds, report.skipped) == ("/lidar/points", FRAMES, [])
    others = lambda bag: [m for m in read_raw(bag) if not m[0].startswith("/lidar/points")]  # noqa: E731
    assert others(out) == others(spray_bag) and len(others(out)) == report.other_messages > 0  # bytes and log times
    reference = make_filter_with_fallback("learned", "dror")  # the node's defaults, fresh state
    removed_total = kept_total = 0
    for raw, kept, removed in zip(read_clouds(spray_bag), read_clouds(out), read_clouds(out, "/lidar/points/removed")):
        mask = reference(raw.points).remove
        assert (kept.stamp_ns, kept.log_time_ns, kept.frame_id) == (raw.stamp_ns, raw.log_time_ns, raw.frame_id)
        assert np.array_equal(kept.points, raw.points[~mask]) and np.array_equal(removed.points, raw.points[mask])
        removed_total, kept_total = removed_total + len(removed.points), kept_total + len(kept.points)
    assert report.points_in - report.points_out == removed_total and report.points_out == kept_total
    # what it removes is the weather: most rain and spray points go, nearly every solid point stays
    raw = np.concatenate([f.points for f in read_clouds(spray_bag)])
    kept = np.concatenate([f.points for f in read_clouds(out)])
    weather_left = np.isin(kept["label"], WEATHER).sum() / max(1, np.isin(raw["label"], WEATHER).sum())
    solid_kept = (kept["label"] < 10).sum() / (raw["label"] < 10).sum()
    assert weather_left < 0.2 and solid_kept > 0.95, (weather_left, solid_kept)


def test_a_cloud_it_cannot_decode_is_skipped_and_named(tmp_path, spray_bag):
    bag = tmp_path / "with_bad"
    with BagWriter(bag) as writer:
        for k, (topic, msgtype, log_time, data) in enumerate(read_raw(spray_bag, ["/lidar/points"])):
            writer.write_serialized(topic, msgtype, data[: len(data) // 2] if k == 3 else data, log_time)
    report = apply_bag(bag, tmp_path / "out")
    assert report.clouds == FRAMES - 1 and len(report.skipped) == 1 and report.skipped[0].startswith("message 3 at log time")
    assert len(list(read_clouds(tmp_path / "out"))) == FRAMES - 1


def test_the_cli_names_what_is_wrong_in_one_line(spray_bag, tmp_path, capsys):
    cli = [sys.executable, "-m", "weather_filter.cli", "apply"]
    two = tmp_path / "two_topics"
    with BagWriter(two) as writer:
        for topic, msgtype, log_time, data in read_raw(spray_bag, ["/lidar/points"]):
            writer.write_serialized("/lidar/front", msgtype, data, log_time)
            writer.write_serialized("/lidar/rear", msgtype, data, log_time)
    cases = [([str(two), "--out", str(tmp_path / "a")], "2 PointCloud2 topics (/lidar/front, /lidar/rear); choose one with --topic"),
             ([str(spray_bag), "--out", str(spray_bag)], "is the input bag"),
             ([str(spray_bag), "--out", str(tmp_path / "b"), "--topic", "/tf"], "has no PointCloud2 topic /tf")]  # fmt: skip
    for args, reason in cases:  # in this process (main() as the console script calls it): one line, status 2
        assert main(["apply", *args]) == 2
        err = capsys.readouterr().err
        assert reason in err and len(err.strip().splitlines()) == 1, err
    assert not (tmp_path / "a").exists() and not (tmp_path / "b").exists()
    run = subprocess.run([*cli, str(two), "--topic", "/lidar/front", "--out", str(tmp_path / "c")], capture_output=True, text=True)
    assert run.returncode == 0 and f"/lidar/front: {FRAMES} clouds filtered (learned {FRAMES})" in run.stdout, run.stderr
    assert len(list(read_clouds(tmp_path / "c", "/lidar/rear"))) == FRAMES  # the other cloud topic copied as it was
