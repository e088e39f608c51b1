#!/usr/bin/env python3
"""Does recorder_node keep every frame? lidar_sim_node at real time (/clock and /tf at 100 Hz, clouds at the
profile's rate) into recorder_node over DDS, then published clouds vs clouds in the bag.

Both nodes run as separate processes on a private DDS domain. The sim node
holds simulated time until the recorder subscribes (``wait_for_subscriber``)
and stops after ``duration x rate`` clouds (``max_frames``); then the recorder
gets SIGINT and closes the bag. Checked on the bag as written: the number of
clouds, their stamps (one per frame period, none missing or repeated) and the
/tf and /clock messages. Prints a JSON summary; exits 1 if a cloud is missing.

    python scripts/recorder_reliability.py --duration-s 600          # the 10-minute run
    python scripts/recorder_reliability.py --duration-s 60 --out DIR # the CI run (test/test_recorder_reliability.py)
"""

from __future__ import annotations

import argparse
import json
import os
import random
import re
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from lidar_weather_sim.core.names import TOPIC_CLOCK, TOPIC_POINTS, TOPIC_TF
from lidar_weather_sim.io.bags import bag_info, read_messages
from lidar_weather_sim.ros.conversions import stamp_to_ns
from lidar_weather_sim.scenario.schema import load_scenario
from lidar_weather_sim.sensor.profile import load_profile


def _env(log_dir: Path) -> dict[str, str]:
    env = dict(os.environ)
    env.setdefault("ROS_DOMAIN_ID", str(random.Random().randint(120, 230)))
    env.update(ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST", ROS_LOG_DIR=str(log_dir), PYTHONUNBUFFERED="1")
    return env


def _node(module: str, params: dict, env: dict, log: Path) -> subprocess.Popen:
    args = [sys.executable, "-m", module, "--ros-args"]
    for name, value in params.items():
        args += ["-p", f"{name}:={value}"]
    return subprocess.Popen(args, env=env, stdout=log.open("w"), stderr=subprocess.STDOUT)


def run(duration_s: float, scenario: str, out: Path) -> dict:
    rate = load_profile(load_scenario(scenario).sensor.profile).scan.frame_rate_hz
    frames = int(round(duration_s * rate))
    out.mkdir(parents=True, exist_ok=True)
    bag, env = out / "bag", _env(out / "ros_log")
    topics = f"[{TOPIC_POINTS},{TOPIC_TF},{TOPIC_CLOCK}]"
    recorder = _node("lidar_weather_sim.ros.recorder_node", {"out": bag, "topics": topics, "overwrite": "true"},
                     env, out / "recorder.log")  # fmt: skip
    start = time.monotonic()
    sim = _node("lidar_weather_sim.ros.lidar_sim_node", {"scenario": scenario, "max_frames": frames, "realtime_factor": 1.0,
                "wait_for_subscriber": "true"}, env, out / "sim.log")  # fmt: skip
    try:
        sim_status = sim.wait(timeout=duration_s * 3 + 120)
    finally:
        sim.kill() if sim.poll() is None else None
    wall_s = time.monotonic() - start
    time.sleep(1.0)  # the last cloud's way through DDS
    recorder.send_signal(signal.SIGINT)
    recorder_status = recorder.wait(timeout=60)
    sim_log = (out / "sim.log").read_text()
    published = int(re.search(r"published (\d+) clouds", sim_log).group(1)) if "published" in sim_log else -1
    counts = {t.name: t.count for t in bag_info(bag).topics}
    stamps = np.array([stamp_to_ns(m.msg.header.stamp) for m in read_messages(bag, [TOPIC_POINTS])], dtype=np.int64)
    period_ns = round(1e9 / rate)
    gaps = np.diff(stamps)
    return {
        "duration_s": duration_s, "scenario": scenario, "frame_rate_hz": rate, "wall_s": round(wall_s, 1),
        "sim_exit": sim_status, "recorder_exit": recorder_status,
        "clouds_published": published, "clouds_recorded": counts.get(TOPIC_POINTS, 0),
        "clouds_missing": published - counts.get(TOPIC_POINTS, 0),
        "stamp_gaps": int((gaps != period_ns).sum()), "first_stamp_ns": int(stamps[0]) if len(stamps) else None,
        "last_stamp_ns": int(stamps[-1]) if len(stamps) else None,
        "tf_recorded": counts.get(TOPIC_TF, 0), "clock_recorded": counts.get(TOPIC_CLOCK, 0),
        "bag_mb": round(sum(f.stat().st_size for f in bag.iterdir()) / 2**20, 1),
    }  # fmt: skip


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--duration-s", type=float, default=600.0, help="simulated = wall seconds to record")
    parser.add_argument("--scenario", default="rooftop_static",
                        help="default rooftop_static: a fixed sensor lasts any duration; a driving scenario's node stops "
                             "when its ego reaches the end of the road (highway_clear: 38.5 s)")  # fmt: skip
    parser.add_argument("--out", type=Path, default=None, help="working directory (default: a temporary one)")
    args = parser.parse_args()
    with tempfile.TemporaryDirectory(prefix="recorder_reliability_") as tmp:
        summary = run(args.duration_s, args.scenario, args.out or Path(tmp))
    print(json.dumps(summary, indent=1))
    ok = summary["clouds_missing"] == 0 and summary["stamp_gaps"] == 0 and summary["clouds_published"] > 0
    sys.exit(0 if ok else 1)


if __name__ == "__main__":
    main()
