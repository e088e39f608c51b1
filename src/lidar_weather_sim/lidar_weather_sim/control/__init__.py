"""Driving functions on a LiDAR cloud (the closed loop's adaptive cruise controller)."""
