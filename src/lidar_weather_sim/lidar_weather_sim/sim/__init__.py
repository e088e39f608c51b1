"""The virtual LiDAR: the frame pipeline, the session the node wraps, and offline runs into a bag."""
