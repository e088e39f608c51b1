"""``recorder_node``: records topics to an MCAP rosbag2 (``lidar_weather_sim.io.bags.BagWriter``).

The project's ``ros2 bag record``. Each topic is subscribed to as raw CDR as
soon as a publisher shows its type (checked every 0.2 s of steady time), so
nothing is deserialised; the log time is the node clock. With ``use_sim_time``
that is /clock, and topics are subscribed to only once /clock has arrived: no
message is logged at a time the node does not know yet.
PointCloud2 topics are read with SensorDataQoS (matches best-effort and
reliable writers) at depth ``queue_depth``, /tf_static transient-local, the rest
reliable. SIGINT/SIGTERM stop the node (rclpy) and the bag is closed with a
valid index (``finish`` of :func:`~lidar_weather_sim.ros.node_main.run_node`,
also at interpreter exit); a SIGKILLed recording is recovered by
``lidar-weather-sim recover``.

Parameters: ``out`` (bag directory), ``topics`` (string array), ``overwrite``
(bool), ``queue_depth`` (int), ``max_messages`` (int, 0 = until shut down: the
node exits after recording that many messages).
"""

from __future__ import annotations

import rclpy
from rcl_interfaces.msg import ParameterDescriptor
from rclpy.clock import Clock, ClockType
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy, qos_profile_sensor_data
from rosgraph_msgs.msg import Clock as ClockMsg

from lidar_weather_sim.core.names import TOPIC_CLOCK, TOPIC_POINTS, TOPIC_TF_STATIC
from lidar_weather_sim.io.bags import POINTCLOUD2, BagError, BagWriter
from lidar_weather_sim.ros.node_main import POLL_S, run_node, stop_requested


class RecorderNode(Node):
    def __init__(self) -> None:
        super().__init__("recorder_node")
        d = lambda text: ParameterDescriptor(description=text, read_only=True)  # noqa: E731
        out = self.declare_parameter("out", "", d("Output rosbag2 directory (MCAP)")).value
        self.wanted = [t for t in self.declare_parameter("topics", [TOPIC_POINTS], d("Topics to record")).value if t]
        overwrite = self.declare_parameter("overwrite", False, d("Replace an existing bag")).value
        self.depth = self.declare_parameter("queue_depth", 100, d("Subscription queue depth")).value
        self.max_messages = self.declare_parameter("max_messages", 0, d("Exit after this many (0 = never)")).value
        if not out:
            raise BagError("parameter 'out' is empty: give the bag directory to write")
        self.writer = BagWriter(out, storage="mcap", overwrite=overwrite, handle_signals=False)  # closed by main()
        self.counts = {t: 0 for t in self.wanted}
        self._subs = {}
        self._clock_sub = None  # with use_sim_time: until the first /clock message
        if self.get_parameter("use_sim_time").value:
            self._clock_sub = self.create_subscription(ClockMsg, TOPIC_CLOCK, self._on_clock, qos_profile_sensor_data)
        self.create_timer(0.2, self._discover, clock=Clock(clock_type=ClockType.STEADY_TIME))
        self._discover()
        self.get_logger().info(f"recording {self.wanted} to {out}" + (" once /clock runs" if self._clock_sub else ""))

    def _on_clock(self, _msg: ClockMsg) -> None:  # the time source's older subscription is served first
        self.destroy_subscription(self._clock_sub)
        self._clock_sub = None
        self._discover()

    def _discover(self) -> None:
        if self._clock_sub is not None:
            return
        types = dict(self.get_topic_names_and_types())
        # clouds last: a sim that waits for a cloud subscriber (wait_for_subscriber) then starts only after
        # /clock and /tf are subscribed too, so their first messages are recorded as well
        for topic in sorted(self.wanted, key=lambda t: POINTCLOUD2 in types.get(t, ())):
            if topic in self._subs or not types.get(topic):
                continue
            msgtype = types[topic][0]
            if msgtype == POINTCLOUD2:
                qos = QoSProfile(depth=self.depth, reliability=qos_profile_sensor_data.reliability)
            elif topic == TOPIC_TF_STATIC:
                qos = QoSProfile(depth=self.depth, reliability=ReliabilityPolicy.RELIABLE, durability=DurabilityPolicy.TRANSIENT_LOCAL)
            else:
                qos = QoSProfile(depth=self.depth, reliability=ReliabilityPolicy.RELIABLE)
            from lidar_weather_sim.ros.conversions import message_class

            callback = lambda data, t=topic, m=msgtype: self._write(t, m, data)  # noqa: E731
            self._subs[topic] = self.create_subscription(message_class(msgtype), topic, callback, qos, raw=True)
            self.get_logger().info(f"subscribed to {topic} [{msgtype}]")

    def _write(self, topic: str, msgtype: str, data: bytes) -> None:
        self.writer.write_serialized(topic, msgtype, data, self.get_clock().now().nanoseconds)
        self.counts[topic] += 1

    @property
    def finished(self) -> bool:
        return 0 < self.max_messages <= sum(self.counts.values())


def _spin(node: RecorderNode) -> None:
    while not stop_requested() and not node.finished:
        rclpy.spin_once(node, timeout_sec=POLL_S)


def _finish(node: RecorderNode) -> None:
    node.writer.close()
    print(f"recorder_node: recorded {node.counts}", flush=True)


def main(args: list[str] | None = None) -> None:
    run_node("recorder_node", RecorderNode, _spin, config_errors=(BagError, ValueError), finish=_finish, args=args)


if __name__ == "__main__":
    main()
