"""Clouds in and out without ROS: PointCloud2 codec, rosbag2 bags, recordings, real-sensor imports, a synthetic sweep."""
