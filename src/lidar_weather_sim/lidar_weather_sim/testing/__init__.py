"""Small scenes, profiles and seeded malformed messages for tests and scripts (no ROS)."""
