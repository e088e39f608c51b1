"""``spray_node``: steps a spray particle system with simulated time and publishes the particles.

The vehicles come from a scenario (``scenario`` parameter, a name in config/scenarios
or a path; its ``spray`` region parameters are used), and so do their poses, unless
``actors_from_tf``. Scenario poses: every ``1 / rate_hz`` s of node time the system
advances to the scenario time and publishes, in frame ``frame_id``. Scenario time is
the /clock time with ``use_sim_time`` (the clock lidar_sim_node publishes in scenario
mode starts at the scenario's t = 0, so both nodes see the vehicles at the same places),
else the wall-clock time since start.

With ``actors_from_tf`` each vehicle's wheels follow its /tf frame ``actor_<id>``
(``frame_id`` -> actor_<id>, the body-to-fixed pose, as lidar_sim_node's scenario mode
publishes them, or another simulator or a bag): the first /tf stamp is the system's
t = 0, and a /tf message at least ``1 / rate_hz`` of stamp time after the last
published step advances the system to its stamp and publishes, stamped with it. A
vehicle whose frame is not known yet throws nothing; a stamp more than 1 s older than
the last one (a looped bag) starts the particles afresh.

- ``/spray/particles`` sensor_msgs/PointCloud2 (fields in spray_particles.sensing.particle_cloud: centre,
  semi-axes, population, drop cross-section, emitting actor id), which the ``spray`` region of
  ``lidar_sim_node`` reads with ``source: topic``;
- ``/spray/markers`` visualization_msgs/MarkerArray, one SPHERE_LIST per population.

Parameters: ``scenario`` (string), ``rate_hz`` (double), ``frame_id`` (string, the fixed
frame), ``actors_from_tf`` (bool), ``max_steps`` (int, 0 = forever). :func:`marker_array`
and :func:`spray_particles.sensing.particle_cloud.particle_cloud` need no running node.
"""

from __future__ import annotations

import numpy as np

from spray_particles.sensing.particle_cloud import TOPIC_PARTICLES

TOPIC_MARKERS = "/spray/markers"
#: Simulated seconds a throwaway copy of the region is stepped at start-up, before the node publishes:
#: the first steps then run at full speed (else loading the kernels delays them by ~1 s).
WARM_UP_S = 0.2


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


def _build_region(world, pose_source=None):
    """The scenario's ``spray`` region; its vehicles follow ``pose_source`` (default: the scenario player)."""
    from lidar_weather_sim.regions.base import REGISTRY, RegionContext

    params = world.scenario.region_params.get("spray", {})
    context = RegionContext(world.profile, world.scenario.weather, world.scene.materials,
                            actors=world.scenario.actors, pose_source=pose_source or world.player)  # fmt: skip
    return REGISTRY.create("spray", params, context)


def tf_actor_source(world, fixed_frame: str):
    """A pose source whose actors are the scenario's vehicles looked up on their /tf frames actor_<id>
    (fixed_frame -> actor_<id>) in a fresh buffer; time origin unset (-1) until the first stamp."""
    from lidar_weather_sim.core.names import actor_frame
    from lidar_weather_sim.poses.sources import TfPoseSource
    from lidar_weather_sim.poses.tf_buffer import TransformBuffer

    frames = {a.id: actor_frame(a.id) for a in world.scenario.actors}
    buffer = TransformBuffer(cache_time_s=10.0, extrapolation_tolerance_s=0.0)
    return TfPoseSource(buffer, fixed_frame, fixed_frame, None, -1, frames)


def main(argv=None) -> None:
    from rclpy.node import Node
    from sensor_msgs.msg import PointCloud2
    from visualization_msgs.msg import MarkerArray

    from lidar_weather_sim.core.names import TOPIC_TF, TOPIC_TF_STATIC
    from lidar_weather_sim.io.cloud_codec import build_message
    from lidar_weather_sim.poses.sources import add_tf_message
    from lidar_weather_sim.ros.conversions import rclpy_message_types
    from lidar_weather_sim.ros.node_main import run_node, spin_until_stopped
    from lidar_weather_sim.ros.qos import TF_QOS, TF_STATIC_QOS
    from lidar_weather_sim.scenario.schema import load_scenario
    from lidar_weather_sim.scenario.world import World

    class SprayNode(Node):
        def __init__(self) -> None:
            super().__init__("spray_node")
            self.declare_parameter("scenario", "highway_spray")
            self.declare_parameter("rate_hz", 25.0)
            self.declare_parameter("frame_id", "map")
            self.declare_parameter("actors_from_tf", False)
            self.declare_parameter("max_steps", 0)
            self.world = World.build(load_scenario(self.get_parameter("scenario").value))
            self.frame_id = self.get_parameter("frame_id").value
            self.max_steps = int(self.get_parameter("max_steps").value)
            self.period_ns = round(1e9 / float(self.get_parameter("rate_hz").value))
            self.steps = 0
            self.logged: set[str] = set()
            from_tf = self.get_parameter("actors_from_tf").value
            self.source = tf_actor_source(self.world, self.frame_id) if from_tf else None
            self.region = _build_region(self.world, self.source)
            _build_region(self.world).step(0.0, WARM_UP_S)  # a throwaway copy: kernels compiled (or loaded) now
            # publishers once the region is built: a subscriber that waits for them finds the node ready
            self.cloud_pub = self.create_publisher(PointCloud2, TOPIC_PARTICLES, 10)
            self.marker_pub = self.create_publisher(MarkerArray, TOPIC_MARKERS, 10)
            if from_tf:
                from tf2_msgs.msg import TFMessage

                self.last_ns = None  # stamp of the last published step
                self.statics = {}  # newest /tf_static transform per child frame
                self.create_subscription(TFMessage, TOPIC_TF, self.on_tf, TF_QOS)
                self.create_subscription(TFMessage, TOPIC_TF_STATIC, self.on_tf_static, TF_STATIC_QOS)
            else:
                sim_time = self.get_parameter("use_sim_time").value
                self.start_ns = 0 if sim_time else self.get_clock().now().nanoseconds
                self.region.step(0.0, 0.0)
                self.create_timer(self.period_ns * 1e-9, self.tick)

        def tick(self) -> None:
            now = self.get_clock().now().nanoseconds
            self.publish((now - self.start_ns) * 1e-9, now)

        def on_tf(self, msg) -> None:
            stamps, problems = add_tf_message(self.source.buffer, msg)
            for problem in problems:
                self.warn_once(problem.cause, f"/tf: {problem.detail} (skipped)")
            if not stamps:
                return
            newest = max(stamps)
            if self.last_ns is not None and newest < self.last_ns - 1_000_000_000:
                self.get_logger().warning(f"/tf time jumped back {(self.last_ns - newest) * 1e-9:.3f} s: new particles")
                self.source = tf_actor_source(self.world, self.frame_id)
                add_tf_message(self.source.buffer, type(msg)(transforms=list(self.statics.values())), static=True)
                self.region, self.last_ns = _build_region(self.world, self.source), None
            if self.source.time_origin_ns < 0:
                self.source.time_origin_ns = newest  # the particle system's t = 0
            if self.last_ns is None or newest >= self.last_ns + self.period_ns:
                self.last_ns = newest
                self.publish(self.source.to_time_s(newest), newest)

        def on_tf_static(self, msg) -> None:
            self.statics.update({ts.child_frame_id: ts for ts in msg.transforms})  # kept for a restart
            for problem in add_tf_message(self.source.buffer, msg, static=True)[1]:
                self.warn_once(problem.cause, f"/tf_static: {problem.detail} (skipped)")

        def publish(self, t: float, stamp_ns: int) -> None:
            """Advance the particles to simulated time ``t`` (s) and publish them stamped ``stamp_ns``."""
            self.region.step(t, t)
            cloud = self.region.particle_cloud(t)
            msg, _ = build_message(cloud, stamp_ns=stamp_ns, frame_id=self.frame_id, types=rclpy_message_types())
            self.cloud_pub.publish(msg)
            self.marker_pub.publish(marker_array(cloud, msg.header.stamp, self.frame_id))
            self.steps += 1
            if self.max_steps and self.steps >= self.max_steps:
                raise SystemExit(0)

        def warn_once(self, key: str, text: str) -> None:
            if key not in self.logged:
                self.logged.add(key)
                self.get_logger().warning(text)

    def spin(node: SprayNode) -> None:
        try:
            spin_until_stopped(node)
        except SystemExit:  # max_steps reached
            pass

    run_node("spray_node", SprayNode, spin, args=argv)


if __name__ == "__main__":
    main()
