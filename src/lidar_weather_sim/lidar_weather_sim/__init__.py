"""Virtual automotive LiDAR in real weather.

The core modules (``points``, ``cloud_codec``, ``config``, ``bags``,
``tf_buffer``, ``names``...) are plain Python + numpy and import without ROS;
``lidar_weather_sim.ros`` holds the thin rclpy adapters.
"""

__version__ = "0.1.0"
