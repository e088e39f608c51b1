"""launch_testing for launch/replay_compare.launch.py (full ROS 2 install: colcon test / launch_test).

An offline run of highway_clear (``lidar-weather-sim run``, 12 frames) is
replayed: bag_player_node -> lidar_sim_node (tf mode, sim time) ->
recorder_node; when lidar_sim_node has cast the bag the others stop, then the
graph's ``compare`` step writes metrics.json, report.md and the plots to
OUT_compare. The test keeps launch alive (``keep_alive``) until compare has
exited, so that compare is never cut short. Checks: every process exits with
status 0 (the nodes stopped by the graph's one SIGINT included), the recording
holds the bag's frames again, and the comparison's files are all written and
find them indistinguishable. Skipped where launch_testing is not installed
(here: test/test_replay.py runs the same graph through `lidar-weather-sim up`).
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
import launch_testing.markers  # noqa: E402
from launch.actions import IncludeLaunchDescription  # noqa: E402
from launch.launch_description_sources import PythonLaunchDescriptionSource  # noqa: E402

import launch  # noqa: E402

LAUNCH = os.path.join(os.path.dirname(__file__), "..", "launch", "replay_compare.launch.py")
WORK = Path(tempfile.mkdtemp(prefix="launch_replay_"))
SOURCE, OUT = WORK / "source", WORK / "replayed"
COMPARE = Path(f"{OUT}_compare")
FRAMES = 12


@pytest.mark.launch_test
@launch_testing.markers.keep_alive
def generate_test_description():
    subprocess.run([sys.executable, "-m", "lidar_weather_sim.cli", "run", "highway_clear", "--frames", str(FRAMES),
                    "--out", str(SOURCE)], check=True, timeout=600)  # fmt: skip
    replay = IncludeLaunchDescription(
        PythonLaunchDescriptionSource(LAUNCH), launch_arguments={"bag": str(SOURCE), "out": str(OUT), "rate": "0.5"}.items()
    )
    return launch.LaunchDescription([replay, launch_testing.actions.ReadyToTest()])


class TestReplayCompare(unittest.TestCase):
    def test_graph_and_compare_run_to_the_end(self, proc_info):
        proc_info.assertWaitForShutdown(process="compare", timeout=300.0)


@launch_testing.post_shutdown_test()
class TestAfterShutdown(unittest.TestCase):
    def test_exit_codes(self, proc_info):
        launch_testing.asserts.assertExitCodes(proc_info)  # 0 each: the nodes, compare

    def test_recording_and_comparison(self):
        from lidar_weather_sim.io.bags import read_clouds

        replayed = list(read_clouds(OUT))
        self.assertGreaterEqual(len(replayed), FRAMES - 2)
        written = sorted(p.name for p in COMPARE.iterdir())
        self.assertEqual(written, ["bev.png", "metrics.json", "ranges.png", "report.md", "returns_by_channel.png"])
        self.assertTrue(all((COMPARE / name).stat().st_size > 0 for name in written))
        metrics = json.loads((COMPARE / "metrics.json").read_text())
        self.assertEqual(metrics["frames"]["paired"], len(replayed))
        self.assertLess(metrics["gap"], 0.01)
