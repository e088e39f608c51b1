"""``lidar_sim_node``: the virtual LiDAR on ROS 2 (parameters, topics, QoS, conversion only).

Pose input (``pose_source``): ``scenario`` (built-in player; the node drives
simulated time and publishes /clock, and with ``publish_tf`` /tf and
/tf_static), ``tf`` (/tf + /tf_static, fixed_frame -> sensor_frame) or
``odometry`` (nav_msgs/Odometry of base_frame in fixed_frame, plus the mount
base_frame -> sensor_frame from /tf_static or ``mount_xyz_m``/``mount_rpy_deg``).
With ``wait_for_subscriber`` the tf/odometry input is subscribed to only once
/lidar/points has a subscriber (bag replay: no frame is cast before its recorder
listens, and the player, waiting for this node's subscriptions, starts after),
and in scenario mode simulated time starts only then (a recorder keeps frame 0);
with ``exit_when_input_ends`` the node exits once every publisher of that input
has left and all it sent is cast (the end of a bag replay). In scenario mode the
node stops (status 0, with a warning) when the ego reaches the end of its road, as
``lidar-weather-sim run`` does: beyond it the ego would leave the map.
The map and the actors come from ``scenario``; with ``actors_from_tf`` (tf/odometry
mode) the actors' bodies and spray emitters follow their /tf frames actor_<id>
(fixed_frame -> actor_<id>, as scenario mode publishes them). Each pose update casts
the columns swept since the last one; a frame is published on /lidar/points
(SensorDataQoS, sensor frame, stamp = scan start) when its sweep completes.
In tf/odometry mode time is taken from the message stamps (bag replay,
use_sim_time). ``regions``, ``region_params``, ``sun_irradiance_w_m2`` and
``seed`` may be set at run time: validated on set, used from the next frame to
start; the log gives the time of the request and the stamp of that frame.
Regions may read points other nodes publish (the ``spray`` region with
``source: topic`` reads spray_node's /spray/particles): the node subscribes to
every topic a region asks for (lidar_weather_sim.regions.topic_inputs) and keeps the
newest message in fixed_frame; a malformed one is logged and skipped.

Why one module of ~410 lines: one node, its parameters and its three pose modes; the simulation
itself is in sim.session, the conversions in ros.conversions.
"""

from __future__ import annotations

import math
import time

from builtin_interfaces.msg import Time
from geometry_msgs.msg import TransformStamped, TwistStamped
from nav_msgs.msg import Odometry
from rcl_interfaces.msg import FloatingPointRange, IntegerRange, ParameterDescriptor, SetParametersResult
from rclpy.clock import Clock, ClockType
from rclpy.executors import ShutdownException, SingleThreadedExecutor, TimeoutException
from rclpy.node import Node
from rclpy.qos import qos_profile_sensor_data
from rosgraph_msgs.msg import Clock as ClockMsg
from sensor_msgs.msg import PointCloud2
from tf2_msgs.msg import TFMessage

from lidar_weather_sim.core.config import ConfigError
from lidar_weather_sim.core.geometry import FrameTransform
from lidar_weather_sim.core.names import (
    FRAME_BASE_LINK,
    FRAME_LIDAR,
    FRAME_MAP,
    RETURN_MODES,
    TOPIC_CLOCK,
    TOPIC_CMD_SPEED,
    TOPIC_POINTS,
    TOPIC_TF,
    TOPIC_TF_STATIC,
    actor_frame,
)
from lidar_weather_sim.poses.gate import PoseGate
from lidar_weather_sim.poses.sources import (
    TfPoseSource,
    add_tf_message,
    mount_transform,
    parse_odometry,
    set_static_mount,
)
from lidar_weather_sim.poses.tf_buffer import TransformBuffer, TransformError
from lidar_weather_sim.regions.topic_inputs import TopicInputs
from lidar_weather_sim.ros.conversions import cloud_to_msg, msg_to_cloud, stamp_to_ns
from lidar_weather_sim.ros.node_main import POLL_S, run_node, stop_requested
from lidar_weather_sim.ros.qos import CLOCK_QOS, TF_QOS, TF_STATIC_QOS
from lidar_weather_sim.ros.readiness import ReadyGate
from lidar_weather_sim.ros.sync import FrameSync
from lidar_weather_sim.scenario.player import moving_transforms, static_transforms
from lidar_weather_sim.scenario.schema import load_scenario
from lidar_weather_sim.scenario.world import World
from lidar_weather_sim.sim.session import RuntimeSettings, SimSession, parse_region_params
from lidar_weather_sim.sim.simulator import scenario_settings

POSE_SOURCES = ("scenario", "tf", "odometry")
RUNTIME = ("regions", "region_params", "sun_irradiance_w_m2", "seed")
LINGER_S = 1.0  # after max_frames: the writer stays this long (s) before the process ends
SILENT_INPUT_FRAMES = 25  # warn once when a topic a region reads has sent nothing after this many clouds
BACKWARDS_RESTART_S = 1.0  # a stamp this much older than the last one (bag loop, sim reset) restarts the scan


def _time(ns: int) -> Time:
    return Time(sec=ns // 1_000_000_000, nanosec=ns % 1_000_000_000)


def _tf_message(ns: int, transforms: list[FrameTransform]) -> TFMessage:
    """The transforms as one TFMessage, each stamped ``ns``."""
    msgs = []
    for parent, child, translation, quaternion in transforms:
        msg = TransformStamped()
        msg.header.stamp, msg.header.frame_id, msg.child_frame_id = _time(ns), parent, child
        tr, rot = msg.transform.translation, msg.transform.rotation
        tr.x, tr.y, tr.z = translation
        rot.x, rot.y, rot.z, rot.w = quaternion
        msgs.append(msg)
    return TFMessage(transforms=msgs)


class LidarSimNode(Node):
    def __init__(self, **kwargs) -> None:
        super().__init__("lidar_sim_node", **kwargs)
        p = self._p
        p("scenario", "highway_clear", "Scenario (name or YAML path): map, actors, weather, regions")
        p("profile", "", "Sensor profile name or YAML path ('' = the scenario's)")
        p("return_mode", "", f"What each beam reports of its echoes: {', '.join(RETURN_MODES)} ('' = the scenario's, "
          "else the profile's detection.return_mode)")
        mode = p("pose_source", "scenario", "Pose input: scenario (built-in player, drives /clock), tf or odometry")
        if mode not in POSE_SOURCES:
            raise ConfigError(f"pose_source '{mode}' is not one of {', '.join(POSE_SOURCES)}")
        self.world = World.build(load_scenario(p("scenario")), p("profile") or None, p("return_mode") or None)
        scenario, mount = self.world.scenario, self.world.scenario.sensor.mount
        self.fixed = p("fixed_frame", FRAME_MAP, "Fixed (world) frame of the scene")
        self.base = p("base_frame", FRAME_BASE_LINK, "Vehicle frame (odometry child; scenario mode /tf)")
        self.frame = p("sensor_frame", FRAME_LIDAR, "Sensor frame: header.frame_id of the clouds")
        odom_topic = p("odometry_topic", "/odom", "nav_msgs/Odometry input (pose_source odometry)")
        xyz = p("mount_xyz_m", [mount.x_m, mount.y_m, mount.z_m], "Odometry: sensor in base (m) if not on /tf_static")
        rpy = [mount.roll_deg, mount.pitch_deg, mount.yaw_deg]
        rpy = p("mount_rpy_deg", rpy, "Odometry: mount roll, pitch, yaw (deg) if not on /tf_static")
        ground_truth = p("ground_truth", True, "Publish the label and object_id fields")
        backend = p("backend", "", "Ray casting backend: mitsuba, open3d or embree ('' = fastest available)")
        dt = p("time_step_s", 0.01, "Scenario mode: simulated seconds per tick", (1e-4, 1.0))
        rtf = p("realtime_factor", 1.0, "Scenario mode: sim / wall-clock speed (0 = flat out)", (0.0, 1e3))
        publish_tf = p("publish_tf", True, "Scenario mode: publish map->base_link, actor_<id>, base_link->lidar")
        regions = p("regions", list(scenario.regions), "Region plugins in order (default: the scenario's)", None, False)
        p("region_params", "", "YAML mapping plugin -> parameters, over the scenario's region_params", None, False)
        settings = scenario_settings(scenario)
        p("sun_irradiance_w_m2", settings["sun_irradiance_w_m2"], "Sun irradiance (W/m^2; default: the scenario's weather)",
          (0.0, 1400.0), False)  # fmt: skip
        p("seed", settings["seed"], "Random seed: same seed and poses, same clouds", (0, 2**31 - 1), False)
        self.max_frames = p("max_frames", 0, "Stop after publishing this many clouds (0 = run until shut down)", (0, 2**31 - 1))
        wait = p("wait_for_subscriber", False, "Start the poses (scenario: the clock) once /lidar/points has a subscriber")
        ready = p("wait_for_ready", [], "Node names: start the poses (scenario: the clock) once each has said it is "
                  "ready on /<node>/ready (graphs: every other node)", None)
        ready_timeout = p("ready_timeout_s", 600.0, "Fail when wait_for_ready is not met after this long (s, wall clock; "
                          "0 = wait for ever)", (0.0, 1e5))
        synchronous = p("synchronous", False, "Scenario mode: after each cloud, advance only once every sync_topics "
                        "topic has answered with that cloud's stamp (CARLA's synchronous mode)")
        sync_topics = p("sync_topics", [TOPIC_CMD_SPEED], "Synchronous mode: the topics (with a std_msgs/Header) whose "
                        "answer to each cloud the clock waits for", None)
        sync_timeout = p("sync_timeout_s", 10.0, "Synchronous mode: stop the run when a sync topic stays silent this "
                         "long (s, wall clock)", (0.1, 1e5))
        self.exit_when_input_ends = p("exit_when_input_ends", False, "tf/odometry: exit once the pose publishers have left")
        gap = p("odometry_max_gap_s", 1.0, "Odometry: skip a stamp this far (s) from the last, unless the next confirms it",
                (1e-3, 3600.0))
        speed = p("odometry_max_speed_m_s", 100.0, "Odometry: skip a pose reached faster than this (m/s)", (0.1, 1e4))
        self._gate = PoseGate(gap, speed)
        self.inputs = 0  # pose messages (/tf or odometry) received
        self.published = 0
        self.road_end_s: float | None = None  # scenario mode: when the ego reached the end of its road (s)
        from_tf = p("actors_from_tf", False, "tf/odometry: actors (bodies and spray emitters) follow their /tf frames "
                    "actor_<id> in fixed_frame instead of the scenario; absent while their frame is unknown")
        if mode != "scenario":
            self._statics: dict[str, TransformStamped] = {}  # newest /tf_static edge per child, for restarts
            self._mount = mount_transform(xyz, rpy) if mode == "odometry" else None
            frames = {a.id: actor_frame(a.id) for a in scenario.actors} if from_tf else None
            self.source = TfPoseSource(self._new_buffer(), self.fixed, self.frame, self.world.player.actor_poses, -1,
                                       frames)  # fmt: skip
        self.topic_inputs = TopicInputs(self.fixed)  # points regions read from other nodes (spray source: topic)
        self._topic_subscriptions: dict[str, object] = {}
        self._subscribed_at: dict[str, int] = {}  # topic -> clouds published when it was subscribed
        region_poses = self.source if from_tf and mode != "scenario" else None  # spray emitters on /tf frames
        self.session = SimSession(self.world, self._settings_with({}), backend=backend, ground_truth=ground_truth,
                                  inputs=self.topic_inputs, pose_source=region_poses)  # fmt: skip
        self._subscribe_topic_inputs()
        self._in_use = self.session.settings  # the settings the last published frames were cast with
        self.add_on_set_parameters_callback(self._validate)
        self.add_post_set_parameters_callback(self._apply)
        self._logged: set[str] = set()
        self._points = self.create_publisher(PointCloud2, TOPIC_POINTS, qos_profile_sensor_data)
        self.mode = mode
        self._hold_for_subscriber = wait
        self.error: str | None = None  # why the run stopped early (a silent consumer, a node never ready)
        for name, value in (("wait_for_ready", ready), ("sync_topics", sync_topics)):
            if not isinstance(value, (list, tuple)) or not all(isinstance(v, str) for v in value):
                raise ConfigError(f"{name} must be a string array, got {value!r}")
        self._ready = ReadyGate(self, list(ready), ready_timeout)
        if synchronous and mode != "scenario":
            raise ConfigError(f"synchronous needs pose_source scenario (the node's own clock), not {mode}")
        self._sync = FrameSync(self, list(sync_topics), sync_timeout) if synchronous else None
        steady = Clock(clock_type=ClockType.STEADY_TIME)  # not sim time: runs without /clock
        if mode == "scenario":
            self._tick, self._dt, self._t = 0, dt, 0.0
            self._clock_pub = self.create_publisher(ClockMsg, TOPIC_CLOCK, CLOCK_QOS)
            self._tf = self.create_publisher(TFMessage, TOPIC_TF, TF_QOS) if publish_tf else None
            if publish_tf:
                self._static = self.create_publisher(TFMessage, TOPIC_TF_STATIC, TF_STATIC_QOS)
                self._static.publish(_tf_message(0, static_transforms(self.world.player, self.base, self.frame)))
            self.create_subscription(TwistStamped, TOPIC_CMD_SPEED, self._on_speed, 10)
            self._commanded_s = 0.0  # simulated time of the newest speed command in effect
            self._hold = wait  # until /lidar/points has a subscriber
            self.create_timer(dt / rtf if rtf > 0 else 0.0, self._on_tick, clock=steady)
        else:
            gated = wait or self._ready.pending
            self._wait = self.create_timer(0.05, lambda: self._subscribe_input(odom_topic), clock=steady) if gated else None
            self._subscribe_input(odom_topic)
        self.get_logger().info(
            f"scenario '{scenario.name}', profile '{self.world.profile.name}' "
            f"(return mode {self.world.profile.detection.return_mode}), pose source {mode}, "
            f"regions {list(regions)}, backend {self.session.sim.caster.backend}"
            + (f"; regions read {', '.join(self.topic_inputs.topics)}" if self.topic_inputs.topics else "")
            + (f"; starts once {TOPIC_POINTS} has a subscriber" if wait else "")
            + (f"; starts once these are ready: {', '.join(self._ready.pending)}" if self._ready.pending else "")
            + (f"; synchronous on {', '.join(sync_topics)}" if synchronous else "")
        )

    def _subscribe_input(self, odom_topic: str) -> None:
        """Subscribe to /tf_static and /tf or odometry (with the wait_for_subscriber gate: once it opens)."""
        if self._wait is not None:
            if (self._hold_for_subscriber and self._points.get_subscription_count() == 0) or not self._gate_open():
                return
            self.destroy_timer(self._wait)
            self._wait = None
        self.create_subscription(TFMessage, TOPIC_TF_STATIC, self._on_tf_static, TF_STATIC_QOS)
        if self.mode == "tf":
            self._input = self.create_subscription(TFMessage, TOPIC_TF, self._on_tf, TF_QOS)
        else:
            self._input = self.create_subscription(Odometry, odom_topic, self._on_odometry, 50)

    @property
    def input_ended(self) -> bool:
        """With ``exit_when_input_ends``: poses have come and every publisher of them has left."""
        return self.exit_when_input_ends and self.inputs > 0 and self._input.get_publisher_count() == 0

    # -- parameters --------------------------------------------------------------------
    def _p(self, name, default=None, description="", value_range=None, read_only=True):
        """Declare (when given a description) and return a parameter's value."""
        if description:
            d = ParameterDescriptor(description=description, read_only=read_only)
            if isinstance(value_range, tuple) and isinstance(default, int) and not isinstance(default, bool):
                d.integer_range = [IntegerRange(from_value=value_range[0], to_value=value_range[1], step=1)]
            elif value_range is not None:
                d.floating_point_range = [FloatingPointRange(from_value=value_range[0], to_value=value_range[1])]
            # string arrays: dynamic typing so that `ros2 param set ... regions "[]"` (a bool array) clears them
            d.dynamic_typing = isinstance(default, list) and all(isinstance(v, str) for v in default)
            self.declare_parameter(name, default, d)
        return self.get_parameter(name).value

    def _settings_with(self, changes: dict) -> RuntimeSettings:
        v = {name: changes.get(name, self.get_parameter(name).value) for name in RUNTIME}
        if not isinstance(v["regions"], (list, tuple)) or not all(isinstance(r, str) for r in v["regions"]):
            raise ConfigError(f"regions must be a string array, got {v['regions']!r}")
        return RuntimeSettings(tuple(v["regions"]), parse_region_params(v["region_params"]),
                               float(v["sun_irradiance_w_m2"]), int(v["seed"]))  # fmt: skip

    def _validate(self, params) -> SetParametersResult:
        changes = {q.name: q.value for q in params if q.name in RUNTIME}
        if changes:
            try:
                settings = self._settings_with(changes)
                self._accepted = (settings, self.session.build_regions(settings))  # requested as built in _apply
                self._subscribe_topic_inputs()
            except (ConfigError, ValueError, TypeError) as exc:
                return SetParametersResult(successful=False, reason=str(exc))
        return SetParametersResult(successful=True)

    def _apply(self, params) -> None:
        changes = {q.name: q.value for q in params if q.name in RUNTIME}
        if changes:
            self.session.request(*self._accepted)
            listed = ", ".join(f"{k}={v}" for k, v in changes.items())
            last = self.session.last_time_s
            when = "before the first frame" if last is None else f"at {self._stamp_text(last)} s"
            self.get_logger().info(f"{listed}: requested {when}, used from the next frame to start")

    # -- inputs --------------------------------------------------------------------------
    def _once(self, cause: str, detail: str, note: str = "skipped") -> None:
        if cause not in self._logged:
            self._logged.add(cause)
            self.get_logger().warning(f"{detail} ({note}; logged once per cause)")

    def _subscribe_topic_inputs(self) -> None:
        """Subscribe to the PointCloud2 topics the regions want (TopicInputs), once each; unsubscribe
        from those no region in use (or requested) wants any more."""
        wanted = self.topic_inputs.topics
        for topic in wanted:
            if topic not in self._topic_subscriptions:
                self._topic_subscriptions[topic] = self.create_subscription(
                    PointCloud2, topic, lambda msg, topic=topic: self._on_topic_input(topic, msg), 10)  # fmt: skip
                self._subscribed_at[topic] = self.published
        for topic in [t for t in self._topic_subscriptions if t not in wanted]:
            self.destroy_subscription(self._topic_subscriptions.pop(topic))
            self._subscribed_at.pop(topic, None)
            self.get_logger().info(f"{topic}: no region reads it any more, unsubscribed")

    def _on_topic_input(self, topic: str, msg: PointCloud2) -> None:
        try:
            cloud = msg_to_cloud(msg)
            self.topic_inputs.put(topic, cloud.points, stamp_to_ns(msg.header.stamp) * 1e-9, msg.header.frame_id)
        except ValueError as exc:  # a malformed cloud (CloudFormatError), missing fields or another frame
            self._once(f"{topic}: {type(exc).__name__}", f"{topic}: {exc}", "skipped, the previous points kept")

    def _on_tf(self, msg: TFMessage) -> None:
        self.inputs += 1
        stamps, problems = add_tf_message(self.source.buffer, msg)
        for problem in problems:
            self._once(*problem)
        if stamps:
            self._step(stamps)

    def _on_tf_static(self, msg: TFMessage) -> None:
        self._statics.update({ts.child_frame_id: ts for ts in msg.transforms})
        for problem in add_tf_message(self.source.buffer, msg, static=True)[1]:
            self._once(*problem)

    def _new_buffer(self) -> TransformBuffer:
        """Zero extrapolation tolerance: a pose is ready when it can be interpolated."""
        buffer = TransformBuffer(cache_time_s=10.0, extrapolation_tolerance_s=0.0)
        if self._mount is not None:  # odometry: the parameter mount, replaced by a /tf_static one
            set_static_mount(buffer, self.base, self.frame, self._mount)
        add_tf_message(buffer, TFMessage(transforms=list(self._statics.values())), static=True)
        return buffer

    def _on_odometry(self, msg: Odometry) -> None:
        self.inputs += 1
        try:
            stamp, pose = parse_odometry(msg, self.fixed, self.base)
            refused = self._gate.check(stamp, pose.translation)
            if refused:
                raise ValueError(f"implausible pose: {refused}, at {stamp * 1e-9:.9f} s")
            if self._gate.jumped and self.session.last_time_s is not None:
                self._restart("odometry jumped")
            self.source.buffer.set_transform(self.fixed, self.base, stamp, pose.translation, pose.rotation)
        except ValueError as exc:
            return self._once(f"odometry: {str(exc).split(':')[0]}", f"odometry: {exc}")
        self._step([stamp])

    def _on_speed(self, msg: TwistStamped) -> None:
        """A speed command answering the cloud stamped ``msg.header.stamp``: in effect from the start of the
        next frame (stamp + scan period), or from now if that has passed (free-running, a late answer);
        a zero stamp: from now."""
        speed = msg.twist.linear.x
        try:
            if not math.isfinite(speed):
                raise ValueError(f"speed {speed} is not finite")
            if self.world.player.ego is None:
                raise ValueError("the scenario has no ego (mesh-only, driven by its trajectory): speed commands "
                                 "are ignored")  # fmt: skip
            stamp_ns = stamp_to_ns(msg.header.stamp)
            wanted = stamp_ns * 1e-9 + self.world.profile.period_s if stamp_ns else self._t
            if wanted < self._t - 1e-9 and self._sync is None:
                self._once("late command", f"{TOPIC_CMD_SPEED}: the command for the cloud stamped "
                           f"{stamp_ns * 1e-9:.3f} s came after {wanted:.3f} s, applied at {self._t:.3f} s (the run "
                           "is free-running: synchronous:=true makes it deterministic)", "applied late")  # fmt: skip
            self._commanded_s = max(wanted, self._t, self._commanded_s)
            self.world.player.ego.command_speed(self._commanded_s, speed)
        except ValueError as exc:
            self._once(f"{TOPIC_CMD_SPEED}: {str(exc).split(' ')[0]}", f"{TOPIC_CMD_SPEED}: {exc}")

    # -- time ----------------------------------------------------------------------------
    def _gate_open(self) -> bool:
        """The wait_for_ready nodes are all ready (a node never ready stops the run: :attr:`error`)."""
        try:
            return self._ready.check()
        except TimeoutError as exc:
            self.error = str(exc)
            return False

    def _on_tick(self) -> None:
        if self.error:
            return
        if self._hold:
            if self._points.get_subscription_count() == 0:
                return
            self._hold = False
        if not self._gate_open():
            return
        if self._sync is not None:
            try:
                if not self._sync.answered(self._points):
                    return
            except TimeoutError as exc:
                self.error = str(exc)
                return
        self._tick += 1
        self._t = t = self._tick * self._dt
        ego = self.world.player.ego  # None: a mesh-only scenario driven by its trajectory (no road to leave)
        if ego is not None and ego.at_road_end(t):  # as `run`: the ego would leave the map, the clouds go empty
            self.road_end_s = t
            self.get_logger().warning(f"the ego reached the end of road {self.world.scenario.ego.road!r} at {t:.2f} s "
                                      f"(it would leave the map): stopping after {self.published} clouds")  # fmt: skip
            return
        ns = round(t * 1e9)
        self._clock_pub.publish(ClockMsg(clock=_time(ns)))
        if self._tf is not None:
            self._tf.publish(_tf_message(ns, moving_transforms(self.world.player, t, self.fixed, self.base)))
        self._publish(self.session.advance(t, self.world.player))

    def _step(self, candidates: list[int]) -> None:
        source = self.source
        stamp = source.ready_stamp_ns(candidates)
        if stamp is None:
            return self._once(*source.why_not_ready(max(candidates)), note="waiting for the sensor pose")
        if source.time_origin_ns < 0:
            source.time_origin_ns = stamp  # simulated time 0 (scenario time of the actors)
        t, last = source.to_time_s(stamp), self.session.last_time_s
        if last is not None and t <= last:
            if t > last - BACKWARDS_RESTART_S:
                return None  # old or repeated stamp
            return self._restart(f"time jumped back {last - t:.3f} s")
        try:
            self._publish(self.session.advance(t, source))
        except (TransformError, ValueError) as exc:
            self._once(f"cast: {type(exc).__name__}", f"cannot cast up to {stamp * 1e-9:.9f} s: {exc}")

    def _restart(self, why: str) -> None:
        self.get_logger().warning(f"{why}: restarting the scan")
        self.session.restart()
        self.source.buffer, self.source.time_origin_ns = self._new_buffer(), -1

    @property
    def finished(self) -> bool:
        """max_frames clouds published, (scenario mode) the ego reached the end of its road, or :attr:`error`."""
        return 0 < self.max_frames <= self.published or self.road_end_s is not None or self.error is not None

    def _stamp_ns(self, time_s: float) -> int:
        """Simulated seconds -> ROS stamp (scenario mode: simulated time is ROS time)."""
        return (0 if self.mode == "scenario" else self.source.time_origin_ns) + round(time_s * 1e9)

    def _stamp_text(self, time_s: float) -> str:
        ns = self._stamp_ns(time_s)
        return f"{ns // 1_000_000_000}.{ns % 1_000_000_000:09d}"

    def _publish(self, frames) -> None:
        """Publish the frames of one advance (and log a requested settings change it swapped in)."""
        session = self.session
        if session.settings is not self._in_use:
            self._in_use, since = session.settings, session.settings_from_s
            first = "the first frame" if since is None else f"the frame stamped {self._stamp_text(since)} s"
            self.get_logger().info(f"in use from {first}: {session.settings}")
            self._subscribe_topic_inputs()  # the replaced regions' topics go
        for frame in frames:
            if self.finished:
                return
            msg, _ = cloud_to_msg(frame.points, self._stamp_ns(frame.stamp_s), self.frame)
            self._points.publish(msg)
            self.published += 1
            if self._sync is not None:
                self._sync.sent(msg)
        for topic in self.topic_inputs.topics:
            waited = self.published - self._subscribed_at.get(topic, self.published)  # clouds since it was wanted
            if waited >= SILENT_INPUT_FRAMES and self.topic_inputs.latest(topic) is None:
                self._once(f"{topic}: silent", f"{topic}: nothing received in the {waited} clouds since it was "
                           "subscribed (is its publisher running?)", "its region adds nothing until then")  # fmt: skip


def _spin_once(executor: SingleThreadedExecutor, timeout_sec: float) -> bool:
    """Run one ready callback; False if none became ready within ``timeout_sec``."""
    try:
        handler, _, _ = executor.wait_for_ready_callbacks(timeout_sec=timeout_sec)
    except (TimeoutException, ShutdownException):
        return False
    handler()
    handler.result()  # raises the callback's exception
    return True


def _spin(node: LidarSimNode) -> None:
    executor = SingleThreadedExecutor()
    executor.add_node(node)
    while not stop_requested() and not node.finished:
        ended = node.input_ended  # then all the input sent is queued here
        if not _spin_once(executor, POLL_S) and ended:
            break  # ... and cast
    if node.error:
        node.get_logger().error(node.error)
        raise SystemExit(1)
    if node.finished:  # max_frames or road end: the last clouds are best effort; give them time to reach the readers
        linger_until = time.monotonic() + LINGER_S
        while not stop_requested() and time.monotonic() < linger_until:
            time.sleep(POLL_S)


def main(args: list[str] | None = None) -> None:
    run_node("lidar_sim_node", LidarSimNode, _spin, config_errors=(ConfigError,), args=args,
             finish=lambda node: print(f"lidar_sim_node: published {node.published} clouds", flush=True))


if __name__ == "__main__":
    main()
