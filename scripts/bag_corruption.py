#!/usr/bin/env python3
"""Corrupt copies of a bag and count how each is read: identically, refused as damaged, or differently.

Each case copies BAG, XORs 1-3 seeded random bytes of its MCAP file with a random non-zero byte, and
reads it with ``bag_info`` and ``read_messages`` (what every command uses). "differently" (records or
message count not those of the intact bag) and "other errors" (anything but a BagError) must be 0.
Exit 1 otherwise.

    python scripts/bag_corruption.py BAG [--cases 1000] [--seed 0]
"""

from __future__ import annotations

import argparse
import shutil
import sys
import tempfile
from pathlib import Path

import numpy as np

from lidar_weather_sim.io.bags import BagError, _open_bag, _raw, bag_info


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("bag", type=Path)
    ap.add_argument("--cases", type=int, default=1000)
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args()
    bag = _open_bag(args.bag)
    if bag.storage != "mcap" or len(bag.files) != 1 or not bag.path.is_dir():
        ap.error(f"{args.bag}: a rosbag2 directory with one MCAP file is needed")
    intact = list(_raw(bag))
    rng = np.random.default_rng(args.seed)
    counts = {"identically": 0, "refused as damaged": 0, "differently": 0, "other errors": 0}
    for _ in range(args.cases):
        with tempfile.TemporaryDirectory() as tmp:
            copy = Path(tmp) / bag.path.name
            shutil.copytree(bag.path, copy)
            mcap = copy / bag.files[0].name
            data = bytearray(mcap.read_bytes())
            for _ in range(int(rng.integers(1, 4))):
                data[int(rng.integers(len(data)))] ^= int(rng.integers(1, 256))
            mcap.write_bytes(bytes(data))
            try:
                info, got = bag_info(copy), list(_raw(_open_bag(copy)))
                counts["identically" if got == intact and info.message_count == len(intact) else "differently"] += 1
            except BagError:
                counts["refused as damaged"] += 1
            except Exception as exc:  # noqa: BLE001 - counted and shown: the figure this script exists for
                counts["other errors"] += 1
                print(f"other error: {exc!r}", file=sys.stderr)
    size = bag.files[0].stat().st_size
    print(f"{args.cases} corrupted copies of {args.bag} ({size} bytes, {len(intact)} messages): "
          + ", ".join(f"{k} {v}" for k, v in counts.items()))  # fmt: skip
    return 0 if counts["differently"] == counts["other errors"] == 0 else 1


if __name__ == "__main__":
    sys.exit(main())
