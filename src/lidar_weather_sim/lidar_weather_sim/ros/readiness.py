"""Readiness: a node says it is ready on a latched ``/<node>/ready``; a clock waits for a list of them.

Every node of the project is started by :func:`lidar_weather_sim.ros.node_main.run_node`, which
publishes ``std_msgs/Bool`` ``true`` on ``/<node name>/ready`` (reliable, transient local, depth 1:
a late subscriber still gets it) once the node's constructor has returned. A constructor does its
warm-up (model load, numba compilation on a dummy cloud, caster build) before it creates its
subscriptions, so "ready" means: the next message it receives is handled at full speed.

:class:`ReadyGate` is the other side: the node that drives time (lidar_sim_node in scenario mode,
bag_player_node) holds its clock until every named node has said it is ready. Graphs fill the list
with ``$(graph nodes)`` (:mod:`lidar_weather_sim.ros.graph`): every other node of the graph.
"""

from __future__ import annotations

import time

from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
from std_msgs.msg import Bool

READY_QOS = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE, durability=DurabilityPolicy.TRANSIENT_LOCAL)
LOG_EVERY_S = 5.0  # wall seconds between "still waiting for ..." lines


def ready_topic(node_name: str) -> str:
    """``/<node>/ready`` of a node name given with or without its leading slash."""
    return f"/{node_name.strip('/')}/ready"


def announce_ready(node: Node):
    """Publish ``true`` on the node's latched ready topic; returns the publisher (keep it alive)."""
    publisher = node.create_publisher(Bool, ready_topic(node.get_fully_qualified_name()), READY_QOS)
    publisher.publish(Bool(data=True))
    return publisher


class ReadyGate:
    """Open once every node in ``names`` has announced it is ready (a node's own name is ignored).

    ``timeout_s`` (wall clock): :meth:`check` raises ``TimeoutError`` naming the silent nodes when
    they have not all answered by then; 0 waits for ever.
    """

    def __init__(self, node: Node, names: list[str], timeout_s: float = 0.0) -> None:
        own = node.get_fully_qualified_name().strip("/")
        self._node = node
        self.pending = sorted({n.strip("/") for n in names} - {own})
        self._subscriptions = [node.create_subscription(Bool, ready_topic(n), self._on_ready(n), READY_QOS)
                               for n in self.pending]  # fmt: skip
        self._since = time.monotonic()
        self._logged_at = self._since
        self._timeout_s = timeout_s

    def _on_ready(self, name: str):
        def callback(msg: Bool) -> None:
            if msg.data and name in self.pending:
                self.pending.remove(name)
                self._node.get_logger().info(f"{name} is ready"
                                             + (f"; waiting for {', '.join(self.pending)}" if self.pending else ""))
        return callback

    @property
    def open(self) -> bool:
        return not self.pending

    def check(self) -> bool:
        """True when open; logs the nodes still awaited every few seconds; raises once ``timeout_s`` is over."""
        if not self.pending:
            return True
        now = time.monotonic()
        if self._timeout_s > 0 and now - self._since > self._timeout_s:
            raise TimeoutError(f"not ready after {self._timeout_s:g} s: {', '.join(self.pending)} "
                               f"(no true on {', '.join(map(ready_topic, self.pending))})")
        if now - self._logged_at >= LOG_EVERY_S:
            self._logged_at = now
            self._node.get_logger().info(f"waiting for {', '.join(self.pending)} to be ready "
                                         f"({now - self._since:.0f} s)")
        return False
