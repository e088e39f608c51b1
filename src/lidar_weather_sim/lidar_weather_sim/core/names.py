"""Topic and frame names shared by every node, CLI and test (REP-105 frames), and the return modes."""

TOPIC_POINTS = "/lidar/points"
TOPIC_POINTS_FILTERED = "/lidar/points/filtered"
TOPIC_POINTS_REMOVED = "/lidar/points/removed"
TOPIC_TF = "/tf"
TOPIC_TF_STATIC = "/tf_static"
TOPIC_CLOCK = "/clock"
TOPIC_CMD_SPEED = "/ego/cmd_speed"  # geometry_msgs/TwistStamped: twist.linear.x (m/s), stamp = the cloud it answers

FRAME_MAP = "map"
FRAME_BASE_LINK = "base_link"
FRAME_LIDAR = "lidar"

#: Return modes: what each beam reports of the echoes it detected (up to ``detection.max_echoes``), as real
#: drivers offer them: ``strongest`` (highest peak), ``last`` (farthest), ``first`` (nearest), ``dual`` (last and
#: strongest, Velodyne's dual return) or ``all`` (every echo, the thesis' multi-echo output). A profile's
#: ``detection.return_mode``, a scenario's ``sensor.return_mode``, ``lidar-weather-sim run --return-mode`` and the
#: node's ``return_mode`` parameter take these names; :func:`lidar_weather_sim.sensor.echo.select_returns` applies them.
RETURN_MODES = ("strongest", "last", "dual", "first", "all")


def actor_frame(actor_id: int) -> str:
    """The tf frame of a scenario actor's body (published in scenario mode, read by replays)."""
    return f"actor_{actor_id}"
