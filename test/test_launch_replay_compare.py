"""launch_testing for launch/replay_compare.launch.py (full ROS 2 install: colcon test / launch_test).

An offline run of highway_clear (``lidar-weather-sim run``, 12 frames) is
replayed: bag_player_node -> lidar_sim_node (tf mode, sim time) ->
recorder_node; when lidar_sim_node has cast the bag the others stop, then the
graph's ``compare`` step writes OUT_compare/metrics.json and launch shuts down.
Checks: the recording holds the bag's frames again, and the comparison finds
them indistinguishable. Skipped where launch_testing is not installed (here:
test/test_replay.py runs the same graph through `lidar-weather-sim up`).
"""

import json
import os
import subprocess
import sys
import tempfile
import unittest
from pathlib import Path

import pytest

pytest.importorskip("launch_testing", reason="launch_testing is not installed (no full ROS 2 install); "
                    "test/test_replay.py covers the same graph through `lidar-weather-sim up`")
pytest.importorskip("launch_ros", reason="launch_ros is not installed (no full ROS 2 install)")

import launch_testing.actions  # noqa: E402
import launch_testing.asserts  # noqa: E402
from launch.actions import IncludeLaunchDescription  # noqa: E402
from launch.launch_description_sources import PythonLaunchDescriptionSource  # noqa: E402

import launch  # noqa: E402

LAUNCH = os.path.join(os.path.dirname(__file__), "..", "launch", "replay_compare.launch.py")
WORK = Path(tempfile.mkdtemp(prefix="launch_replay_"))
SOURCE, OUT = WORK / "source", WORK / "replayed"
FRAMES = 12


@pytest.mark.launch_test
def generate_test_description():
    subprocess.run([sys.executable, "-m", "lidar_weather_sim.cli", "run", "highway_clear", "--frames", str(FRAMES),
                    "--out", str(SOURCE)], check=True, timeout=600)  # fmt: skip
    replay = IncludeLaunchDescription(
        PythonLaunchDescriptionSource(LAUNCH), launch_arguments={"bag": str(SOURCE), "out": str(OUT), "rate": "0.5"}.items()
    )
    return launch.LaunchDescription([replay, launch_testing.actions.ReadyToTest()])


class TestReplayCompare(unittest.TestCase):
    def test_compare_report_appears(self):
        import time

        metrics = Path(f"{OUT}_compare") / "metrics.json"
        deadline = time.monotonic() + 300.0
        while not metrics.exists() and time.monotonic() < deadline:
            time.sleep(0.5)
        self.assertTrue(metrics.exists(), f"no {metrics}")


@launch_testing.post_shutdown_test()
class TestAfterShutdown(unittest.TestCase):
    def test_exit_codes(self, proc_info):
        launch_testing.asserts.assertExitCodes(proc_info, allowable_exit_codes=[0, -2, -15])

    def test_recording_and_comparison(self):
        from lidar_weather_sim.io.bags import read_clouds

        replayed = list(read_clouds(OUT))
        self.assertGreaterEqual(len(replayed), FRAMES - 2)
        metrics = json.loads((Path(f"{OUT}_compare") / "metrics.json").read_text())
        self.assertEqual(metrics["frames"]["paired"], len(replayed))
        self.assertLess(metrics["gap"], 0.01)
