#!/usr/bin/env python3
"""How much a SIGKILL of recorder_node loses, killed at seeded random moments.

``lidar-weather-sim pattern`` publishes clouds at ``--rate`` Hz and recorder_node records them (log
time = the receiving node's clock, wall time); the recorder is SIGKILLed after a seeded 1-6 s of
recording. Loss = the kill's wall time minus the last log time in the (unindexed) bag. Prints one line
per trial and the largest loss; exit 1 if a trial lost more than 0.5 s (the longest chunk,
``lidar_weather_sim.io.mcap_checks``) plus ``--slack-s`` (the DDS delivery of the last messages).

``lidar-weather-sim run`` writes simulated time as fast as it can, so its loss cannot be timed against
the wall clock; it uses the same BagWriter, whose bound is checked by killing a writing process at 10
seeded moments (``src/lidar_weather_sim/test/test_bag_damage.py``).

    python scripts/kill_loss.py [--trials 10] [--seed 0] [--rate 25]
"""

from __future__ import annotations

import argparse
import os
import random
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from lidar_weather_sim.io.bags import _open_bag, _raw
from lidar_weather_sim.io.mcap_checks import CHUNK_SPAN_NS

CHUNK_SPAN_S = CHUNK_SPAN_NS / 1e9


def _env(tmp: Path) -> dict[str, str]:
    env = dict(os.environ)
    env.update(ROS_DOMAIN_ID=str(random.Random().randint(120, 230)), ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST",
               ROS_LOG_DIR=str(tmp / "ros_log"), PYTHONUNBUFFERED="1")  # fmt: skip
    return env


def recorder_trial(tmp: Path, after_s: float, rate: float) -> tuple[float, int]:
    env = _env(tmp)
    cli = [sys.executable, "-m", "lidar_weather_sim.cli"]
    pattern = subprocess.Popen([*cli, "pattern", "--rate", str(rate)], env=env, stdout=subprocess.DEVNULL,
                               stderr=subprocess.DEVNULL)  # fmt: skip
    bag = tmp / "rec"
    rec = subprocess.Popen([sys.executable, "-m", "lidar_weather_sim.ros.recorder_node", "--ros-args", "-p",
                            f"out:={bag}", "-p", "topics:=[/lidar/points]"], env=env, stdout=subprocess.DEVNULL,
                           stderr=subprocess.DEVNULL)  # fmt: skip
    try:
        deadline = time.monotonic() + 60
        while not any(bag.glob("*.mcap")) and time.monotonic() < deadline:
            time.sleep(0.05)
        time.sleep(after_s)
        killed_ns = time.time_ns()
        rec.send_signal(signal.SIGKILL)
        rec.wait(timeout=30)
    finally:
        pattern.terminate()
        pattern.wait(timeout=30)
    logs = [log for _, _, log, _ in _raw(_open_bag(bag))]
    return (killed_ns - max(logs)) / 1e9 if logs else float("inf"), len(logs)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--trials", type=int, default=10)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--rate", type=float, default=25.0, help="recorder: clouds per second")
    ap.add_argument("--slack-s", type=float, default=0.1, help="recorder: DDS delivery allowed on top of 0.5 s")
    args = ap.parse_args()
    rng = random.Random(args.seed)
    worst = 0.0
    for trial in range(args.trials):
        with tempfile.TemporaryDirectory() as tmp:
            after = rng.uniform(1.0, 6.0)
            lost, kept = recorder_trial(Path(tmp), after, args.rate)
            worst = max(worst, lost)
            print(f"trial {trial}: killed {after:.2f} s into recording: {kept} clouds kept, the last one logged "
                  f"{lost:.3f} s before the kill", flush=True)  # fmt: skip
    print(f"largest loss: {worst:.3f} s")
    return 0 if worst <= CHUNK_SPAN_S + args.slack_s else 1


if __name__ == "__main__":
    sys.exit(main())
