"""Damaged bags are read identically or refused as damaged, never silently changed; a killed writer
loses at most 0.5 s of data (lidar_weather_sim.io.mcap_checks).

Seeded property-based fuzzing flips bytes anywhere in a recorded MCAP (``FUZZ_CASES=N`` sets the
number of cases; CI runs 100) and reads it back through the functions every command uses
(``bag_info``, ``read_messages``): the records are those of the intact bag, or one BagError names
the bag. The reported cases are pinned: a flipped bit in a cloud (was read as a different cloud), a
record length of 2^64 - 1 (was an OverflowError traceback), a truncated bag (was "no PointCloud2
topic").
"""

from __future__ import annotations

import os
import shutil
import signal
import struct
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from lidar_weather_sim.io.bags import BagError, BagWriter, _open_bag, _raw, bag_info, read_clouds
from lidar_weather_sim.io.mcap_checks import CHUNK_SPAN_NS, first_damage
from lidar_weather_sim.testing.fixtures import one_frame, scene_of, simple_profile, wall

CASES = int(os.environ.get("FUZZ_CASES", "100"))


@pytest.fixture(scope="module")
def recorded(tmp_path_factory) -> tuple[Path, list]:
    """A bag of 6 clouds 0.2 s apart (2 chunks of 0.4 s) and its records as read intact."""
    from lidar_weather_sim.sim.simulator import LidarSimulator

    points = one_frame(LidarSimulator(simple_profile(), scene_of(wall(12.0, "concrete", 1)))).points
    bag = tmp_path_factory.mktemp("bags") / "rec"
    with BagWriter(bag) as writer:
        for k in range(6):
            writer.write_cloud("/lidar/points", points[k:], stamp_ns=k * 200_000_000, frame_id="lidar")
    return bag, list(_raw(_open_bag(bag)))


def _records(bag: Path) -> list:
    info = bag_info(bag)
    records = list(_raw(_open_bag(bag)))
    assert info.message_count == len(records)
    return records


def _copy(bag: Path, into: Path) -> Path:
    out = into / bag.name
    shutil.copytree(bag, out)
    return out


@settings(max_examples=CASES, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(flips=st.lists(st.tuples(st.floats(0.0, 1.0, exclude_max=True), st.integers(1, 255)), min_size=1, max_size=3))
def test_fuzz_a_flipped_byte_is_read_identically_or_refused_as_damaged(recorded, flips):
    bag, intact = recorded
    with tempfile.TemporaryDirectory() as tmp:
        copy = _copy(bag, Path(tmp))
        mcap = copy / f"{copy.name}.mcap"
        data = bytearray(mcap.read_bytes())
        for where, xor in flips:
            data[int(where * len(data))] ^= xor
        mcap.write_bytes(bytes(data))
        try:
            got = _records(copy)
        except BagError as err:
            assert str(copy) in str(err) and "\n" not in str(err), str(err)
            return
        assert got == intact


def _chunk_offsets(mcap: Path) -> list[int]:
    data = mcap.read_bytes()
    at, found = 8, []
    while data[at] != 0x02:
        (length,) = struct.unpack_from("<Q", data, at + 1)
        if data[at] == 0x06:
            found.append(at)
        at += 9 + length
    return found


def test_a_flipped_bit_in_a_cloud_names_the_file_and_the_chunk(recorded, tmp_path):
    """Was: eval read a different cloud and exited 0."""
    bag, _ = recorded
    copy = _copy(bag, tmp_path)
    mcap = copy / f"{copy.name}.mcap"
    chunk = _chunk_offsets(mcap)[1]
    data = bytearray(mcap.read_bytes())
    data[chunk + 400] ^= 0x10
    mcap.write_bytes(bytes(data))
    with pytest.raises(BagError, match=rf"^{mcap}: damaged at offset {chunk}: chunk checksum mismatch$"):
        list(read_clouds(copy))


def test_a_record_length_of_2_64_minus_1_is_refused_naming_the_offset(recorded, tmp_path):
    """Was: an OverflowError traceback in info, eval and compare. In the summary (which the index read
    uses) the summary checksum refuses it; in a chunk of an intact bag the index read never uses the
    chunk's own length (the records are read identically); in a bag without footer, which is read
    record by record, the walk names the record."""
    bag, intact = recorded
    copy = _copy(bag, tmp_path)
    mcap = copy / f"{copy.name}.mcap"
    data = bytearray(mcap.read_bytes())
    chunk = _chunk_offsets(mcap)[1]
    (summary_start,) = struct.unpack_from("<Q", data, len(data) - 8 - 20)
    broken = bytearray(data)
    broken[summary_start + 1 : summary_start + 9] = struct.pack("<Q", 2**64 - 1)
    mcap.write_bytes(bytes(broken))
    with pytest.raises(BagError, match=rf"^{mcap}: damaged at offset {summary_start}: summary checksum mismatch$"):
        bag_info(copy)
    broken = bytearray(data)
    broken[chunk + 1 : chunk + 9] = struct.pack("<Q", 2**64 - 1)
    mcap.write_bytes(bytes(broken))
    assert _records(copy) == intact
    mcap.write_bytes(bytes(broken[: summary_start]))  # no summary, no footer: read record by record
    assert first_damage(mcap) == (f"damaged at offset {chunk}: record length {2**64 - 1} runs past the end "
                                  f"of the file ({summary_start} bytes)")  # fmt: skip
    with pytest.raises(BagError, match=rf"^{mcap}: damaged at offset {chunk}: record length"):
        bag_info(copy)


def test_a_truncated_bag_is_read_up_to_its_last_whole_chunk(recorded, tmp_path):
    """Was: "no PointCloud2 topic"; a truncated bag is a damaged one, read up to where it breaks."""
    bag, intact = recorded
    copy = _copy(bag, tmp_path)
    mcap = copy / f"{copy.name}.mcap"
    chunks = _chunk_offsets(mcap)
    mcap.write_bytes(mcap.read_bytes()[: chunks[1] + 100])
    info = bag_info(copy)
    assert info.damaged and 0 < info.message_count < len(intact)
    assert _records(copy) == intact[: info.message_count]
    mcap.write_bytes(mcap.read_bytes()[: chunks[0] + 100])  # not even one whole chunk
    for topic in (None, "/lidar/points"):  # the bag's only cloud topic, or the one asked for
        with pytest.raises(BagError, match=r"has no sensor_msgs/msg/PointCloud2 topic( /lidar/points)? in its readable "
                                           r"part \(the bag is damaged"):  # fmt: skip
            list(read_clouds(copy, topic))


_KILLED_WRITER = """
import os, signal, sys
from lidar_weather_sim.io.bags import BagWriter, clock_message
writer = BagWriter(sys.argv[1])
for k in range(int(sys.argv[2])):
    writer.write("/clock", clock_message(k * 10_000_000), k * 10_000_000)
    print(k, flush=True)
os.kill(os.getpid(), signal.SIGKILL)
"""


@pytest.mark.parametrize("seed", range(10))
def test_a_killed_writer_loses_at_most_half_a_second(tmp_path, seed):
    """SIGKILL after a seeded number of /clock messages 10 ms apart: the bag holds every message
    logged more than 0.5 s before the last one written."""
    written = int(np.random.default_rng(seed).integers(5, 400))
    bag = tmp_path / "killed"
    proc = subprocess.run([sys.executable, "-c", _KILLED_WRITER, str(bag), str(written)], capture_output=True,
                          text=True, timeout=120)  # fmt: skip
    assert proc.returncode == -signal.SIGKILL, proc.stderr
    last_ns = (written - 1) * 10_000_000
    kept = [log for _, _, log, _ in _raw(_open_bag(bag))]
    assert kept == list(range(0, len(kept) * 10_000_000, 10_000_000))  # a prefix, nothing altered
    lost_ns = last_ns - (kept[-1] if kept else -10_000_000)
    assert lost_ns <= CHUNK_SPAN_NS, (written, len(kept))
