"""Child process for test_bags: records deterministic clouds forever until signalled or killed.

Usage: bag_writer_child.py OUT STORAGE [LIMIT]. Prints "ready" once a few messages are
written; with LIMIT, returns after LIMIT messages. The writer is never closed by this
script, and SIGINT/SIGTERM have their default (process-killing) disposition, so only
BagWriter's own signal handlers and atexit hook can finish the bag.
"""

import signal
import sys

import numpy as np

from lidar_weather_sim.core.names import FRAME_LIDAR, TOPIC_POINTS
from lidar_weather_sim.core.points import empty_points
from lidar_weather_sim.io.bags import BagWriter

N_POINTS = 3000
STAMP_LAG_NS = 5_000_000


def log_time_ns(i: int) -> int:
    """Log time of message ``i``; its header stamp is STAMP_LAG_NS earlier."""
    return 1_700_000_000_000_000_000 + i * 100_000_000


def make_points(i: int) -> np.ndarray:
    """The points of message ``i`` (seeded by ``i``)."""
    rng = np.random.default_rng(i)
    points = empty_points(N_POINTS)
    for name in ("x", "y", "z", "epw"):
        points[name] = rng.uniform(-80, 80, N_POINTS)
    points["intensity"] = rng.integers(0, 256, N_POINTS)
    points["label"] = rng.integers(0, 16, N_POINTS)
    points["object_id"] = rng.integers(0, 2**32, N_POINTS, dtype=np.uint32)
    return points


def main() -> None:
    out, storage = sys.argv[1:3]
    limit = int(sys.argv[3]) if len(sys.argv) > 3 else None
    signal.signal(signal.SIGINT, signal.SIG_DFL)
    writer = BagWriter(out, storage=storage)
    i = 0
    while i != limit:
        stamp = log_time_ns(i) - STAMP_LAG_NS
        writer.write_cloud(TOPIC_POINTS, make_points(i), stamp, FRAME_LIDAR, log_time_ns=log_time_ns(i))
        if i == 3:
            print("ready", flush=True)
        i += 1


if __name__ == "__main__":
    main()
