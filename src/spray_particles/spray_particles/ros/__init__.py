"""The ROS 2 node (``spray_node``): the only part of spray_particles that imports rclpy."""
