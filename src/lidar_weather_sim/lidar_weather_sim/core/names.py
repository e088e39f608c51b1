"""Topic and frame names shared by every node, CLI and test (REP-105 frames)."""

TOPIC_POINTS = "/lidar/points"
TOPIC_POINTS_FILTERED = "/lidar/points/filtered"
TOPIC_POINTS_REMOVED = "/lidar/points/removed"
TOPIC_TF = "/tf"
TOPIC_TF_STATIC = "/tf_static"
TOPIC_CLOCK = "/clock"

FRAME_MAP = "map"
FRAME_BASE_LINK = "base_link"
FRAME_LIDAR = "lidar"


def actor_frame(actor_id: int) -> str:
    """The tf frame of a scenario actor's body (published in scenario mode, read by replays)."""
    return f"actor_{actor_id}"
