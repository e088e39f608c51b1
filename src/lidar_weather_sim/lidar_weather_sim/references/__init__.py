"""Generators of "measured" recordings and the independent references the simulator is checked against:
``make-measured`` (:mod:`.measured`), the seeded gap draw (:mod:`.cases`), the droplet reference atmosphere
(:mod:`.droplets`), a simplified Hahner-style fog generator (:mod:`.hahner`) and the fixed generators with their
seeded draw (:mod:`.generators`: fog as loss only, spread or as a shell, rain and snow of other drop-size laws, a
dirty cover), all written apart from the simulator's own atmosphere."""
