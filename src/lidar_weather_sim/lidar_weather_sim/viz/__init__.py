"""Pictures of recorded clouds without rviz2: ``lidar-weather-sim render`` (bird's-eye and range-image
PNGs, an animated GIF, a self-contained 3D HTML page). Reads bags through :mod:`lidar_weather_sim.io`;
all geometry is in the cloud's sensor frame (REP-103: x forward, y left, z up; metres)."""
