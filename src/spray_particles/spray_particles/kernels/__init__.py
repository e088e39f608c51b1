"""numba kernels of a particle tick: the stages (air, integration, collisions; serial and parallel) and
the fused tick in two calls, bit for bit the numpy stages of :mod:`spray_particles.model`."""
