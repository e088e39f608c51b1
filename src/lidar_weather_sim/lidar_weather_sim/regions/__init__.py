"""Region plugins (thesis framework): the protocol and registry, the sensor cover and the atmosphere."""
