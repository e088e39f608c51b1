"""weather_filter_node in its own process over DDS: filtered/removed clouds, diagnostics, malformed input."""

import sys

import numpy as np
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
from rclpy.qos import qos_profile_sensor_data
from sensor_msgs.msg import PointCloud2

from lidar_weather_sim.core.points import Label, strip_ground_truth
from lidar_weather_sim.ros.conversions import cloud_to_msg, msg_to_cloud
from weather_filter.synthetic import highway_frame

NODE = [sys.executable, "-m", "weather_filter.ros.weather_filter_node"]
OK, ERROR = DiagnosticStatus.OK, DiagnosticStatus.ERROR


def _wire(ros):
    got = {"filtered": [], "removed": [], "diag": []}
    ros.node.create_subscription(PointCloud2, "/lidar/points/filtered", got["filtered"].append, qos_profile_sensor_data)
    ros.node.create_subscription(PointCloud2, "/lidar/points/removed", got["removed"].append, qos_profile_sensor_data)
    diag = ros.node.create_subscription(DiagnosticArray, "/diagnostics", got["diag"].append, 10)
    pub = ros.node.create_publisher(PointCloud2, "/lidar/points", qos_profile_sensor_data)
    assert ros.spin_until(lambda: pub.get_subscription_count() > 0, timeout_s=30), "node did not subscribe"
    # the node's first diagnostics are volatile: they reach only a subscription already matched
    assert ros.spin_until(lambda: diag.get_publisher_count() > 0, timeout_s=30), "no /diagnostics publisher"
    return got, pub


def _publish_until(ros, pub, msgs, done, tries=100):
    for _ in range(tries):  # best-effort QoS: repeat until seen
        for msg in msgs:
            pub.publish(msg)
        ros.spin_until(done, timeout_s=0.2)
        if done():
            return True
    return False


def test_node_splits_a_labelled_cloud_and_reports_diagnostics(processes, ros):
    node = processes.start(*NODE, "--ros-args", "-p", "method:=echo")
    got, pub = _wire(ros)
    points = highway_frame("rain", seed=11, obstacle_in_spray=True)
    msg, _ = cloud_to_msg(points, stamp_ns=123, frame_id="lidar")
    ok = _publish_until(ros, pub, [msg], lambda: got["filtered"] and got["removed"] and got["diag"])
    assert ok, processes.output(node)
    filtered = msg_to_cloud(got["filtered"][-1]).points
    removed = msg_to_cloud(got["removed"][-1]).points
    assert filtered.dtype.names == points.dtype.names == removed.dtype.names
    assert len(filtered) + len(removed) == len(points)
    assert (removed["label"] >= 10).all() and (filtered["label"] == Label.OBSTACLE).sum() == (points["label"] == Label.OBSTACLE).sum()
    values = {kv.key: kv.value for kv in got["diag"][-1].status[0].values}
    assert values["method"] == "echo" and int(values["points_in"]) == len(points)
    assert int(values["label_11_in"]) == int((points["label"] == Label.RAIN).sum())
    assert float(values["time_ms"]) > 0
    assert node.poll() is None


def test_node_skips_malformed_clouds_and_falls_back_without_echo_fields(processes, ros):
    node = processes.start(*NODE)  # the defaults: the learned filter, DROR for clouds without its fields
    got, pub = _wire(ros)
    bad, _ = cloud_to_msg(highway_frame("rain"), stamp_ns=1, frame_id="lidar")
    bad.data = bytes(bad.data)[:-3]
    plain = strip_ground_truth(highway_frame("rain", seed=4))
    xyz_only = np.zeros(len(plain), dtype=[("x", "<f4"), ("y", "<f4"), ("z", "<f4")])
    for axis in "xyz":
        xyz_only[axis] = plain[axis]
    good, _ = cloud_to_msg(xyz_only, stamp_ns=2, frame_id="lidar")
    statuses = lambda level: [d.status[0] for d in got["diag"] if d.status[0].level == level]  # noqa: E731
    # best-effort input: publish until two skips and a filtered cloud have come through
    done = lambda: statuses(OK) and len(statuses(ERROR)) >= 2  # noqa: E731
    assert _publish_until(ros, pub, [bad, bad, good], done), processes.output(node)
    assert node.poll() is None, "node must keep running after a malformed cloud"
    skipped = statuses(ERROR)[-1]  # every skipped cloud is on /diagnostics, not only the first of its cause
    assert skipped.message.startswith("skipped malformed cloud: data length") and skipped.hardware_id == "lidar"
    counts = [int({kv.key: kv.value for kv in s.values}["clouds_skipped"]) for s in statuses(ERROR)]
    assert counts == list(range(counts[0], counts[0] + len(counts))) and len(counts) >= 2, counts  # none missed
    values = {kv.key: kv.value for kv in statuses(OK)[-1].values}
    assert values["method"] == "dror"
    pairs, errors = [], 0  # each OK status counts the ERROR statuses before it (one publisher, reliable QoS: in order)
    for d in got["diag"]:
        if d.status[0].level == ERROR:
            errors += 1
        else:
            pairs.append((int({kv.key: kv.value for kv in d.status[0].values}["clouds_skipped"]), errors))
    assert all(count == seen for count, seen in pairs), pairs
    out = processes.output(node)
    assert out.count("skipped malformed cloud: data length") == 1, out
    assert "(needed by 'learned'): using geometry-only 'dror'" in out


def test_learned_node_survives_clouds_the_decoder_accepts_but_no_filter_can_use(processes, ros):
    """The reported crashers, each a valid PointCloud2: an INT32 channel of -2e9 (segfaulted the learned
    filter), a channel of 2e7 (a 1.5 GB range image), a FLOAT64 x of 1e300 and half the cloud at the
    origin. The node keeps running: the channels are skipped with a reason naming the field, the far
    point and the placeholders are removed and counted, and every cloud after them is filtered."""
    node = processes.start(*NODE, "--ros-args", "-p", "method:=learned")
    got, pub = _wire(ros)
    frame = highway_frame("rain", seed=6)
    descr = [(n, np.int32 if n == "channel" else np.float64 if n in "xyz" else frame.dtype.fields[n][0])
             for n in frame.dtype.names]  # fmt: skip
    wide = np.zeros(len(frame), descr)
    for n in frame.dtype.names:
        wide[n] = frame[n]
    negative, huge, far = wide.copy(), wide.copy(), wide.copy()
    negative["channel"][10] = -2_000_000_000
    huge["channel"][10] = 20_000_000
    far["x"][10] = 1e300
    placeholders = np.concatenate([wide, np.zeros(len(wide), descr)])
    msgs = [cloud_to_msg(c, stamp_ns=k + 1, frame_id="lidar")[0] for k, c in enumerate((negative, huge, far, placeholders))]
    by_stamp = lambda: {d.header.stamp.nanosec: d.status[0] for d in got["diag"]}  # noqa: E731
    filtered_stamps = lambda: {m.header.stamp.nanosec for m in got["filtered"]}  # noqa: E731
    for k, msg in enumerate(msgs, start=1):  # one at a time (best-effort input; a new field type compiles first)
        # a refused cloud has only its status; a filtered one also its output (best-effort: it may need a resend)
        seen = lambda k=k: k in by_stamp() and (k <= 2 or k in filtered_stamps())  # noqa: E731
        assert _publish_until(ros, pub, [msg], seen, tries=300), (k, processes.output(node))
    assert node.poll() is None, processes.output(node)
    status = by_stamp()
    assert status[1].level == ERROR and "field 'channel': value -2000000000 outside 0..1023" in status[1].message
    assert status[2].level == ERROR and "field 'channel': value 20000000 outside 0..1023" in status[2].message
    for stamp, set_aside in ((3, 1), (4, len(wide))):
        values = {kv.key: kv.value for kv in status[stamp].values}
        assert status[stamp].level == OK and values["points_set_aside"] == str(set_aside), (stamp, values)
    filtered = {m.header.stamp.nanosec: msg_to_cloud(m).points for m in got["filtered"]}
    kept = filtered[4]  # the placeholders removed, the frame's rain mostly too, its road and cars kept
    assert not ((kept["x"] == 0) & (kept["y"] == 0) & (kept["z"] == 0)).any()
    solid = np.isin(wide["label"], [Label.STATIC, Label.VEHICLE])
    assert 0.95 * solid.sum() <= len(kept) < len(wide), (len(kept), solid.sum(), len(wide))
    assert "Traceback" not in processes.output(node)
