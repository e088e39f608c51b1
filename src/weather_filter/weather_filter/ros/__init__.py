"""ROS 2 wrapper of the weather filters (imports rclpy)."""
