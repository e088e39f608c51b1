"""The reality gap: signatures, compare, effects, re-simulation, the gap search and its report, make-measured."""
