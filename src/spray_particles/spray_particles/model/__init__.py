"""The spray physics: constants, water film and drops, wheel emitter, forces, integrator, the particle
system and its seeds, and the fits of the constants to the thesis tables (world frame, m, s)."""
