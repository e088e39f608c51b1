"""Spray particle systems thrown by vehicle wheels (thesis paper 3).

Pure-Python library (numpy, no rclpy at import time); the ROS 2 node and the
``spray`` region plugin for lidar_weather_sim sit on top of it.
"""
