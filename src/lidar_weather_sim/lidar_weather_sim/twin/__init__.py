"""Digital twin of a recording (``lidar-weather-sim twin``): poses, static mesh, reflectivity, profile, split."""
