"""Filter a recording offline (``weather-filter apply BAG --out BAG2``), as weather_filter_node would live.

Every message of BAG is copied to BAG2 as it was stored (same topic, type, log time, bytes), except the
clouds of the cloud topic (unless given: /lidar/points, else the bag's only PointCloud2 topic): each is decoded, filtered with
``method`` (default: the node's, the learned filter, with the geometry-only ``fallback`` for clouds lacking
its fields) and written in its place with the same header stamp, frame and log time; with ``removed_topic``
the removed points are written there too. Clouds of any common driver are read into the project's point
layout (:mod:`lidar_weather_sim.io.layouts`) and written in it. A cloud that cannot be decoded or filtered is left out of BAG2,
counted and named in the report (the node skips it the same way). BAG2 is closed with its index whatever
happens (:class:`lidar_weather_sim.io.bags.BagWriter`).
"""

from __future__ import annotations

from collections import Counter
from dataclasses import dataclass, field
from pathlib import Path

from rosbags.serde import SerdeError

from lidar_weather_sim.io.bags import BagError, BagWriter, cloud_topic, read_raw, typestore
from lidar_weather_sim.io.cloud_codec import CloudFormatError
from lidar_weather_sim.io.layouts import CloudReader
from weather_filter.filter_methods import DEFAULT_METHOD, make_filter_with_fallback
from weather_filter.points.base import MissingFieldsError
from weather_filter.points.cloud_check import CloudFieldError


@dataclass
class ApplyReport:
    """What :func:`apply_bag` did: clouds filtered and skipped (with the first reasons), points in and out."""

    topic: str
    clouds: int = 0
    points_in: int = 0
    points_out: int = 0
    other_messages: int = 0
    filters: Counter = field(default_factory=Counter)  # filter name -> clouds it filtered
    skipped: list[str] = field(default_factory=list)  # one reason per skipped cloud

    def summary(self) -> str:
        used = ", ".join(f"{name} {n}" for name, n in self.filters.items()) or "none"
        removed = self.points_in - self.points_out
        share = f" ({100 * removed / self.points_in:.1f} %)" if self.points_in else ""
        text = (f"{self.topic}: {self.clouds} clouds filtered ({used}), {removed} of {self.points_in} points "
                f"removed{share}; {self.other_messages} other messages copied")  # fmt: skip
        if self.skipped:
            text += f"; {len(self.skipped)} clouds skipped, the first: {self.skipped[0]}"
        return text


def apply_bag(bag: str | Path, out: str | Path, *, topic: str | None = None, method: str = DEFAULT_METHOD,
              fallback: str = "dror", removed_topic: str | None = None, overwrite: bool = False) -> ApplyReport:  # fmt: skip
    """Write BAG with its clouds filtered to ``out`` (a rosbag2 directory, MCAP); returns the report."""
    if Path(out).resolve() == Path(bag).resolve():
        raise BagError(f"--out {out} is the input bag: write the filtered recording elsewhere")
    topic = cloud_topic(bag, topic)
    if removed_topic == topic:
        raise ValueError(f"--removed {removed_topic} is the cloud topic itself")
    filt = make_filter_with_fallback(method, fallback)
    report = ApplyReport(topic)
    store = typestore()
    reader = CloudReader(f"{bag} {topic}")
    with BagWriter(out, overwrite=overwrite) as writer:
        for index, (name, msgtype, log_time, data) in enumerate(read_raw(bag)):
            if name != topic:
                writer.write_serialized(name, msgtype, data, log_time)
                report.other_messages += 1
                continue
            try:
                msg = store.deserialize_cdr(data, msgtype)
                frame = reader.read_message(msg)
                points = frame.points
                result = filt(points)
            except (SerdeError, CloudFormatError, CloudFieldError, MissingFieldsError, KeyError, ValueError) as exc:
                report.skipped.append(f"message {index} at log time {log_time} ns: {exc}")
                continue
            stamp_ns = frame.stamp_ns
            kept = points[~result.remove]
            writer.write_cloud(topic, kept, stamp_ns, msg.header.frame_id, log_time)
            if removed_topic:
                writer.write_cloud(removed_topic, points[result.remove], stamp_ns, msg.header.frame_id, log_time)
            report.clouds += 1
            report.points_in += len(points)
            report.points_out += len(kept)
            report.filters[getattr(filt, "last_used", filt.name)] += 1
    return report
