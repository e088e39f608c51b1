"""A region plugin for lidar_weather_sim (copy of templates/region_template)."""
