"""What a sensor sees of the particles: the exact ray-sphere test and the particle message
(``/spray/particles``) the ``spray`` region rebuilds its scatterers from."""
