"""``lidar-weather-sim sweep``: many seeded simulation runs over swept scenario keys, on the Dask engine."""
