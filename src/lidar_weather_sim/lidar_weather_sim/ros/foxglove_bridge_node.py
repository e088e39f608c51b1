"""``foxglove_bridge_node``: the live view in Foxglove (app or web) without rviz2, over Foxglove's WebSocket protocol.

Serves, on a ``foxglove-sdk`` WebSocket server (``ws://HOST:PORT``; foxglove-sdk 0.30.3 negotiates the
subprotocol ``foxglove.sdk.v1``, the successor of ``foxglove.websocket.v1`` with the same framing):

- each topic of ``cloud_topics`` (sensor_msgs/PointCloud2, SensorDataQoS) as a ``foxglove.PointCloud``
  channel of the same name (advertised from the start; a topic nobody publishes stays empty): every
  field of the cloud, x, y, z in m in the cloud's frame (``lidar``);
- /tf and /tf_static as ``foxglove.FrameTransforms`` channels of the same names (m, unit quaternions);
- ``/actors``: a ``foxglove.SceneUpdate`` with a box per actor frame ``actor_<id>`` seen on /tf (box sizes
  from ``scenario``'s actors, a mid-size car otherwise), locked to that frame, renewed every
  ``actor_period_s`` of /tf time and expiring after three periods (an actor that leaves disappears).

Times are the header stamps (ROS time: simulated under ``use_sim_time`` or from a bag), both in each
message and as its log time. Clouds are converted only while a client subscribes to their channel.
A client that subscribes late gets /tf_static and the actor boxes resent (within 0.2 s).
A malformed cloud or transform is skipped and logged once per cause; the node keeps running.

Parameters: ``host`` (address to bind; default 127.0.0.1, this machine only: ``0.0.0.0`` serves every
network, with no authentication), ``port`` (TCP port; 0 = any free one, logged), ``cloud_topics``
(string array), ``scenario`` (name or YAML path for the actor sizes; '' = default sizes),
``actor_period_s`` (s).
"""

from __future__ import annotations

import threading

import foxglove
from foxglove.channels import FrameTransformsChannel, PointCloudChannel, SceneUpdateChannel
from foxglove.websocket import ServerListener
from rcl_interfaces.msg import FloatingPointRange, IntegerRange, ParameterDescriptor
from rclpy.clock import Clock, ClockType
from rclpy.node import Node
from rclpy.qos import qos_profile_sensor_data
from sensor_msgs.msg import PointCloud2
from tf2_msgs.msg import TFMessage

from lidar_weather_sim.core.config import ConfigError
from lidar_weather_sim.core.names import TOPIC_POINTS, TOPIC_POINTS_FILTERED, TOPIC_TF, TOPIC_TF_STATIC
from lidar_weather_sim.io.cloud_codec import CloudFormatError
from lidar_weather_sim.io.foxglove_messages import actor_ids, actor_scene, frame_transforms, point_cloud
from lidar_weather_sim.ros.conversions import msg_to_cloud, stamp_to_ns
from lidar_weather_sim.ros.node_main import run_node
from lidar_weather_sim.ros.qos import TF_QOS, TF_STATIC_QOS

DEFAULT_HOST = "127.0.0.1"
DEFAULT_PORT = 8765
TOPIC_ACTORS = "/actors"
ACTOR_LIFETIME_PERIODS = 3.0


class _Resubscribed(ServerListener):
    """Notes the topics clients subscribe to (called on the server's thread; the other callbacks do nothing)."""

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self._topics: set[str] = set()

    def on_subscribe(self, client, channel) -> None:
        with self._lock:
            self._topics.add(channel.topic)

    def take(self) -> set[str]:
        with self._lock:
            topics, self._topics = self._topics, set()
        return topics


class FoxgloveBridgeNode(Node):
    def __init__(self) -> None:
        super().__init__("foxglove_bridge_node")
        ro = lambda text, **kw: ParameterDescriptor(description=text, read_only=True, **kw)  # noqa: E731
        host = self.declare_parameter("host", DEFAULT_HOST, ro("Address to bind (127.0.0.1: this machine only)")).value
        ports = IntegerRange(from_value=0, to_value=65535, step=1)
        port = self.declare_parameter("port", DEFAULT_PORT, ro("TCP port (0: any free port)", integer_range=[ports])).value
        topics = self.declare_parameter("cloud_topics", [TOPIC_POINTS, TOPIC_POINTS_FILTERED],
                                        ro("PointCloud2 topics to serve")).value  # fmt: skip
        scenario = self.declare_parameter("scenario", "", ro("Scenario for actor box sizes ('' = default sizes)")).value
        period = FloatingPointRange(from_value=0.05, to_value=60.0)
        self.actor_period_ns = round(1e9 * self.declare_parameter(
            "actor_period_s", 1.0, ro("Actor boxes renewed every (s of /tf time)", floating_point_range=[period])).value)  # fmt: skip
        self.sizes = _actor_sizes(scenario) if scenario else {}
        self._logged: set[str] = set()
        self._fox = foxglove.Context()
        self._listener = _Resubscribed()
        try:
            self.server = foxglove.start_server(name="lidar_weather_sim", host=host, port=port, context=self._fox,
                                                server_listener=self._listener)  # fmt: skip
        except RuntimeError as exc:  # FoxgloveError: port in use, unknown host
            raise ConfigError(f"cannot serve on {host}:{port}: {exc}") from exc
        self.url = f"ws://{host}:{self.server.port}"
        self._tf = {TOPIC_TF: FrameTransformsChannel(TOPIC_TF, context=self._fox),
                    TOPIC_TF_STATIC: FrameTransformsChannel(TOPIC_TF_STATIC, context=self._fox)}  # fmt: skip
        self._actors = SceneUpdateChannel(TOPIC_ACTORS, context=self._fox)
        self._statics: dict[str, object] = {}  # child frame -> its latest /tf_static TransformStamped
        self._static_ns = 0
        self._seen: list[int] = []  # actor ids on /tf since the last scene update
        self._last_scene: tuple[int, list[int]] | None = None  # (stamp in ns, ids)
        self.forwarded = {t: 0 for t in topics if t}
        self._clouds = {t: PointCloudChannel(t, context=self._fox) for t in self.forwarded}
        for topic in self.forwarded:
            self.create_subscription(PointCloud2, topic, lambda m, t=topic: self._on_cloud(t, m), qos_profile_sensor_data)
        self.create_subscription(TFMessage, TOPIC_TF, self._on_tf, TF_QOS)
        self.create_subscription(TFMessage, TOPIC_TF_STATIC, self._on_tf_static, TF_STATIC_QOS)
        self.create_timer(0.2, self._resend, clock=Clock(clock_type=ClockType.STEADY_TIME))
        self.get_logger().info(f"serving {self.url} (Foxglove WebSocket): clouds {sorted(self.forwarded)}, "
                               f"{TOPIC_TF}, {TOPIC_TF_STATIC}, actor boxes on {TOPIC_ACTORS}")  # fmt: skip

    # -- input ------------------------------------------------------------------------------------
    def _once(self, key: str, text: str) -> None:
        if key not in self._logged:
            self._logged.add(key)
            self.get_logger().warning(f"{text} (logged once per cause)")

    def _on_cloud(self, topic: str, msg: PointCloud2) -> None:
        channel = self._clouds[topic]
        if not channel.has_sinks():
            return  # nobody watches: no conversion
        try:
            points = msg_to_cloud(msg).points
            stamp_ns = stamp_to_ns(msg.header.stamp)
            message = point_cloud(points, stamp_ns, msg.header.frame_id)
        except CloudFormatError as exc:
            self._once(f"{topic}:malformed:{exc.cause}", f"{topic}: skipped malformed cloud: {exc}")
            return
        except (ValueError, OverflowError) as exc:
            self._once(f"{topic}:{type(exc).__name__}:{str(exc).split(':')[0]}", f"{topic}: skipped cloud: {exc}")
            return
        channel.log(message, log_time=stamp_ns)
        if not self.forwarded[topic]:
            self.get_logger().info(f"{topic}: first cloud served ({len(points)} points, frame '{msg.header.frame_id}')")
        self.forwarded[topic] += 1

    def _transforms(self, topic: str, msg: TFMessage):
        try:
            message, stamp_ns, rejected = frame_transforms(msg)
        except (AttributeError, TypeError, ValueError, OverflowError) as exc:
            self._once(f"{topic}:{type(exc).__name__}", f"{topic}: skipped message: {exc}")
            return None, 0
        for reason in rejected:
            self._once(f"{topic}:{reason}", f"{topic}: skipped transform {reason}")
        return message, stamp_ns

    def _on_tf(self, msg: TFMessage) -> None:
        message, stamp_ns = self._transforms(TOPIC_TF, msg)
        if message is None:
            return
        self._tf[TOPIC_TF].log(message, log_time=stamp_ns)
        self._seen += [i for i in actor_ids(msg) if i not in self._seen]
        last = self._last_scene
        new_ids = last is not None and not set(self._seen) <= set(last[1])
        if self._seen and (last is None or new_ids or not 0 <= stamp_ns - last[0] < self.actor_period_ns):
            self._publish_actors(stamp_ns, self._seen)
            self._seen = []

    def _on_tf_static(self, msg: TFMessage) -> None:
        for ts in msg.transforms:  # kept for clients that subscribe later (transient local, as tf2_ros)
            self._statics[ts.child_frame_id] = ts
        message, stamp_ns = self._transforms(TOPIC_TF_STATIC, msg)
        if message is not None:
            self._static_ns = stamp_ns
            self._tf[TOPIC_TF_STATIC].log(message, log_time=stamp_ns)

    # -- output -----------------------------------------------------------------------------------
    def _publish_actors(self, stamp_ns: int, ids: list[int]) -> None:
        lifetime_s = ACTOR_LIFETIME_PERIODS * self.actor_period_ns * 1e-9
        self._actors.log(actor_scene(ids, stamp_ns, self.sizes, lifetime_s), log_time=stamp_ns)
        self._last_scene = (stamp_ns, list(ids))

    def _resend(self) -> None:
        """What a client that just subscribed has missed: every static transform, the current actor boxes."""
        topics = self._listener.take()
        if TOPIC_TF_STATIC in topics and self._statics:
            message, _ = self._transforms(TOPIC_TF_STATIC, TFMessage(transforms=list(self._statics.values())))
            if message is not None:
                self._tf[TOPIC_TF_STATIC].log(message, log_time=self._static_ns)
        if TOPIC_ACTORS in topics and self._last_scene is not None:
            self._publish_actors(*self._last_scene)

    def close(self) -> None:
        self.server.stop()


def _actor_sizes(scenario: str) -> dict[int, tuple[float, float, float]]:
    """Actor id -> (length, width, height) in m of a scenario's actors."""
    from lidar_weather_sim.scenario.schema import load_scenario

    return {a.id: (a.size.length_m, a.size.width_m, a.size.height_m) for a in load_scenario(scenario).actors}


def main(args: list[str] | None = None) -> None:
    run_node("foxglove_bridge_node", FoxgloveBridgeNode, config_errors=(ConfigError, ValueError, OSError),
             finish=FoxgloveBridgeNode.close, args=args)  # fmt: skip


if __name__ == "__main__":
    main()
