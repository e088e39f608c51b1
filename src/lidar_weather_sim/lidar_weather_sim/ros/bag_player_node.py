"""``bag_player_node``: publishes a recorded bag's topics with their original timing, and /clock.

The project's ``ros2 bag play --clock`` (rosbag2_py is not installable everywhere).
Messages go out in log-time order, each at ``(log_time - first log_time) / rate``
wall seconds after the start; with ``publish_clock`` /clock carries the bag's
log time (before each message and at ``clock_hz`` in between) and the bag's own
/clock messages are not replayed (while the node waits for subscribers, /clock
stands at the first log time). /tf_static is published transient-local,
every other topic reliable (depth 100), so best-effort and reliable readers both match.
The /tf_static messages of the bag's first instant go out before the clock starts,
and playback starts once every reader has acknowledged them: no reader gets a /tf
that needs a static frame before that frame.

Parameters: ``bag`` (path), ``topics`` (string array, empty = all), ``rate``
(playback speed factor), ``publish_clock`` (bool), ``clock_hz`` (Hz),
``wait_for_topics`` (string array: start only when each has a subscriber),
``wait_timeout_s`` (s, then start anyway), ``wait_for_ready`` (string array of node names: start
once each has said it is ready on /<node>/ready, :mod:`lidar_weather_sim.ros.readiness`; graphs give
every other node), ``ready_timeout_s`` (s: a node not ready by then ends the run, status 1),
``stay_after_playing`` (bool).
A topic this node plays counts as subscribed once a reader is matched to its
publisher (what was published before would be lost to a volatile reader, or
reach a transient-local one late); any other topic once a subscription shows in
the graph. When the bag is played and every reliable reader has acknowledged it
(at most ``wait_timeout_s`` each), the publishers go: their readers see the
input end. The node then exits, or with ``stay_after_playing`` runs on until
shut down (in a graph that a reader ends when it is done with the bag, e.g.
``lidar_sim_node`` with ``exit_when_input_ends``).
"""

from __future__ import annotations

import itertools
import time

import rclpy
from rcl_interfaces.msg import FloatingPointRange, ParameterDescriptor
from rclpy.duration import Duration
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
from rosgraph_msgs.msg import Clock

from lidar_weather_sim.core.names import TOPIC_CLOCK, TOPIC_TF_STATIC
from lidar_weather_sim.io.bags import BagError, read_messages, typestore
from lidar_weather_sim.ros.conversions import message_class
from lidar_weather_sim.ros.node_main import POLL_S, run_node, stop_requested
from lidar_weather_sim.ros.readiness import ReadyGate

RELIABLE = QoSProfile(depth=100, reliability=ReliabilityPolicy.RELIABLE)
LATCHED = QoSProfile(depth=100, reliability=ReliabilityPolicy.RELIABLE, durability=DurabilityPolicy.TRANSIENT_LOCAL)


def _time(ns: int):
    from builtin_interfaces.msg import Time

    return Time(sec=ns // 1_000_000_000, nanosec=ns % 1_000_000_000)


class BagPlayerNode(Node):
    def __init__(self) -> None:
        super().__init__("bag_player_node")
        d = ParameterDescriptor
        self.bag = self.declare_parameter("bag", "", d(description="rosbag2 directory or .mcap", read_only=True)).value
        topics = self.declare_parameter("topics", [""], d(description="Topics to play (empty: all)", read_only=True)).value
        rate = FloatingPointRange(from_value=0.01, to_value=100.0)
        self.rate = self.declare_parameter("rate", 1.0, d(description="Playback speed factor", floating_point_range=[rate])).value
        self.publish_clock = self.declare_parameter("publish_clock", True, d(description="Publish /clock from log time")).value
        hz = FloatingPointRange(from_value=1.0, to_value=1000.0)
        self.clock_hz = self.declare_parameter("clock_hz", 100.0, d(description="/clock rate between messages (Hz)", floating_point_range=[hz])).value
        wait = self.declare_parameter("wait_for_topics", [""], d(description="Start when each has a subscriber")).value
        self.wait_timeout_s = self.declare_parameter("wait_timeout_s", 30.0, d(description="Start anyway after (s)")).value
        ready = self.declare_parameter("wait_for_ready", [""], d(description="Start once each of these nodes is ready")).value
        ready_timeout = self.declare_parameter("ready_timeout_s", 600.0, d(description="Fail when they are not ready after (s)")).value
        stay = d(description="After playing, run on until shut down")
        self.stay_after_playing = self.declare_parameter("stay_after_playing", False, stay).value
        self.topics = [t for t in topics if t] or None
        self.wait_for = [t for t in wait if t]
        self._ready = ReadyGate(self, [n for n in ready if n], ready_timeout)
        if not self.bag:
            raise BagError("parameter 'bag' is empty: give the bag to play")
        self.messages = [m for m in read_messages(self.bag, self.topics) if not (self.publish_clock and m.topic == TOPIC_CLOCK)]
        self._pubs = {}
        for m in self.messages:
            if m.topic not in self._pubs:
                qos = LATCHED if m.topic == TOPIC_TF_STATIC else RELIABLE
                self._pubs[m.topic] = self.create_publisher(message_class(m.msgtype), m.topic, qos)
        self._clock = self.create_publisher(Clock, TOPIC_CLOCK, RELIABLE) if self.publish_clock else None
        self.published = 0
        self.get_logger().info(f"playing {len(self.messages)} messages on {sorted(self._pubs)} from {self.bag} at x{self.rate:g}")

    def _topic_publishers(self) -> dict:
        """This node's publishers by topic (the played topics and /clock)."""
        return {**self._pubs, **({TOPIC_CLOCK: self._clock} if self._clock is not None else {})}

    def _subscribed(self, topic: str) -> bool:
        own = self._topic_publishers().get(topic)
        return own.get_subscription_count() > 0 if own is not None else self.count_subscribers(topic) > 0

    def wait_for_subscribers(self) -> None:
        """Until each ``wait_for_ready`` node is ready, then until each ``wait_for_topics`` topic has a
        subscriber; meanwhile /clock stands at the bag's start. A node never ready: status 1, one line."""
        while not stop_requested():
            try:
                if self._ready.check():
                    break
            except TimeoutError as exc:
                self.get_logger().error(str(exc))
                raise SystemExit(1) from None
            if self._clock is not None and self.messages:
                self._clock.publish(Clock(clock=_time(self.messages[0].log_time_ns)))
            rclpy.spin_once(self, timeout_sec=0.05)
        deadline = time.monotonic() + self.wait_timeout_s
        while time.monotonic() < deadline and not stop_requested() and not all(self._subscribed(t) for t in self.wait_for):
            if self._clock is not None and self.messages:
                self._clock.publish(Clock(clock=_time(self.messages[0].log_time_ns)))
            rclpy.spin_once(self, timeout_sec=0.05)
        if missing := [t for t in self.wait_for if not self._subscribed(t)]:
            self.get_logger().warning(f"no subscriber on {missing} after {self.wait_timeout_s:g} s: playing anyway")

    def wait_for_acks(self, topics=None) -> None:
        """Until every reader of ``topics`` (default: all) has acknowledged what was published (at most ``wait_timeout_s`` each)."""
        for topic, publisher in self._topic_publishers().items():
            if (topics is None or topic in topics) and not publisher.wait_for_all_acked(Duration(seconds=self.wait_timeout_s)):
                self.get_logger().warning(f"{topic}: not acknowledged by every reader after {self.wait_timeout_s:g} s")

    def play(self) -> None:
        """Publish every message at its original (scaled) time; /clock in between."""
        if not self.messages:
            return
        t0 = self.messages[0].log_time_ns
        first = [m.topic == TOPIC_TF_STATIC and m.log_time_ns == t0 for m in self.messages]  # static frames of t0
        for m in itertools.compress(self.messages, first):
            self._publish(m)
        self.wait_for_acks([TOPIC_TF_STATIC])
        start, clock_step_ns = time.monotonic(), round(1e9 / self.clock_hz)
        next_clock = t0
        for m in itertools.compress(self.messages, [not f for f in first]):
            if stop_requested():
                return
            while True:  # /clock ticks (and spinning) until this message is due
                due = start + (m.log_time_ns - t0) * 1e-9 / self.rate
                tick_due = start + (next_clock - t0) * 1e-9 / self.rate
                if self._clock is not None and next_clock < m.log_time_ns and tick_due <= due:
                    self._sleep_until(tick_due)
                    self._clock.publish(Clock(clock=_time(next_clock)))
                    next_clock += clock_step_ns
                    continue
                self._sleep_until(due)
                break
            if self._clock is not None and next_clock <= m.log_time_ns:
                self._clock.publish(Clock(clock=_time(m.log_time_ns)))
                next_clock = m.log_time_ns + clock_step_ns
            self._publish(m)
        self.get_logger().info(f"played {self.published} messages")

    def _publish(self, m) -> None:
        self._pubs[m.topic].publish(bytes(typestore().serialize_cdr(m.msg, m.msgtype)))
        self.published += 1

    def finish(self) -> None:
        """End the stream: once every reader has all of it, the publishers go (see the module docstring)."""
        self.wait_for_acks()
        for publisher in self._topic_publishers().values():
            self.destroy_publisher(publisher)
        self._pubs, self._clock = {}, None

    def _sleep_until(self, deadline: float) -> None:
        while (left := deadline - time.monotonic()) > 0 and not stop_requested():
            time.sleep(min(left, 0.01))


def _spin(node: BagPlayerNode) -> None:
    node.wait_for_subscribers()
    node.play()
    if stop_requested():
        return
    node.finish()
    while node.stay_after_playing and not stop_requested():
        rclpy.spin_once(node, timeout_sec=POLL_S)


def main(args: list[str] | None = None) -> None:
    run_node("bag_player_node", BagPlayerNode, _spin, config_errors=(BagError, ValueError), args=args)


if __name__ == "__main__":
    main()
