"""Default frame budgets of the gap search (``lidar-weather-sim gap``; a module of its own so the CLI reads
them without importing the search).

They are what test/test_gap.py checks, so that a user who sets none gets tested budgets."""

FIT_FRAMES = 30  # calibration frames used for fitting
HELDOUT_FRAMES = 30  # held-out frames used for every decision
SCREEN_FRAMES = 6  # calibration frames of the screening grid
