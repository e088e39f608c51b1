"""``spray`` region plugin for lidar_weather_sim: spray particles as scatterers of the multi-echo pipeline.

Inertial particles are spheres of the thesis' mesh diameter (1.8 cm) with water's
single scattering albedo (0.53, absorption 0.47, Table II): a sub-ray that enters
one is returned from the sphere's surface like a Lambertian surface hit
(reflectance = albedo x cos(incidence)) and is fully blocked behind it (occlusion
1). Drop packets are balls of drops seen by their optical depth (``_hit_returns``):
dense young packets near the wheels and dilute old ones close to the sensor return
light, dilute ones far away do not (the 1/R^2 of the echo threshold), and each lets
exp(-tau) of the light through. So spray creates first echoes in front of the
vehicle that throws it and hides what lies behind on that sub-ray; the other
sub-rays of the beam still reach the vehicle. Labels are ``Label.SPRAY`` (14),
object ids the emitting vehicle's actor id.

The region needs the scenario's actors and their poses: ``RegionContext.actors``
(emitting vehicles are those with ``emits_spray``, or ``actor_ids``) and
``RegionContext.pose_source`` (anything with ``actor_poses(t) -> {id: 4x4}``,
e.g. the scenario player). ``step(t0, t1)`` advances the particles in simulated
time (the simulator calls it before each batch); the first step starts ``warmup_s`` earlier.

With ``source: topic`` the particles come from spray_node instead
(``RegionContext.inputs``, a :class:`~lidar_weather_sim.regions.topic_inputs.TopicInputs` that
lidar_sim_node fills from ``topic``): the newest message, as published, with the fields
of :mod:`spray_particles.sensing.particle_cloud`; no particles until the first one arrives.
"""

from __future__ import annotations

from typing import ClassVar, Literal, NamedTuple

import numba
import numpy as np
from pydantic import Field

from lidar_weather_sim.core.config import ConfigError
from lidar_weather_sim.core.points import Label
from lidar_weather_sim.regions.base import RayBatch, RegionContext, RegionEffect, Scatterers
from lidar_weather_sim.regions.weather import Weather
from spray_particles.model.constants import load_constants
from spray_particles.model.emitter import vehicle_emitter
from spray_particles.kernels.fused import packet_radii
from spray_particles.sensing.particle_cloud import TOPIC_FIELDS, TOPIC_PARTICLES, particle_cloud
from spray_particles.sensing.raycast import candidates, group_bounds, origin_spread, rays_in_cone, sphere_hits
from spray_particles.model.system import EmittingVehicle, SprayParams, SpraySystem, SprayTunables
from spray_particles.model.water import tyre_dimensions


class SprayRegion:
    name = "spray"

    class Params(SprayTunables):
        source: Literal["internal", "topic"] = Field(
            "internal", description="Particles: 'internal' (this process steps them) or 'topic' (spray_node's)")
        topic: str = Field(TOPIC_PARTICLES, description="PointCloud2 of spray_node's particles (source 'topic')")
        actor_ids: list[int] | None = Field(None, description="Emitting actors (default: those with emits_spray)")
        water_film_mm: float | None = Field(None, ge=0, le=3, description="Overrides weather.road.water_film_mm for "
                                            "this region (mm); both none: eq. 1 from the rain")
        mesh_diameter_m: float | None = Field(None, gt=0, description="Render sphere diameter (m); default config/spray.yaml")
        albedo: float | None = Field(None, ge=0, le=1, description="Single scattering albedo; default config/spray.yaml")
        warmup_s: float = Field(0.0, ge=0, le=60, description="Simulated time (s) the particles run before the first "
                                "step, so spray is already out at the first frame (actors must move then: a "
                                "trajectory may start before 0); 0: the first frame has none")

        moved_keys: ClassVar[dict[str, str]] = {"texture_depth_mm": "moved to weather.road.texture_depth_mm"}

    def __init__(self, params: "SprayRegion.Params", context: RegionContext) -> None:
        self.p = params
        self.constants = c = load_constants()
        self.inputs = getattr(context, "inputs", None)
        if params.source == "topic":
            if self.inputs is None:
                raise ConfigError("region 'spray': source 'topic' but no topic inputs in the RegionContext")
            self.inputs.want(params.topic, TOPIC_FIELDS, owner=self)
        actors = list(getattr(context, "actors", None) or [])
        wanted = params.actor_ids
        chosen = [a for a in actors if (a.id in wanted if wanted is not None else getattr(a, "emits_spray", False))]
        if wanted is not None:
            missing = sorted(set(wanted) - {a.id for a in chosen})
            if missing:
                raise ConfigError(f"region 'spray' parameters: key 'actor_ids': value {missing}: no such actors")
        self.pose_source = getattr(context, "pose_source", None)
        if chosen and self.pose_source is None:
            raise ConfigError("region 'spray': emitting actors but no pose source in the RegionContext")
        radius, width = tyre_dimensions(c.tyre.size)
        vehicles = []
        for a in chosen:
            s = a.size
            emitter = vehicle_emitter(s.length_m, s.width_m, s.height_m, radius, width, c.tyre.treads_across,
                                      c.tyre.ring_vertices)  # fmt: skip
            vehicles.append(EmittingVehicle(a.id, s.length_m, s.width_m, s.height_m, 0.15, emitter))
        weather = context.weather or Weather()
        rain = weather.precipitation.intensity_mm_h if weather.precipitation.type == "rain" else 0.0
        film = params.water_film_mm if params.water_film_mm is not None else weather.road.film_mm(rain)
        wind = (0.0, 0.0, 0.0)
        if weather.wind.speed_m_s > 0:  # blows from direction_deg (from north, clockwise)
            a = np.deg2rad(weather.wind.direction_deg)
            wind = (-weather.wind.speed_m_s * np.sin(a), -weather.wind.speed_m_s * np.cos(a), 0.0)
        self.water_film_mm = film
        sp = SprayParams(**params.model_dump(include=set(SprayTunables.model_fields)), water_film_mm=film,
                         ambient_wind_m_s=wind)  # fmt: skip
        poses = self.pose_source.actor_poses if self.pose_source is not None else (lambda t: {})
        self.system = SpraySystem(vehicles, poses, sp, c)
        self.radius_m = 0.5 * (params.mesh_diameter_m or c.particles.mesh_diameter_m)
        self.albedo = c.particles.single_scattering_albedo if params.albedo is None else params.albedo
        self._actor_ids = np.array([v.actor_id for v in vehicles], dtype=np.uint32)
        memo = getattr(context, "memo", None)
        #: (start tick, tick) -> the particles' state there, shared with this region's earlier builds (``memo``)
        self._states = None
        if memo is not None and params.source == "internal":
            actors = tuple((a.id, a.size.length_m, a.size.width_m, a.size.height_m) for a in chosen)
            self._states = memo.setdefault(("spray", sp.model_dump_json(), actors), {})
        self._start_tick: int | None = None

    def step(self, t0_s: float, t1_s: float) -> None:
        """Advance the particles to ``t1_s`` (simulated s; the system keeps its own fixed-step clock;
        nothing to do with source 'topic'). With a ``memo`` in the context, a state an earlier build of the same
        particles reached is taken from there instead of simulated again."""
        if self.p.source == "topic":
            return
        system = self.system
        if system.time_s is None:
            system.advance_to(t0_s - self.p.warmup_s)
            self._start_tick = system.tick_index
        target = system.tick_at(t1_s)
        if self._states is None or target <= system.tick_index:
            system.advance_to(t1_s)
            return
        kept = self._states.get((self._start_tick, target))
        if kept is not None:
            system.restore(kept)
            return
        system.advance_to(t1_s)
        self._states[(self._start_tick, target)] = system.state()

    def radii(self, time_s: float, centres: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
        """Horizontal and vertical semi-axes (m) of every particle at ``time_s`` (``centres``: their
        positions then, if the caller has them): the render sphere of an inertial particle, the ellipsoid
        a drop packet has spread to."""
        s, c = self.system, self.constants
        p = s.particles
        above = s.heights_above_ground(s.positions_at(time_s) if centres is None else centres)
        return packet_radii(p.age, max(0.0, time_s - (s.time_s or 0.0)), p.diffusivity, p.kappa, p.lam, p.population,
                            above, c.mist.initial_radius_m, c.physics.gravity_m_s2, self.radius_m)  # fmt: skip

    def particle_cloud(self, time_s: float) -> np.ndarray:
        """The particles of the in-process system at ``time_s`` as spray_node publishes them
        (:data:`~spray_particles.sensing.particle_cloud.PARTICLE_DTYPE`, world frame)."""
        p = self.system.particles
        centres = self.system.positions_at(time_s)
        radii, vertical = self.radii(time_s, centres)
        return particle_cloud(centres, radii, p.population, vertical, _cross_section(p),
                              self._actor_ids[p.vehicle])  # fmt: skip

    def _particles(self, time_s: float) -> "_Particles | None":
        """What the ray test needs of the particles at ``time_s``: from the in-process system, or the
        newest message of the topic (as published; None before the first)."""
        if self.p.source == "topic":
            got = self.inputs.latest(self.p.topic)
            if got is None or not len(got.points):
                return None
            c = got.points
            ids, group = np.unique(c["object_id"], return_inverse=True)
            centres = np.stack([c["x"], c["y"], c["z"]], axis=1).astype(np.float64)
            return _Particles(centres, c["radius"].astype(np.float64), c["vertical"].astype(np.float64),
                              group.astype(np.int64), len(ids), c["population"], c["cross_section_m2"].astype(np.float64),
                              c["object_id"].astype(np.uint32))  # fmt: skip
        centres = self.system.positions_at(time_s)
        if not len(centres):
            return None
        p = self.system.particles
        radii, vertical = self.radii(time_s, centres)
        groups = max(len(self.system.vehicles), int(p.vehicle.max()) + 1)  # particles may be placed by hand
        return _Particles(centres, radii, vertical, p.vehicle, groups, p.population, _cross_section(p),
                          self._actor_ids[p.vehicle])  # fmt: skip

    def apply(self, batch: RayBatch, rng: np.random.Generator) -> RegionEffect:
        n, n_sub = batch.shape
        if self.p.source == "internal" and self.system.time_s is None:
            self.step(float(batch.time_s.min()), float(batch.time_s.max()))
        p = self._particles(float(batch.time_s.mean()))
        if p is None:
            return RegionEffect()
        centres, radii, vertical = p.centres, p.radius, p.vertical
        dirs = batch.directions.reshape(-1, 3)
        # broad phase per vehicle: the bounding sphere of its particles against the batch's rays
        # (one dot product per ray); only the rays inside one of these cones go further
        ref, spread = origin_spread(np.ascontiguousarray(batch.origins, np.float64))  # mean origin, farthest from it
        lo, hi, largest = group_bounds(centres, radii, p.group, p.n_groups)
        chosen = np.zeros(len(lo), bool)
        ray_mask = np.zeros(len(dirs), bool)
        for k in np.flatnonzero(largest >= 0):  # vehicles with particles
            q = 0.5 * (lo[k] + hi[k]) - ref
            rad = 0.5 * float(np.linalg.norm(hi[k] - lo[k])) + float(largest[k]) + spread
            dist = float(np.linalg.norm(q))
            if dist <= rad:
                chosen[k] = True
                ray_mask[:] = True
                continue
            cos_half = float(np.cos(min(np.pi, np.arcsin(min(1.0, rad / dist)) * 1.001 + 1e-6)))
            chosen[k] = rays_in_cone(dirs, q / dist, cos_half, ray_mask)
        rays, idx, origins, directions, max_range = candidates(ray_mask, chosen, p.group, batch.origins, dirs,
                                                               batch.distance.reshape(-1), n_sub)  # fmt: skip
        if not len(rays) or not len(idx):
            return RegionEffect()
        hits = sphere_hits(origins, directions, max_range, centres[idx], radii[idx], vertical[idx])
        if not len(hits.ray):
            return RegionEffect()
        beam, sub, particle, range_m, chord, tau, packet = _hit_geometry(
            hits.ray, hits.sphere, hits.range_m, hits.half_chord_m, rays, idx, max_range, n_sub, p.population,
            p.cross_section, radii, vertical)  # fmt: skip
        phase = self.constants.particles.backscatter_phase
        reflectance, occlusion, range_m = _hit_returns(packet, -np.expm1(-tau), hits.cos_incidence, range_m, chord,
                                                       self.albedo, phase)  # fmt: skip
        sc = Scatterers(
            beam=beam, subray=sub, range_m=range_m, reflectance=reflectance, occlusion=occlusion,
            label=np.full(len(beam), Label.SPRAY, np.uint8), object_id=p.object_id[particle],
        )  # fmt: skip
        return RegionEffect(scatterers=sc)


class _Particles(NamedTuple):
    """The particles as the ray test sees them: centres (n, 3) m (world), horizontal and vertical
    semi-axes (n,) m, group (n,) (emitting vehicle, 0..n_groups-1), population (n,), summed drop
    cross-section (n,) m^2 (packets) and object id (n,)."""

    centres: np.ndarray
    radius: np.ndarray
    vertical: np.ndarray
    group: np.ndarray
    n_groups: int
    population: np.ndarray
    cross_section: np.ndarray
    object_id: np.ndarray


def _cross_section(p) -> np.ndarray:
    """Summed cross-section (m^2) of the airborne drops of each particle of ``p`` (system.Particles)."""
    return p.weight * (np.pi / 4.0) * (p.diameter * p.diameter) * p.airborne


@numba.njit(cache=True, nogil=True)
def _hit_geometry(ray, sphere, entry, half_chord, rays, idx, max_range, n_sub, population, cross_section, radius,
                  vertical):  # fmt: skip
    """Per hit of the candidate rays ``rays`` (indices of (beam, sub-ray) pairs) and spheres ``idx``
    (indices of particles): beam, sub-ray, particle, entry range (m), the chord (m) inside the sphere
    or ellipsoid up to the scene hit (``max_range``), its optical depth tau had the particle been a drop
    packet (a uniform ellipsoid, semi-axes ``radius``, ``radius``, ``vertical``, holding drops of
    summed ``cross_section`` (m^2): cross-section per volume x chord) and whether it is one
    (population 1)."""
    n = ray.shape[0]
    beam, sub, particle = np.empty(n, np.int64), np.empty(n, np.int64), np.empty(n, np.int64)
    chord, tau, packet = np.empty(n), np.empty(n), np.empty(n, np.bool_)
    for h in range(n):
        r = rays[ray[h]]
        beam[h], sub[h] = r // n_sub, r % n_sub
        i = idx[sphere[h]]
        particle[h] = i
        chord[h] = min(2.0 * half_chord[h], max_range[ray[h]] - entry[h])
        density = cross_section[i] / (4.0 / 3.0 * np.pi * (radius[i] * radius[i]) * vertical[i])  # per m^3
        tau[h] = density * chord[h]
        packet[h] = population[i] == 1
    return beam, sub, particle, entry, chord, tau, packet


@numba.njit(cache=True, nogil=True)
def _hit_returns(packet, opacity_of_packet, cos_incidence, entry, chord, albedo, phase_of_packet):
    """Reflectance, occlusion (0-1) and range (m) of each hit. An inertial particle is a solid sphere:
    albedo x cos(incidence) at its entry point, blocking the sub-ray. A drop packet is returned from
    its chord's middle with reflectance albedo x phase x (1 - exp(-tau)) and passes on exp(-tau) of
    the light (``opacity_of_packet`` = 1 - exp(-tau), from numpy's expm1)."""
    n = packet.shape[0]
    reflectance, occlusion, range_m = np.empty(n), np.empty(n), np.empty(n)
    for h in range(n):
        occlusion[h] = opacity_of_packet[h] if packet[h] else 1.0
        phase = phase_of_packet if packet[h] else cos_incidence[h]
        reflectance[h] = albedo * phase * occlusion[h]
        range_m[h] = entry[h] + (0.5 * chord[h] if packet[h] else 0.0)
    return reflectance, occlusion, range_m
