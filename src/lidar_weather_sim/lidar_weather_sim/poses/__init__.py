"""Where the sensor and the actors are: a tf2-style transform buffer, pose sources over it, a plausibility gate."""
