"""Weather-detection filters and per-frame weather classification.

Pure-Python library (numpy, no rclpy at import time); the ROS 2 node and the
``weather-filter`` CLI sit on top of it.
"""
