"""Scenario files, the player that moves the ego and actors over time, and the World that makes a scenario runnable."""
