"""``ego_controller_node``: minimal adaptive cruise on a (filtered) LiDAR cloud -> /ego/cmd_speed.

Subscribes ``cloud_topic`` (default /lidar/points/filtered, SensorDataQoS); per
cloud it finds the nearest obstacle in its lane and publishes the commanded
speed on /ego/cmd_speed (geometry_msgs/TwistStamped: ``twist.linear.x`` in m/s
along base_link's x, ``header.stamp`` = the cloud's stamp, ``header.frame_id``
base_link), which lidar_sim_node's scenario player applies from the start of the
next frame. A cloud it has answered already (the simulator's synchronous mode sends
an unanswered cloud again) gets the same command again. Logic and parameters: :mod:`lidar_weather_sim.control.acc`
(every AccConfig field is a parameter). Time is the cloud's header stamp (sim
time). ``trace_csv``: if set, one line per cloud for the closed-loop report: stamp_s,
detected_m (nearest in-lane cluster), distance_m (the confirmed obstacle the
controller acts on), label (the most common ground-truth label in that
cluster), cmd_speed_m_s, decel_m_s2, points.
"""

from __future__ import annotations

import numpy as np
from geometry_msgs.msg import TwistStamped
from rcl_interfaces.msg import ParameterDescriptor
from rclpy.node import Node
from rclpy.qos import qos_profile_sensor_data
from sensor_msgs.msg import PointCloud2

from lidar_weather_sim.control.acc import AccConfig, AccState, ObstacleTrack, clusters, step
from lidar_weather_sim.core.config import ConfigError, validate
from lidar_weather_sim.core.names import FRAME_BASE_LINK, TOPIC_CMD_SPEED, TOPIC_POINTS_FILTERED
from lidar_weather_sim.io.cloud_codec import CloudFormatError
from lidar_weather_sim.io.layouts import CloudReader
from lidar_weather_sim.ros.conversions import stamp_to_ns
from lidar_weather_sim.ros.node_main import run_node


class EgoControllerNode(Node):
    def __init__(self) -> None:
        super().__init__("ego_controller_node")
        values = {}
        for name, field in AccConfig.model_fields.items():
            d = ParameterDescriptor(description=field.description or name, read_only=True)
            values[name] = self.declare_parameter(name, field.default, d).value
        self.cfg = validate(values, AccConfig, "ego_controller_node parameters")
        topic = self.declare_parameter("cloud_topic", TOPIC_POINTS_FILTERED, ParameterDescriptor(read_only=True)).value
        trace = self.declare_parameter("trace_csv", "", ParameterDescriptor(description="per-cloud trace file")).value
        self.state, self.track = AccState(self.cfg.cruise_speed_m_s), ObstacleTrack(self.cfg)
        self._trace = open(trace, "w", buffering=1) if trace else None  # noqa: SIM115 (closed in close())
        if self._trace:
            self._trace.write("stamp_s,detected_m,distance_m,label,cmd_speed_m_s,decel_m_s2,points\n")
        self._pub = self.create_publisher(TwistStamped, TOPIC_CMD_SPEED, 10)
        self._last: TwistStamped | None = None  # the newest command, sent again for a repeated cloud
        self.create_subscription(PointCloud2, topic, self._on_cloud, qos_profile_sensor_data)
        self.commands = 0
        self._logged: set[str] = set()
        self._reader = CloudReader(topic, self.get_logger().info)  # any driver's layout, said in one line
        self.get_logger().info(f"adaptive cruise on {topic} -> {TOPIC_CMD_SPEED}, set speed {self.cfg.cruise_speed_m_s} m/s")

    def _on_cloud(self, msg: PointCloud2) -> None:
        try:
            points = self._reader.read_message(msg).points
            found = clusters(points, self.cfg)
        except (CloudFormatError, KeyError, ValueError) as exc:
            key = type(exc).__name__
            if key not in self._logged:
                self._logged.add(key)
                self.get_logger().warning(f"skipped cloud: {exc} (logged once per cause)")
            return
        t = stamp_to_ns(msg.header.stamp) * 1e-9
        if self.state.time_s is not None and t <= self.state.time_s:
            if self._last is not None and self._last.header.stamp == msg.header.stamp:
                self._pub.publish(self._last)  # a repeated cloud: its answer again
            return  # old or repeated cloud
        distances = [float(points["x"][c[0]]) for c in found]
        has_label = "label" in points.dtype.names
        labels = [int(np.bincount(points["label"][c]).argmax()) for c in found] if has_label else None
        track = self.track.update(distances, labels)
        detected = distances[0] if distances else None
        distance = track.distance_m if track is not None else None
        speed, decel = step(self.state, t, distance, self.cfg)
        command = TwistStamped()
        command.header.stamp, command.header.frame_id = msg.header.stamp, FRAME_BASE_LINK
        command.twist.linear.x = float(speed)
        self._pub.publish(command)
        self._last = command
        self.commands += 1
        if self._trace:
            text = lambda d: "" if d is None else f"{d:.3f}"  # noqa: E731
            label = track.tag if track is not None and track.tag is not None else ""
            self._trace.write(f"{t:.6f},{text(detected)},{text(distance)},{label},{speed:.6f},{decel:.6f},{len(points)}\n")

    def close(self) -> None:
        """Close the trace file (run_node's ``finish``, before the node is destroyed)."""
        if self._trace:
            self._trace.close()


def main(args: list[str] | None = None) -> None:
    run_node("ego_controller_node", EgoControllerNode, config_errors=(ConfigError,), finish=EgoControllerNode.close,
             args=args)


if __name__ == "__main__":
    main()
