"""``spray_node``: steps a spray particle system with simulated time and publishes the particles.

The vehicles and their poses come from a scenario (``scenario`` parameter, a name in
config/scenarios or a path; its ``spray`` region parameters are used). Every
``1 / rate_hz`` s of node time the system advances to the scenario time and publishes,
in frame ``map``. Scenario time is the /clock time with ``use_sim_time`` (the clock
lidar_sim_node publishes in scenario mode starts at the scenario's t = 0, so both
nodes see the vehicles at the same places), else the wall-clock time since start:

- ``/spray/particles`` sensor_msgs/PointCloud2 (fields in spray_particles.particle_cloud: centre,
  semi-axes, population, drop cross-section, emitting actor id), which the ``spray`` region of
  ``lidar_sim_node`` reads with ``source: topic``;
- ``/spray/markers`` visualization_msgs/MarkerArray, one SPHERE_LIST per population.

Parameters: ``scenario`` (string), ``rate_hz`` (double), ``frame_id`` (string),
``max_steps`` (int, 0 = forever). :func:`marker_array` and
:func:`spray_particles.particle_cloud.particle_cloud` need no running node.
"""

from __future__ import annotations

import numpy as np

from spray_particles.particle_cloud import TOPIC_PARTICLES

TOPIC_MARKERS = "/spray/markers"


def marker_array(cloud: np.ndarray, stamp, frame_id: str):
    """visualization_msgs/MarkerArray: one SPHERE_LIST marker per population (blue inertial, cyan drop
    packets), its sphere size the population's median diameter."""
    from geometry_msgs.msg import Point
    from std_msgs.msg import ColorRGBA
    from visualization_msgs.msg import Marker, MarkerArray

    markers = MarkerArray()
    for pop, rgba in ((0, (0.1, 0.3, 1.0, 0.9)), (1, (0.3, 0.9, 1.0, 0.6))):
        sel = cloud[cloud["population"] == pop]
        m = Marker()
        m.header.stamp, m.header.frame_id = stamp, frame_id
        m.ns, m.id, m.type = "spray", pop, Marker.SPHERE_LIST
        m.action = Marker.ADD if len(sel) else Marker.DELETE
        m.pose.orientation.w = 1.0
        d = float(2.0 * np.median(sel["radius"])) if len(sel) else 0.018
        m.scale.x = m.scale.y = m.scale.z = d
        m.color = ColorRGBA(r=rgba[0], g=rgba[1], b=rgba[2], a=rgba[3])
        m.points = [Point(x=float(p["x"]), y=float(p["y"]), z=float(p["z"])) for p in sel]
        markers.markers.append(m)
    return markers


def _build_region(scenario_name: str):
    from lidar_weather_sim.regions import REGISTRY
    from lidar_weather_sim.scenario import load_scenario
    from lidar_weather_sim.world import World

    world = World.build(load_scenario(scenario_name))
    params = world.scenario.region_params.get("spray", {})
    from lidar_weather_sim.regions import RegionContext

    context = RegionContext(world.profile, world.scenario.weather, world.scene.materials,
                            actors=world.scenario.actors, pose_source=world.player)  # fmt: skip
    return REGISTRY.create("spray", params, context)


def main(argv=None) -> None:
    from rclpy.node import Node
    from sensor_msgs.msg import PointCloud2
    from visualization_msgs.msg import MarkerArray

    from lidar_weather_sim.ros.conversions import rclpy_message_types
    from lidar_weather_sim.ros.node_main import run_node, spin_until_stopped
    from lidar_weather_sim.cloud_codec import build_message

    class SprayNode(Node):
        def __init__(self) -> None:
            super().__init__("spray_node")
            self.declare_parameter("scenario", "highway_spray")
            self.declare_parameter("rate_hz", 25.0)
            self.declare_parameter("frame_id", "map")
            self.declare_parameter("max_steps", 0)
            self.region = _build_region(self.get_parameter("scenario").value)
            self.frame_id = self.get_parameter("frame_id").value
            self.max_steps = int(self.get_parameter("max_steps").value)
            self.cloud_pub = self.create_publisher(PointCloud2, TOPIC_PARTICLES, 10)
            self.marker_pub = self.create_publisher(MarkerArray, TOPIC_MARKERS, 10)
            sim_time = self.get_parameter("use_sim_time").value
            self.start_ns = 0 if sim_time else self.get_clock().now().nanoseconds
            self.steps = 0
            self.region.step(0.0, 0.0)
            self.timer = self.create_timer(1.0 / float(self.get_parameter("rate_hz").value), self.tick)

        def tick(self) -> None:
            now = self.get_clock().now()
            t = (now.nanoseconds - self.start_ns) * 1e-9
            self.region.step(t, t)
            cloud = self.region.particle_cloud(t)
            msg, _ = build_message(cloud, stamp_ns=now.nanoseconds, frame_id=self.frame_id,
                                   types=rclpy_message_types())  # fmt: skip
            self.cloud_pub.publish(msg)
            self.marker_pub.publish(marker_array(cloud, now.to_msg(), self.frame_id))
            self.steps += 1
            if self.max_steps and self.steps >= self.max_steps:
                raise SystemExit(0)

    def spin(node: SprayNode) -> None:
        try:
            spin_until_stopped(node)
        except SystemExit:  # max_steps reached
            pass

    run_node("spray_node", SprayNode, spin, finish=SprayNode.destroy_node, args=argv)


if __name__ == "__main__":
    main()
