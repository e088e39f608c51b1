"""The reality gap (entry points in :mod:`.command`): compare a recording with its re-simulation (signatures,
compare, report) and search the effects that close the gap (:mod:`.search` and its rounds)."""

# Default frame budgets of the search, here so that the CLI reads them without importing the search; they
# are what test/test_gap.py checks, so that a user who sets none gets tested budgets.
FIT_FRAMES = 30  # calibration frames used for fitting
HELDOUT_FRAMES = 30  # held-out frames used for every decision
SCREEN_FRAMES = 6  # calibration frames of the screening grid
