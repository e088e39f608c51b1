"""foxglove_bridge_node over real DDS and a real WebSocket: `up sim foxglove:=true` and `play BAG --foxglove`.

A WebSocket client in the test (PyPI websockets) speaks Foxglove's protocol: it reads the ``advertise``
JSON, subscribes to channels by id and decodes the binary Message Data frames (opcode 0x01, subscription
id, log time, payload) and their protobuf payloads (lidar_weather_sim.testing.foxglove_wire). What it
receives is compared, number by number, with what the test itself receives over DDS or reads from the bag.
"""

from __future__ import annotations

import copy
import json
import re
import signal
import socket
import subprocess
import threading
from pathlib import Path

import numpy as np
import pytest

from lidar_weather_sim.testing.foxglove_wire import decode_point_cloud, message_data, protobuf_fields

# foxglove-sdk 0.30.3 speaks foxglove.sdk.v1 (and refuses a handshake offering only foxglove.websocket.v1)
SUBPROTOCOLS = ["foxglove.sdk.v1", "foxglove.websocket.v1"]
_SERVING = re.compile(r"serving ws://([0-9.]+):(\d+) ")


class FoxgloveClient(threading.Thread):
    """Connects, subscribes to ``topics`` as they are advertised, and keeps every message (topic, log time, payload)."""

    def __init__(self, url: str, topics: set[str]) -> None:
        super().__init__(daemon=True)
        self.url, self.topics = url, topics
        self.channels: dict[int, dict] = {}
        self.messages: list[tuple[str, int, bytes]] = []
        self.subprotocol = None
        self.error: BaseException | None = None
        self._stop_event = threading.Event()

    def run(self) -> None:
        from websockets.exceptions import ConnectionClosed
        from websockets.sync.client import connect

        try:
            with connect(self.url, subprotocols=SUBPROTOCOLS, max_size=None, compression=None, open_timeout=60) as ws:
                self.subprotocol = ws.subprotocol
                subscription = 0
                while not self._stop_event.is_set():
                    try:
                        frame = ws.recv(timeout=0.2)
                    except TimeoutError:
                        continue
                    except ConnectionClosed:
                        return
                    if isinstance(frame, str):
                        op = json.loads(frame)
                        for channel in op.get("channels", []) if op.get("op") == "advertise" else []:
                            if channel["topic"] in self.topics:
                                subscription += 1
                                self.channels[subscription] = channel
                                ws.send(json.dumps({"op": "subscribe",
                                                    "subscriptions": [{"id": subscription, "channelId": channel["id"]}]}))  # fmt: skip
                    else:
                        sub, log_time, payload = message_data(frame)
                        self.messages.append((self.channels[sub]["topic"], log_time, payload))
        except BaseException as exc:  # reported by the test
            self.error = exc

    def received(self, topic: str) -> list[tuple[int, bytes]]:
        return [(t, p) for name, t, p in list(self.messages) if name == topic]

    def channel(self, topic: str) -> dict | None:
        return next((c for c in list(self.channels.values()) if c["topic"] == topic), None)

    def close(self) -> None:
        self._stop_event.set()
        self.join(timeout=10)


def _listening_addresses(port: int) -> set[str]:
    """Local addresses of the TCP sockets listening on ``port`` (Linux /proc/net/tcp and tcp6)."""
    out = set()
    for path, family in (("/proc/net/tcp", socket.AF_INET), ("/proc/net/tcp6", socket.AF_INET6)):
        try:
            lines = Path(path).read_text().splitlines()[1:]
        except OSError:
            continue
        for line in lines:
            local, state = line.split()[1], line.split()[3]
            address, hex_port = local.split(":")
            if state == "0A" and int(hex_port, 16) == port:  # 0A: LISTEN
                raw = bytes.fromhex(address)
                raw = b"".join(raw[i:i + 4][::-1] for i in range(0, len(raw), 4))  # host-order 32-bit words
                out.add(socket.inet_ntop(family, raw))
    return out


def _serving(output: str) -> tuple[str, int] | None:
    m = _SERVING.search(output)
    return None if m is None else (m.group(1), int(m.group(2)))


def _start_client(ros, processes, proc, topics) -> FoxgloveClient:
    """The bridge's address from its log line; it listens on 127.0.0.1 only; a client subscribed to ``topics``."""
    assert ros.spin_until(lambda: _serving(processes.output(proc)) is not None, timeout_s=120), processes.output(proc)
    host, port = _serving(processes.output(proc))
    assert host == "127.0.0.1" and port > 0  # the default host; port 0 asked for any free port
    assert _listening_addresses(port) == {"127.0.0.1"}  # bound to loopback only, not 0.0.0.0 or another address
    client = FoxgloveClient(f"ws://127.0.0.1:{port}", topics)
    client.start()
    return client


def _assert_same_cloud(payload: bytes, log_time: int, stamp_ns: int, frame_id: str, points: np.ndarray) -> None:
    cloud = decode_point_cloud(payload)
    assert cloud.stamp_ns == log_time == stamp_ns  # header stamp: message time and log time
    assert cloud.frame_id == frame_id == "lidar"
    assert len(cloud.points) == len(points) > 0
    assert {name: cloud.fields[name][1] for name in ("x", "y", "z")} == {"x": 7, "y": 7, "z": 7}  # float32
    assert set(cloud.fields) == set(points.dtype.names)
    for name in points.dtype.names:
        np.testing.assert_array_equal(cloud.points[name], points[name])


def test_up_sim_foxglove_serves_the_cloud_tf_static_and_actor_boxes(processes, cli, ros, tmp_path):
    from rclpy.qos import QoSProfile, ReliabilityPolicy
    from sensor_msgs.msg import PointCloud2
    from tf2_msgs.msg import TFMessage

    from lidar_weather_sim.ros.conversions import msg_to_cloud, stamp_to_ns
    from lidar_weather_sim.ros.qos import TF_QOS
    from lidar_weather_sim.scenario.schema import load_scenario

    up = processes.start(*cli, "up", "sim", "foxglove:=true", "foxglove_port:=0", "--run-dir", str(tmp_path / "run"))
    clouds, actor_frames = {}, set()
    queued = QoSProfile(depth=100, reliability=ReliabilityPolicy.BEST_EFFORT)
    ros.node.create_subscription(PointCloud2, "/lidar/points", lambda m: clouds.setdefault(stamp_to_ns(m.header.stamp), m), queued)
    ros.node.create_subscription(TFMessage, "/tf", lambda m: actor_frames.update(
        t.child_frame_id for t in m.transforms if t.child_frame_id.startswith("actor_")), TF_QOS)  # fmt: skip
    client = _start_client(ros, processes, up, {"/lidar/points", "/tf_static", "/actors"})
    try:
        both = lambda: [(t, p) for t, p in client.received("/lidar/points") if t in clouds]  # noqa: E731
        assert ros.spin_until(lambda: len(both()) >= 3 or client.error, timeout_s=240), (client.error, processes.output(up))
        assert ros.spin_until(lambda: client.received("/actors") and client.received("/tf_static"), timeout_s=60)
    finally:
        client.close()
    assert client.error is None and client.subprotocol in SUBPROTOCOLS
    channel = client.channel("/lidar/points")
    assert (channel["schemaName"], channel["encoding"]) == ("foxglove.PointCloud", "protobuf")
    for log_time, payload in both()[:3]:
        msg = clouds[log_time]
        assert msg.width * msg.height == len(msg_to_cloud(msg).points)  # the sim sends no non-finite point
        _assert_same_cloud(payload, log_time, stamp_to_ns(msg.header.stamp), msg.header.frame_id, msg_to_cloud(msg).points)

    # /tf_static, sent before the client came, is resent when it subscribes: base_link -> lidar at the mount
    statics = [protobuf_fields(t) for _, p in client.received("/tf_static") for t in protobuf_fields(p)[1]]
    assert (b"base_link", b"lidar") in {(t[2][0], t[3][0]) for t in statics}
    # actor boxes: one per actor frame on /tf, in that frame, of the scenario's actor size
    sizes = {f"actor_{a.id}": (a.size.length_m, a.size.width_m, a.size.height_m) for a in load_scenario("highway_clear").actors}
    _, scene = client.received("/actors")[-1]
    entities = [protobuf_fields(e) for e in protobuf_fields(scene)[2]]
    boxed = {e[2][0].decode() for e in entities}
    # the bridge may have sent a box before this node's /tf subscription saw that frame: wait for it
    assert entities and ros.spin_until(lambda: boxed <= actor_frames, timeout_s=30), (boxed, actor_frames)
    assert actor_frames <= set(sizes), actor_frames
    for entity in entities:
        size = protobuf_fields(protobuf_fields(entity[8][0])[2][0])  # SceneEntity.cubes[0].size
        got = tuple(np.frombuffer(b"".join(size[k][0] for k in (1, 2, 3)), "<f8"))
        assert got == sizes[entity[2][0].decode()]
    up.send_signal(signal.SIGINT)
    assert up.wait(timeout=60) == 0, processes.output(up)
    assert "[up] foxglove_bridge_node exited with status 0" in processes.output(up)


@pytest.mark.slow
def test_play_foxglove_serves_the_bags_clouds_and_skips_malformed_ones(processes, cli, ros, tmp_path):
    """The player waits (--wait-for) until the client is subscribed, malformed clouds were refused and the bridge's
    subscription is matched to the player's publisher, then plays."""
    from rclpy.qos import QoSProfile, ReliabilityPolicy
    from sensor_msgs.msg import PointCloud2, PointField

    from lidar_weather_sim.io.bags import read_messages
    from lidar_weather_sim.io.cloud_codec import decode_message
    from lidar_weather_sim.ros.conversions import cloud_to_msg
    from lidar_weather_sim.testing.malformed import malformed_cloud

    bag = tmp_path / "bag"
    run = subprocess.run([*cli, "run", "highway_clear", "--frames", "20", "--out", str(bag)], capture_output=True, text=True)
    assert run.returncode == 0, run.stderr
    stamps = {int(m.msg.header.stamp.sec) * 10**9 + int(m.msg.header.stamp.nanosec): m.msg
              for m in read_messages(str(bag), ["/lidar/points"])}  # fmt: skip
    assert len(stamps) == 20

    # the player starts once the test says go and the bridge's /lidar/points subscription (made when the client
    # subscribed) is matched to its publisher: on a loaded machine the 20 clouds were once all played before it was
    play = processes.start(*cli, "play", str(bag), "--foxglove", "--foxglove-port", "0",
                           "--wait-for", "/foxglove_test/go", "/lidar/points", "--wait-timeout", "600")  # fmt: skip
    client = _start_client(ros, processes, play, {"/lidar/points"})
    try:
        assert ros.spin_until(lambda: client.channel("/lidar/points") is not None or client.error, timeout_s=60)
        good = cloud_to_msg(decode_message(next(iter(stamps.values()))).points, 999 * 10**9, "lidar")[0]
        pub = ros.node.create_publisher(PointCloud2, "/lidar/points", QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE))
        rng = np.random.default_rng(26)
        refused = lambda: "/lidar/points: skipped malformed cloud" in processes.output(play)  # noqa: E731
        for _ in range(600):  # re-sent until one reached the bridge while the client was subscribed
            if refused() or play.poll() is not None:
                break
            kind = str(rng.choice(["truncated", "absurd_size"]))
            pub.publish(malformed_cloud(good, rng, copy.deepcopy, PointField, kind=kind)[1])
            ros.spin_until(refused, timeout_s=0.5)
        assert refused() and play.poll() is None, processes.output(play)  # refused, and the bridge runs on
        ros.node.create_subscription(PointCloud2, "/foxglove_test/go", lambda _: None, 1)  # the player starts
        assert play.wait(timeout=300) == 0, processes.output(play)  # played, then both processes ended cleanly
    finally:
        client.close()
    assert client.error is None, client.error
    served = client.received("/lidar/points")
    assert served and all(t in stamps for t, _ in served), [t for t, _ in served]  # bag clouds only, none malformed
    for log_time, payload in served:
        msg = stamps[log_time]
        _assert_same_cloud(payload, log_time, log_time, msg.header.frame_id, decode_message(msg).points)
    out = processes.output(play)
    assert "[up] bag_player_node exited with status 0" in out and "[up] foxglove_bridge_node exited with status 0" in out
