"""Synchronous mode of the simulator's clock: frame k+1 is simulated only once the consumers answered frame k.

As CARLA's synchronous mode is used in closed loops: after lidar_sim_node publishes a cloud stamped S,
its clock stands still until every topic in ``sync_topics`` has delivered a message whose
``header.stamp`` is at least S (the weather filter's cloud, the controller's command...). The result
then no longer depends on how fast the machine is: same seed, same scenario, same trace.

Each topic is subscribed once it shows in the graph, with its type read from the graph and its
publishers' reliability (best effort if any publisher is). Before the first cloud the clock waits
until every topic has a publisher. A cloud not answered within :data:`RESEND_S` wall seconds is sent
again (a reader matched just after the first send would never have seen it); a topic silent for
``timeout_s`` wall seconds ends the run with one line naming it.
"""

from __future__ import annotations

import time

from rclpy.node import Node
from rclpy.qos import QoSProfile, ReliabilityPolicy

from lidar_weather_sim.ros.conversions import message_class, stamp_to_ns

RESEND_S = 1.0  # wall seconds without an answer before a cloud is sent again


class FrameSync:
    """The answers awaited after each cloud. Call :meth:`sent` with every cloud published and
    :meth:`answered` before advancing the clock."""

    def __init__(self, node: Node, topics: list[str], timeout_s: float) -> None:
        if not topics:
            raise ValueError("synchronous mode needs at least one topic in sync_topics")
        self._node = node
        self.topics = list(dict.fromkeys(topics))
        self.timeout_s = timeout_s
        self._latest_ns = {t: -1 for t in self.topics}  # newest answer stamp per topic
        self._subscriptions: dict[str, object] = {}
        self._awaited_ns: int | None = None  # stamp of the cloud awaiting its answers (None: none sent yet)
        self._cloud = None
        self._since = self._sent_at = None  # wall clock of the first call of answered(), then of the last send
        self.resent = 0

    def _subscribe(self) -> None:
        """Subscribe to every sync topic that shows in the graph and is not subscribed yet."""
        if len(self._subscriptions) == len(self.topics):
            return
        types = dict(self._node.get_topic_names_and_types())
        for topic in self.topics:
            if topic in self._subscriptions or topic not in types:
                continue
            cls = message_class(types[topic][0])
            if not hasattr(cls, "header"):
                raise TimeoutError(f"synchronous mode: {topic} carries {types[topic][0]}, which has no header "
                                   "stamp to answer a cloud with")  # fmt: skip
            best_effort = any(info.qos_profile.reliability == ReliabilityPolicy.BEST_EFFORT
                              for info in self._node.get_publishers_info_by_topic(topic))  # fmt: skip
            qos = QoSProfile(depth=10, reliability=ReliabilityPolicy.BEST_EFFORT if best_effort
                             else ReliabilityPolicy.RELIABLE)  # fmt: skip
            self._subscriptions[topic] = self._node.create_subscription(cls, topic, self._on_answer(topic), qos)

    def _on_answer(self, topic: str):
        def callback(msg) -> None:
            self._latest_ns[topic] = max(self._latest_ns[topic], stamp_to_ns(msg.header.stamp))
        return callback

    def sent(self, cloud) -> None:
        """A cloud was published: the clock now waits for its answers."""
        self._awaited_ns = stamp_to_ns(cloud.header.stamp)
        self._cloud = cloud
        self._since = self._sent_at = time.monotonic()

    def answered(self, publisher) -> bool:
        """True when the clock may advance; sends the awaited cloud again on ``publisher`` when it has been
        unanswered for :data:`RESEND_S`; raises ``TimeoutError`` (one line, naming the silent topics)."""
        self._subscribe()
        now = time.monotonic()
        if self._since is None:  # the clock is allowed to run from now: the timeout starts
            self._since = self._sent_at = now
        if self._awaited_ns is None:  # before the first cloud: every topic subscribed and published
            silent = [t for t in self.topics if t not in self._subscriptions
                      or self._subscriptions[t].get_publisher_count() == 0]  # fmt: skip
            if silent and now - self._since > self.timeout_s:
                raise TimeoutError(f"synchronous mode: no publisher on {', '.join(silent)} after "
                                   f"{self.timeout_s:g} s (wall clock); is the consumer running?")  # fmt: skip
            return not silent
        silent = [t for t in self.topics if self._latest_ns[t] < self._awaited_ns]
        if not silent:
            return True
        if now - self._since > self.timeout_s:
            raise TimeoutError(f"synchronous mode: {', '.join(silent)} did not answer the cloud stamped "
                               f"{self._awaited_ns * 1e-9:.3f} s within {self.timeout_s:g} s (wall clock); stopping")
        if now - self._sent_at >= RESEND_S:
            publisher.publish(self._cloud)
            self._sent_at = now
            self.resent += 1
        return False
