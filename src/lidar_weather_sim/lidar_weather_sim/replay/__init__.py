"""Re-simulation of a recording along its recorded sensor poses (:mod:`.resimulator`), with what the gap search
and the augmentation share about it: the road level and the vehicles around the sensor (:mod:`.surroundings`)
and the beams' keys that pair returns of two clouds (:mod:`.beams`)."""
