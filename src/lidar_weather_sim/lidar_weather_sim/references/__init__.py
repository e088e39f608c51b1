"""Generators of "measured" recordings and the independent references the simulator is checked against:
``make-measured`` (:mod:`.measured`), the seeded gap draw (:mod:`.cases`), the droplet reference atmosphere
(:mod:`.droplets`) and a simplified Hahner-style fog generator (:mod:`.hahner`), written apart from the
simulator's own atmosphere."""
