"""Bag replay over DDS: bag_player_node drives lidar_sim_node (tf mode, sim time), recorder_node records it.

The input bag is an offline run of highway_clear (``lidar-weather-sim run``):
/tf and /clock every 10 ms, a cloud every 40 ms. Replayed through the graph
``replay_compare``, the node sees the same poses, so the recorded clouds carry
the bag's scan-start stamps and the same geometry; the graph's ``after`` step
then runs ``lidar-weather-sim compare`` on the bag and the recording.
"""

from __future__ import annotations

import json

import numpy as np
import pytest

from lidar_weather_sim.io.bags import bag_info, read_clouds, read_messages

FRAMES = 12


@pytest.mark.slow
def test_replayed_poses_give_the_recorded_clouds_again(processes, cli, tmp_path):
    source, out = tmp_path / "source", tmp_path / "replayed"
    run = processes.start(*cli, "run", "highway_clear", "--frames", str(FRAMES), "--out", str(source))
    assert run.wait(timeout=300) == 0, processes.output(run)
    up = processes.start(*cli, "up", "replay_compare", f"bag:={source}", f"out:={out}", "rate:=0.5",
                         "--run-dir", str(tmp_path / "run"))  # fmt: skip
    assert up.wait(timeout=300) == 0, processes.output(up)
    log = processes.output(up)
    assert "[up] bag_player_node exited with status 0" in log and "[up] recorder_node exited with status 0" in log
    assert "[up] compare exited with status 0" in log
    original = list(read_clouds(source))
    replayed = list(read_clouds(out))
    info = bag_info(out)
    assert not info.damaged and [t.name for t in info.topics] == ["/lidar/points"]
    tf_end = max(m.log_time_ns for m in read_messages(source, ["/tf"]))
    # frame i is complete once a pose at or after its last column (scan start + 16 ms) has arrived
    expected = [f.stamp_ns for f in original if f.stamp_ns + 20_000_000 <= tf_end]
    assert len(expected) >= FRAMES - 2
    assert [f.stamp_ns for f in replayed] == expected
    for a, b in zip(original, replayed):
        assert a.points.dtype.names == b.points.dtype.names
        assert len(a.points) == len(b.points)  # same poses, same batching (one advance per /tf message)
        assert set(np.unique(b.points["object_id"])) == set(np.unique(a.points["object_id"]))
    # log time of the recording is the replayed sim time: each cloud is logged after its scan start
    assert all(f.log_time_ns >= f.stamp_ns for f in replayed)
    # compare (the graph's after step): the replay is the recording again
    metrics = json.loads((tmp_path / "replayed_compare" / "metrics.json").read_text())
    assert metrics["frames"]["paired"] == len(replayed)
    assert metrics["gap"] < 0.01 and metrics["bev"]["pearson"] > 0.99, (metrics["gap"], metrics["bev"])
