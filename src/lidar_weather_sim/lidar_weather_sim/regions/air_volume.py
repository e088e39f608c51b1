"""The physical atmosphere's volume return (fog, and the drops too weak to be seen one by one) as tables of the
echo stage (:mod:`lidar_weather_sim.sensor.volume_tables`), built once per weather state and profile.

Ranges are in m along the beam from the sensor; returns in the simulator's noise units. The mean return density
is the caller's (``C pi beta(r) O(r) exp(-2 alpha r) / r^2``, noise units per m). In the near field the fog's
droplets fluctuate from beam to beam: slab i (edges ``slab_edges[i]``, ``slab_edges[i + 1]``) holds a Poisson
number of droplets, so its return is the mean times ``max(1 + rel_sd[i] z, 0)``, z a standard normal (the
compound-Poisson normal limit, clipped at 0). ``REALISATIONS`` such near fields are drawn once, from a generator
seeded alike for every weather state (common random numbers: the near field changes smoothly with the
weather's values); each beam reads one of them, chosen with the region's generator.

The volume is two layers, each a table cut at the beam's hit: the near layer (the cells in front of
``boundary``: one table per realisation) and the far layer (the mean's cells from ``boundary`` on). The receiver's
AC coupling is causal: ``boundary`` lies 30 time constants behind the last fluctuating slab, where what the filter
keeps of a realisation's near field differs from the mean's by exp(-30) of it, so the far layer is the mean's for
every realisation. Each layer's support is where its waveform exceeds half the floor.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from functools import cache

import numpy as np

from lidar_weather_sim.physics.overlap import OVERLAP_MODELS
from lidar_weather_sim.regions.base import VolumeTerm
from lidar_weather_sim.sensor.volume_tables import (REACH, VolumeTable, cell_density, cell_nodes, grid_step,
                                                     realised_density, table_of_cells, tables_of_cells)

#: Near-field realisations drawn per weather state (each beam reads one).
REALISATIONS = 256
#: Time constants of the AC coupling between the last fluctuating slab and the far layer.
COUPLING_REACH = 30.0
#: The overlap's sampling for the tables (m): fine out to OVERLAP_FINE_M, coarser beyond (linear interpolation).
OVERLAP_FINE_STEP_M, OVERLAP_FINE_M, OVERLAP_COARSE_STEP_M = 0.002, 10.0, 0.05


@dataclass(frozen=True)
class AirVolume:
    """The volume layers of one weather state seen by one profile (module doc)."""

    far: VolumeTable  # the mean from ``boundary_m`` on (the whole beam without fluctuation)
    near: tuple[VolumeTable, ...]  # the realisations in front of ``boundary_m`` (empty: no fluctuation)
    factors: np.ndarray  # (REALISATIONS, slabs): each realisation's factor on the mean per near-field slab
    slab_edges: np.ndarray  # (slabs + 1,) m
    boundary_m: float  # m

    def terms(self, n_beams: int, rng: np.random.Generator) -> list[VolumeTerm]:
        """The layers on ``n_beams`` beams (each cut at its hit), each beam's realisation drawn from ``rng``."""
        ones = np.ones(n_beams)
        terms = [VolumeTerm(self.far, ones)] if self.far.support[1] > self.far.support[0] else []
        if self.near:
            terms.append(VolumeTerm(self.near, ones, choice=rng.integers(len(self.near), size=n_beams)))
        return terms


def air_volume(density_fn: Callable[[np.ndarray], np.ndarray], *, sigma_m: float, r_max_m: float, start_m: float,
               tau_m: float, floor: float, label: int, slab_edges: np.ndarray, rel_sd: np.ndarray,
               seed: list[int]) -> AirVolume:  # fmt: skip
    """The layers of the mean density ``density_fn(r)`` (noise units per m) from ``start_m`` to ``r_max_m`` (m),
    pulse sigma ``sigma_m`` (m), AC coupling ``tau_m`` (m; 0: DC), support above ``floor`` (noise units) in all,
    cells labelled ``label``; near-field slabs ``slab_edges`` (m) of relative standard deviation ``rel_sd``
    (none: no fluctuation), realisations from ``np.random.default_rng(seed)``."""
    dx = grid_step(sigma_m)
    mean = cell_density(density_fn, sigma_m=sigma_m, r_max_m=r_max_m, start_m=start_m, tau_m=tau_m)
    if not len(rel_sd) or not np.any(rel_sd > 0):
        return AirVolume(table_of_cells(mean, dx, label, floor), (), np.zeros((0, 0)), np.zeros(0), 0.0)
    cells = int(np.ceil((slab_edges[-1] + COUPLING_REACH * tau_m) / dx + 0.5))  # the first far cell (sample)
    boundary_m = (cells - 0.5) * dx
    far = mean.copy()
    far[: cells + REACH] = 0.0
    rng = np.random.default_rng(seed)
    factors = np.maximum(1.0 + rel_sd[None, :] * rng.standard_normal((REALISATIONS, len(rel_sd))), 0.0)
    nodes, lower, upper = cell_nodes(sigma_m=sigma_m, r_max_m=boundary_m, start_m=start_m)
    slab = np.searchsorted(slab_edges, nodes, side="right") - 1  # each node's slab; len(rel_sd): none (factor 1)
    slab[(slab < 0) | (slab >= len(rel_sd))] = len(rel_sd)
    values = density_fn(nodes.ravel()).reshape(nodes.shape)
    realised = realised_density(values, factors, slab, lower, upper, tau_m)
    near = tables_of_cells(realised, dx, label, 0.5 * floor)
    return AirVolume(table_of_cells(far, dx, label, 0.5 * floor), tuple(near), factors, slab_edges, boundary_m)


@cache
def optics_overlap(model: str, r_max_m: float, **optics: float) -> Callable[[np.ndarray], np.ndarray]:
    """O(r) of ``OVERLAP_MODELS[model]`` with ``optics`` (its keyword arguments), sampled once per optics out to
    ``r_max_m`` (m) and interpolated linearly (the defocused overlap's quadrature costs ~30 us a range; on the
    samples the interpolation is within 1e-5 of it)."""
    r = np.concatenate([np.arange(0.0, OVERLAP_FINE_M, OVERLAP_FINE_STEP_M),
                        np.arange(OVERLAP_FINE_M, r_max_m + 2 * OVERLAP_COARSE_STEP_M, OVERLAP_COARSE_STEP_M)])  # fmt: skip
    o = OVERLAP_MODELS[model](r, **optics)
    return lambda range_m: np.interp(range_m, r, o)
