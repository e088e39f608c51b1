"""``weather_filter_node``: removes weather detections from a PointCloud2 stream.

Subscribes ``/lidar/points`` (remap it), publishes ``/lidar/points/filtered``
and ``/lidar/points/removed`` (same fields as the input, SensorDataQoS) and a
``diagnostic_msgs/DiagnosticArray`` on ``/diagnostics`` per frame (points in/out
per label when the cloud has ``label``, filter time, method, and ``weather`` /
``weather_confidence`` from the shipped per-frame KNN when the cloud has x, echo and EPW, and the count of
clouds skipped so far). A malformed cloud is skipped: logged once per cause, and reported every time on
``/diagnostics`` with level ERROR, its reason and the counts; so is a cloud with a field the filter
cannot use (``weather_filter.points.cloud_check``: an array field, a float or out-of-range channel or echo).
Points no filter can use (non-finite or out-of-reach coordinates, (0, 0, 0) placeholders) are removed
and counted (``points_set_aside``). ``learned`` runs its EPW model on clouds with EPW and echo fields and its
single-return model on clouds without them (most real drivers), the model used named as ``method`` on
``/diagnostics`` (``learned`` / ``learned-single``). A cloud lacking the fields of ``method`` (for ``learned``:
intensity or channel) is
filtered with ``fallback_method`` (geometry only, with
``weather_filter.filter_methods.FALLBACK_PARAMS``), with a warning once.

Parameters: ``method`` (dror|dsor|lior|echo|learned; default learned), ``fallback_method``
(dror|dsor), ``model_path`` (learned filter; empty = packaged model).
"""

from __future__ import annotations

import numpy as np
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from rcl_interfaces.msg import ParameterDescriptor
from rclpy.node import Node
from rclpy.qos import qos_profile_sensor_data
from sensor_msgs.msg import PointCloud2

from lidar_weather_sim.core.names import TOPIC_POINTS, TOPIC_POINTS_FILTERED, TOPIC_POINTS_REMOVED
from lidar_weather_sim.io.cloud_codec import CloudFormatError
from lidar_weather_sim.io.layouts import CloudReader
from lidar_weather_sim.ros.conversions import cloud_to_msg
from lidar_weather_sim.ros.node_main import run_node
from weather_filter.filter_methods import (
    DEFAULT_METHOD,
    GEOMETRY_METHODS,
    METHODS,
    METHOD_HELP,
    make_fallback_filter,
    make_filter,
)
from weather_filter.points.cloud_check import CloudFieldError, usable_points
from weather_filter.points.fallback import fallback_message

DIAGNOSTIC_NAME = "weather_filter_node: filter"


class WeatherFilterNode(Node):
    def __init__(self) -> None:
        super().__init__("weather_filter_node")
        ro = dict(read_only=True)
        described = "; ".join(f"{m}: {METHOD_HELP[m]}" for m in METHODS)
        self.declare_parameter("method", DEFAULT_METHOD, ParameterDescriptor(description=f"filter: {described}", **ro))
        self.declare_parameter(
            "fallback_method", "dror",
            ParameterDescriptor(description=f"geometry-only filter for clouds without the method's fields: {'|'.join(GEOMETRY_METHODS)}", **ro),
        )  # fmt: skip
        self.declare_parameter("model_path", "", ParameterDescriptor(description="learned model file (empty: packaged)", **ro))
        method = self.get_parameter("method").value
        fallback = self.get_parameter("fallback_method").value
        if fallback not in GEOMETRY_METHODS:
            raise ValueError(f"fallback_method must be one of {GEOMETRY_METHODS}, not {fallback!r}")
        extra = {"model_path": self.get_parameter("model_path").value or None} if method == "learned" else {}
        self._filter = make_filter(method, **extra)
        self._fallback = make_fallback_filter(fallback)
        self._logged: set[str] = set()
        self._weather = self._load_weather_classifier()
        self.frames = 0
        self.skipped = 0
        self._pub_filtered = self.create_publisher(PointCloud2, TOPIC_POINTS_FILTERED, qos_profile_sensor_data)
        self._pub_removed = self.create_publisher(PointCloud2, TOPIC_POINTS_REMOVED, qos_profile_sensor_data)
        self._pub_diag = self.create_publisher(DiagnosticArray, "/diagnostics", 10)
        self.create_subscription(PointCloud2, TOPIC_POINTS, self._on_cloud, qos_profile_sensor_data)
        self.get_logger().info(f"filtering {TOPIC_POINTS} with '{method}' (fallback '{fallback}')")
        self._reader = CloudReader(TOPIC_POINTS, self.get_logger().info)  # any driver's layout, said in one line

    def _load_weather_classifier(self):
        """The shipped per-frame KNN (weather_filter.weather_class), or None (logged) if it cannot load."""
        from weather_filter.weather_class import FrameWeatherClassifier

        try:
            return FrameWeatherClassifier.load()
        except (OSError, ImportError, ValueError, KeyError) as exc:
            self.get_logger().warning(f"per-frame weather classification off: {exc}")
            return None

    def _once(self, key: str, text: str, level: str = "warning") -> None:
        # rclpy forbids one call site logging at several severities: one call per level
        if key in self._logged:
            return
        self._logged.add(key)
        logger = self.get_logger()
        if level == "error":
            logger.error(text)
        elif level == "info":
            logger.info(text)
        else:
            logger.warning(text)

    def _skip(self, msg: PointCloud2, key: str, text: str) -> None:
        """A cloud not filtered: logged once per cause, and every time on /diagnostics (level ERROR, the count)."""
        self._once(key, text, "error")
        self.skipped += 1
        status = DiagnosticStatus(level=DiagnosticStatus.ERROR, name=DIAGNOSTIC_NAME, hardware_id=msg.header.frame_id,
                                  message=text, values=[KeyValue(key="clouds_skipped", value=str(self.skipped)),
                                                        KeyValue(key="clouds_filtered", value=str(self.frames))])  # fmt: skip
        self._pub_diag.publish(DiagnosticArray(header=msg.header, status=[status]))

    def _on_cloud(self, msg: PointCloud2) -> None:
        try:
            frame = self._reader.read_message(msg)
        except CloudFormatError as exc:
            self._skip(msg, f"malformed:{exc.cause}", f"skipped malformed cloud: {exc}")
            return
        points = frame.points
        filt = self._filter
        missing = filt.missing_fields(points)
        if missing:
            self._once(f"missing:{missing}", fallback_message(filt.name, missing, self._fallback.name))
            filt = self._fallback
            if filt.missing_fields(points):
                self._skip(msg, "nogeom", "cloud lacks x, y or z: skipped")
                return
        try:
            result = filt(points)
        except CloudFieldError as exc:  # a field no filter can use (names it)
            self._skip(msg, "field:" + str(exc).split(":")[0].split(";")[0], f"skipped cloud: {exc}")
            return
        except Exception as exc:  # never crash on one frame
            self._skip(msg, f"error:{type(exc).__name__}", f"filter '{filt.name}' failed, frame skipped: {exc!r}")
            return
        stamp_ns, frame_id = frame.stamp_ns, msg.header.frame_id
        self._pub_filtered.publish(cloud_to_msg(points[~result.remove], stamp_ns, frame_id)[0])
        self._pub_removed.publish(cloud_to_msg(points[result.remove], stamp_ns, frame_id)[0])
        # the learned method names the model the cloud's fields chose (learned: EPW model, learned-single: without)
        self._pub_diag.publish(self._diagnostics(msg, points, result, getattr(filt, "last_used", filt.name)))
        self.frames += 1

    def _weather_status(self, points: np.ndarray) -> list[KeyValue]:
        if self._weather is None:
            self._once("noweather", "per-frame weather classification unavailable (no trained KNN / "
                       "lidar_weather_sim.core.frame_parameters): not published", "info")  # fmt: skip
            return []
        if not {"x", "echo", "epw"} <= set(points.dtype.names or ()):
            self._once("noweatherfields", "cloud lacks x, echo or epw: no per-frame weather class", "info")
            return []
        try:
            estimate = self._weather.classify(points[usable_points(points, frozenset(("echo",)))[1].keep])
        except Exception as exc:  # the class is an extra: never lose the filtered cloud for it
            self._once(f"weathererror:{type(exc).__name__}", f"no weather class for this cloud: {exc!r}")
            return []
        return [KeyValue(key="weather", value=estimate.weather), KeyValue(key="weather_confidence", value=f"{estimate.confidence:.3f}")]

    def _diagnostics(self, msg: PointCloud2, points: np.ndarray, result, name: str) -> DiagnosticArray:
        values = [
            KeyValue(key="method", value=name),
            KeyValue(key="points_in", value=str(len(points))),
            KeyValue(key="points_out", value=str(int((~result.remove).sum()))),
            KeyValue(key="points_removed", value=str(int(result.remove.sum()))),
            KeyValue(key="time_ms", value=f"{result.elapsed_s * 1e3:.3f}"),
            KeyValue(key="points_set_aside", value=str(result.set_aside)),  # unusable coordinates, (0, 0, 0) placeholders
            KeyValue(key="clouds_skipped", value=str(self.skipped)),  # malformed clouds so far (see _skip)
        ]
        if "label" in points.dtype.names:
            codes, counts = np.unique(points["label"], return_counts=True)
            kept = dict(zip(*np.unique(points["label"][~result.remove], return_counts=True)))
            for code, count in zip(codes.tolist(), counts.tolist()):
                values.append(KeyValue(key=f"label_{code}_in", value=str(count)))
                values.append(KeyValue(key=f"label_{code}_out", value=str(int(kept.get(code, 0)))))
        values += self._weather_status(points)
        status = DiagnosticStatus(level=DiagnosticStatus.OK, name=DIAGNOSTIC_NAME,
                                  hardware_id=msg.header.frame_id, message=f"{name}: removed {int(result.remove.sum())} of {len(points)}", values=values)  # fmt: skip
        return DiagnosticArray(header=msg.header, status=[status])


def main(args: list[str] | None = None) -> None:
    run_node("weather_filter_node", WeatherFilterNode, config_errors=(ValueError, OSError), args=args)


if __name__ == "__main__":
    main()
