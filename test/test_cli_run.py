"""`lidar-weather-sim run`: a scenario into an MCAP bag with /clock, /tf, /tf_static and clouds."""

import subprocess

import numpy as np
import pytest
import yaml

from lidar_weather_sim.core.paths import config_dir
from lidar_weather_sim.io.bags import bag_info, read_clouds, read_messages


def test_run_writes_a_complete_recording(tmp_path, cli):
    out = tmp_path / "run"
    result = subprocess.run([*cli, "run", "highway_clear", "--frames", "12", "--out", str(out)],
                            capture_output=True, text=True, timeout=300)  # fmt: skip
    assert result.returncode == 0, result.stderr
    assert "wrote 12 frames" in result.stdout
    info = bag_info(out)
    topics = {t.name: t for t in info.topics}
    assert set(topics) == {"/clock", "/tf", "/tf_static", "/lidar/points"}
    assert info.storage == "mcap" and topics["/lidar/points"].count == 12 and topics["/tf_static"].count == 1
    clouds = list(read_clouds(out))
    stamps = np.array([c.stamp_ns for c in clouds])
    np.testing.assert_array_equal(np.diff(stamps), 40_000_000)  # scala4: a scan every 40 ms
    assert all(c.frame_id == "lidar" and len(c.points) > 500 for c in clouds)
    assert {2} <= set(np.unique(np.concatenate([c.points["label"] for c in clouds])))
    tf = [m for m in read_messages(out, ["/tf"])]
    xs = [t.transform.translation.x for m in tf for t in m.msg.transforms if t.child_frame_id == "base_link"]
    np.testing.assert_allclose(np.diff(xs), 24.72 * 0.01, atol=1e-6)


def test_run_with_a_bad_scenario_fails_with_one_line(tmp_path, cli):
    data = yaml.safe_load((config_dir() / "scenarios" / "highway_clear.yaml").read_text())
    data["ego"]["speed_m_s"] = -3
    bad = tmp_path / "bad.yaml"
    bad.write_text(yaml.safe_dump(data))
    result = subprocess.run([*cli, "run", str(bad), "--out", str(tmp_path / "o")], capture_output=True, text=True)
    assert result.returncode == 2
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1 and "key 'ego.speed_m_s': value -3" in lines[0] and str(bad) in lines[0]
    assert not (tmp_path / "o").exists()


@pytest.mark.slow
def test_same_seed_gives_a_bit_identical_bag(tmp_path, cli):
    """Rain, near field, spray particles, noise: every random process is seeded. Same seed, same bytes."""
    bags = []
    for parent, seed in (("a", 7), ("b", 7), ("c", 8)):
        out = tmp_path / parent / "run"  # same bag name: the name is written into the MCAP's metadata record
        result = subprocess.run([*cli, "run", "highway_spray", "--frames", "10", "--seed", str(seed), "--out", str(out)],
                                capture_output=True, text=True, timeout=300)  # fmt: skip
        assert result.returncode == 0, result.stderr
        bags.append({f.name: f.read_bytes() for f in sorted(out.iterdir())})
    assert set(bags[0]) == {"run.mcap", "metadata.yaml"}
    assert bags[0] == bags[1]
    assert bags[0]["run.mcap"] != bags[2]["run.mcap"]  # another seed, another recording


def _one_line_error(result, *needles):
    lines = result.stderr.strip().splitlines()
    assert result.returncode == 2, result.stderr
    assert all(n in lines[-1] for n in needles), lines[-1]


def test_counts_and_rates_below_their_range_are_refused_naming_the_option(tmp_path, cli):
    """0 or -3 frames used to write an empty bag (rc 0); gap with 0 held-out frames reported 'no effect'."""
    out = tmp_path / "o"
    for argv, option, reason in (
        (["run", "highway_clear", "--frames", "0", "--out", str(out)], "--frames", "at least 1, got 0"),
        (["run", "highway_clear", "--frames", "-3", "--out", str(out)], "--frames", "at least 1, got -3"),
        (["run", "highway_clear", "--seed", "-1", "--out", str(out)], "--seed", "0 or more, got -1"),
        (["make-measured", "highway_clear", "--frames", "0", "--out", str(out)], "--frames", "at least 1"),
        (["reproduce", "rooftop", "--frames", "0", "--out", str(out)], "--frames", "at least 1"),
        (["gap", "bag", "--scenario", "highway_clear", "--heldout-frames", "0", "--out", str(out)], "--heldout-frames",
         "at least 1"),
        (["gap", "bag", "--scenario", "highway_clear", "--fit-frames", "0", "--out", str(out)], "--fit-frames",
         "at least 1"),
        (["play", "bag", "--rate", "0"], "--rate", "above 0, got 0"),
        (["closed-loop", "--seconds", "nan", "--out", str(out)], "--seconds", "above 0, got nan"),
    ):
        result = subprocess.run([*cli, *argv], capture_output=True, text=True, timeout=120)
        _one_line_error(result, option, reason)
        assert not out.exists()


@pytest.mark.slow
def test_make_measured_on_a_recording_refuses_options_it_cannot_honour(tmp_path, cli):
    """--on uses every frame of its recording at the scenario's seed: --frames/--seed were silently ignored; a
    recording has no ground truth to keep; --beams-per-frame is the reference's, --intensity-scale a recording's."""
    out = tmp_path / "o"
    for extra, reason in ((["--frames", "1"], "--frames and --seed apply only without --on"),
                          (["--seed", "5"], "--frames and --seed apply only without --on"),
                          (["--labels"], "--labels applies only without --on"),
                          (["--beams-per-frame", "64"], "--beams-per-frame is the reference's"),
                          ([], "needs at least one --hide")):  # fmt: skip
        hide = [] if not extra else ["--hide", "atmosphere.fog:visual_range=60"]
        result = subprocess.run([*cli, "make-measured", "highway_clear", "--on", str(tmp_path), *hide, *extra,
                                 "--out", str(out)], capture_output=True, text=True, timeout=120)  # fmt: skip
        _one_line_error(result, reason)
        assert not out.exists()
    result = subprocess.run([*cli, "make-measured", "highway_clear", "--hide", "atmosphere.fog:visual_range=60",
                             "--intensity-scale", "reflectivity", "--out", str(out)],
                            capture_output=True, text=True, timeout=120)  # fmt: skip
    _one_line_error(result, "--intensity-scale", "needs --on BAG")
    assert not out.exists()


def test_a_bag_output_named_like_a_file_is_refused(tmp_path, cli):
    """rosbags would write OUT.mcap/OUT.mcap.mcap."""
    result = subprocess.run([*cli, "run", "highway_clear", "--frames", "1", "--out", str(tmp_path / "run.mcap")],
                            capture_output=True, text=True, timeout=300)  # fmt: skip
    _one_line_error(result, "run.mcap", "a rosbag2 output is a directory")
    assert not (tmp_path / "run.mcap").exists()


def test_recover_says_when_a_bag_is_intact(tmp_path, cli):
    out = tmp_path / "run"
    assert subprocess.run([*cli, "run", "highway_clear", "--frames", "2", "--out", str(out)],
                          capture_output=True, timeout=300).returncode == 0  # fmt: skip
    before = {f.name: f.read_bytes() for f in out.iterdir()}
    result = subprocess.run([*cli, "recover", str(out)], capture_output=True, text=True, timeout=120)
    assert result.returncode == 0 and "is intact" in result.stdout and "nothing to do" in result.stdout, result.stdout
    assert {f.name: f.read_bytes() for f in out.iterdir()} == before


@pytest.mark.slow
def test_the_return_mode_flag_is_honoured_and_an_unknown_mode_refused(tmp_path, cli):
    out = tmp_path / "strongest"
    result = subprocess.run([*cli, "run", "highway_clear", "--frames", "2", "--return-mode", "strongest", "--out",
                             str(out)], capture_output=True, text=True, timeout=300)  # fmt: skip
    assert result.returncode == 0, result.stderr
    for cloud in read_clouds(out):
        points = cloud.points
        assert (points["return_type"] == 3).all()  # Nebula's STRONGEST
        assert np.unique(points[["channel", "time_stamp"]], return_counts=True)[1].max() == 1  # one point per beam
    bad = tmp_path / "bad"
    result = subprocess.run([*cli, "run", "highway_clear", "--frames", "1", "--return-mode", "nearest", "--out", str(bad)],
                            capture_output=True, text=True, timeout=120)  # fmt: skip
    _one_line_error(result, "--return-mode", "'nearest'", "'strongest', 'last', 'dual', 'first', 'all'")
    assert not bad.exists()
