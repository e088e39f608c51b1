"""The spray particle system: emission on the wheels of moving vehicles, forces, collisions, death.

World frame: the frame the vehicle poses are given in (``map``), z up, m, s.
The system advances on a fixed clock of ``tick_s`` aligned to t = 0, so the
particles at a given simulated time do not depend on how callers split time
(:meth:`SpraySystem.advance_to`); :meth:`SpraySystem.positions_at` extrapolates
from the last tick. All randomness comes from one generator per tick seeded
with (seed, tick index): same seed, same particles.

Two populations (``population``): 0 = inertial particles (4 mm, thesis Table
II-IV), each standing for a concentration of drops that causes one detection
(render sphere ``mesh_diameter_m``); 1 = drop packets: each carries an equal share
of the wheel's airborne water (spray_particles.model.drops) in ``weight`` drops of one
size drawn from the drop-size distribution, with that size's drag, so the small
ones follow the air and linger (the low-Stokes population the thesis names as
missing); a packet spreads by turbulent mixing (``diffusivity``, config/spray.yaml
``mist``), loses the drops that reach the ground (``airborne``) and is seen by its
optical depth (:meth:`SpraySystem.mist_radii`, the ``spray`` region).

A tick of fewer than ``kernels.stages.PARALLEL_FROM`` particles runs in two numba calls
(spray_particles.kernels.fused) with the emission drawn first into the survivors' free rows;
bigger sets (the droplet reference) go stage by stage through the parallel kernels.
Both give the same particles bit for bit (test_determinism.py).

Why one module of ~500 lines: the particle system's state (the arrays of one population) and the
stages that advance it are one thing; the stages' kernels live in kernels/fused.py and kernels/stages.py.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Callable, NamedTuple

import numpy as np
from pydantic import Field

from lidar_weather_sim.core import workers
from lidar_weather_sim.core.config import ConfigModel
from spray_particles.kernels import fused
from spray_particles.model.constants import SprayConstants, load_constants
from spray_particles.model.drops import airborne_water_m3, drops_per_volume, volume_weighted_diameters
from spray_particles.model.emitter import WheelEmitter
from spray_particles.model.forces import CurlNoise, drag_rates, lateral_wind_speed
from spray_particles.model.integrator import step as integrate_step
from spray_particles.kernels.inputs import (AirModel, CurlModes, ParticleArrays, TickConstants, VehicleBodies,
                                             VehicleState)  # fmt: skip
from spray_particles.kernels.stages import PARALLEL_FROM
from spray_particles.model.seeds import TickGenerators

#: A mist packet with less than this share of its drops still airborne is dropped.
MIN_MIST_SHARE = 0.01
#: particles per chunk of a tick's move at least, when the simulator's threads share it (one call costs ~0.3 us a
#: particle, handing a chunk to a thread ~30 us)
MOVE_CHUNK_MIN = 256

PoseFunction = Callable[[float], dict]  # time (s) -> {actor id: 4x4 body-to-world}


@dataclass(frozen=True)
class EmittingVehicle:
    """A vehicle whose wheels throw spray: its actor id, body box (m) and wheel emitter."""

    actor_id: int
    length_m: float
    width_m: float
    height_m: float
    ground_clearance_m: float
    emitter: WheelEmitter


class SprayTunables(ConfigModel):
    """The spray system's tunable parameters that a user sets directly (SI units)."""

    seed: int = Field(0, description="Seed of emission and turbulence")
    emission_scale: float = Field(1.0, ge=0, description="Multiplies the calibrated emission rate")
    inertial_scale: float = Field(1.0, ge=0, description="Multiplies the inertial particles' emission alone (0: drop "
                                  "packets only, the same packets: each population draws from its own generator)")
    film_cv: float = Field(0.0, ge=0, description="Variation of the film seen per tick (coefficient of variation)")
    wind_over_speed: float = Field(0.4, ge=0, le=1.5, description="Air speed past the car in its wake / car speed "
                                                                  "(Table III: 0.4, IV: 1)")
    wake_length_m: float = Field(30.0, gt=0, description="e-folding length of the wake (m)")
    lateral_wind_scale: float = Field(1.0, ge=0, description="Multiplies the calibrated lateral wind fields")
    turbulence_intensity: float = Field(0.1, ge=0, description="RMS turbulence speed / car speed")
    turbulence_length_m: float = Field(1.0, gt=0, description="Eddy size of the curl noise (m)")
    mist_packets_per_wheel_per_tick: float = Field(16.0, ge=0, description="Drop packets per wheel per tick (mean)")
    lifetime_s: float = Field(2.0, gt=0, description="Lifetime of inertial particles (s)")
    mist_lifetime_s: float = Field(4.0, gt=0, description="Lifetime of drop packets (s)")
    tick_s: float = Field(0.01, gt=0, le=0.05, description="Integration step (s)")


class SprayParams(SprayTunables):
    """Everything a :class:`SpraySystem` runs with: the tunables plus what the region derives from the
    scenario (the water film and the ambient wind)."""

    water_film_mm: float = Field(0.5, ge=0, description="Water film on the road (mm)")
    ambient_wind_m_s: tuple[float, float, float] = Field((0.0, 0.0, 0.0), description="Wind in the world frame, "
                                                                                       "blowing towards (m/s)")


@dataclass
class Particles:
    """Struct of arrays, one row per live particle (world frame)."""

    pos: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))
    vel: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))
    age: np.ndarray = field(default_factory=lambda: np.zeros(0))
    lifetime: np.ndarray = field(default_factory=lambda: np.zeros(0))
    kappa: np.ndarray = field(default_factory=lambda: np.zeros(0))
    lam: np.ndarray = field(default_factory=lambda: np.zeros(0))
    vehicle: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64))  # index into system.vehicles
    side: np.ndarray = field(default_factory=lambda: np.zeros(0))  # +1 left wheel, -1 right wheel
    population: np.ndarray = field(default_factory=lambda: np.zeros(0, np.uint8))
    wheel: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64))  # index into the vehicle's wheels
    diameter: np.ndarray = field(default_factory=lambda: np.zeros(0))  # drag diameter (m)
    weight: np.ndarray = field(default_factory=lambda: np.zeros(0))  # real drops per particle (drops, packets)
    diffusivity: np.ndarray = field(default_factory=lambda: np.zeros(0))  # packets' turbulent spreading (m^2/s)
    airborne: np.ndarray = field(default_factory=lambda: np.zeros(0))  # share of a packet's drops not deposited

    def __len__(self) -> int:
        return len(self.age)

    def select(self, keep: np.ndarray) -> "Particles":
        return Particles(*(getattr(self, f)[keep] for f in self.__dataclass_fields__))

    @classmethod
    def concatenate(cls, parts: list["Particles"]) -> "Particles":
        return cls(*(np.concatenate([getattr(p, f) for p in parts]) for f in cls.__dataclass_fields__))

    def copy(self) -> "Particles":
        return Particles(*(getattr(self, f).copy() for f in self.__dataclass_fields__))


class SystemState(NamedTuple):
    """What a :class:`SpraySystem` goes on from after a tick (:meth:`SpraySystem.state`)."""

    tick_index: int
    particles: Particles
    emitted: int


def drawn_film_mm(params: SprayParams, rng: np.random.Generator) -> float:
    """One vehicle's water film for one tick (mm): ``water_film_mm`` times a gamma draw of mean 1 and
    coefficient of variation ``film_cv`` (none when it is 0), from ``rng``."""
    film = params.water_film_mm
    if params.film_cv > 0:
        shape = 1.0 / params.film_cv**2
        film *= rng.gamma(shape, 1.0 / shape)
    return film


class SpraySystem:
    """Particles thrown by ``vehicles`` whose body-to-world poses ``poses(t)`` gives."""

    def __init__(self, vehicles: list[EmittingVehicle], poses: PoseFunction, params: SprayParams | None = None,
                 constants: SprayConstants | None = None) -> None:  # fmt: skip
        self.vehicles = list(vehicles)
        self.poses = poses
        self.params = params or SprayParams()
        self.constants = constants or load_constants()
        self.particles = Particles()
        self.tick_index: int | None = None
        self.noise = CurlNoise(self.params.seed, self.params.turbulence_length_m)
        c = self.constants
        self._kappa_inertial, self._lam_inertial = drag_rates(
            c.particles.diameter_m, c.physics.drag_coefficient, c.physics.air_density_kg_m3,
            c.physics.water_density_kg_m3, c.physics.air_viscosity_pa_s,
        )  # fmt: skip
        self.emitted = 0
        self._pose_cache: dict[int, dict] = {}
        self._target_tick = 0
        self._state_cache: tuple[int, tuple] | None = None  # (tick, its _vehicle_state): the next tick's s0
        self._bodies = _vehicle_bodies(self.vehicles)
        self._ambient = np.asarray(self.params.ambient_wind_m_s, dtype=np.float64)
        self._generators = TickGenerators(2)  # the tick's and a population's draws

    @property
    def time_s(self) -> float | None:
        return None if self.tick_index is None else self.tick_index * self.params.tick_s

    # -- vehicle state -----------------------------------------------------------------
    def _poses_at_tick(self, k: int) -> dict:
        cache = self._pose_cache
        if k not in cache:
            t = k * self.params.tick_s
            many = getattr(self.poses, "__self__", None)
            if many is not None and hasattr(many, "actor_poses_at"):  # batch the rest of the step's ticks
                ticks = list(range(k, max(k + 1, self._target_tick + 2)))
                for tick, p in zip(ticks, many.actor_poses_at(np.array(ticks) * self.params.tick_s)):
                    cache[tick] = p
            else:  # poses that arrive over time (/tf): a tick missing a vehicle is asked again later
                poses = self.poses(t)
                if not all(v.actor_id in poses for v in self.vehicles):
                    return poses
                cache[k] = poses
        return cache[k]

    def _vehicle_state(self, k: int) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Per vehicle at tick ``k``: rotation (V, 3, 3), origin (V, 3), world velocity (V, 3) (finite
        difference to the next tick, or from the previous one where the next is not known yet: poses
        from /tf end at the newest message), present (V,)."""
        dt = self.params.tick_s
        now, later = self._poses_at_tick(k), self._poses_at_tick(k + 1)
        nv = len(self.vehicles)
        rot = np.tile(np.eye(3), (nv, 1, 1))
        org = np.zeros((nv, 3))
        vel = np.zeros((nv, 3))
        present = np.zeros(nv, bool)
        earlier = None
        for j, v in enumerate(self.vehicles):
            if v.actor_id not in now:
                continue
            a = np.asarray(now[v.actor_id])
            if v.actor_id in later:
                velocity = (np.asarray(later[v.actor_id])[:3, 3] - a[:3, 3]) / dt
            else:
                earlier = self._poses_at_tick(k - 1) if earlier is None else earlier
                if v.actor_id not in earlier:
                    continue
                velocity = (a[:3, 3] - np.asarray(earlier[v.actor_id])[:3, 3]) / dt
            rot[j], org[j], vel[j], present[j] = a[:3, :3], a[:3, 3], velocity, True
        return rot, org, vel, present

    # -- air -----------------------------------------------------------------------------
    def air_velocity(self, p: Particles, t: float, rot, org, vel) -> np.ndarray:
        """Air velocity (n, 3) m/s, world frame, at the particles (numba kernel of
        :meth:`air_velocity_reference`)."""
        from spray_particles.kernels.stages import air_velocity

        if not len(p) or not self.vehicles:
            return np.broadcast_to(self._ambient, (len(p), 3)).copy()
        return air_velocity(p.pos, p.vehicle, p.side, VehicleState(rot, org, vel), self._bodies, self._air_model(vel),
                            self._curl_modes(), float(t))  # fmt: skip

    def _air_model(self, vel) -> AirModel:
        """The air kernels' parameters with the vehicles at world velocity ``vel`` (V, 3) m/s."""
        prm, lat = self.params, self.constants.lateral_wind
        v_lat = prm.lateral_wind_scale * lateral_wind_speed(np.linalg.norm(vel, axis=1), lat.slope,
                                                            lat.threshold_speed_m_s)  # fmt: skip
        lo, hi = self.constants.particles.lateral_field_range_m
        return AirModel(np.asarray(v_lat, dtype=np.float64), self._ambient, float(prm.wind_over_speed),
                        float(prm.wake_length_m), float(lo), float(hi), float(prm.turbulence_intensity))  # fmt: skip

    def _curl_modes(self) -> CurlModes:
        """The curl noise's modes as the kernels take them."""
        nz = self.noise
        return CurlModes(nz.k, nz.omega, nz.phase, nz.curl)

    def air_velocity_reference(self, p: Particles, t: float, rot, org, vel) -> np.ndarray:
        """Air velocity (n, 3) m/s, world frame, at the particles: ambient wind + wake of the particle's
        vehicle moving with it at (1 - wind_over_speed) v_car + lateral fields + turbulence (numpy)."""
        prm = self.params
        n = len(p)
        u = np.broadcast_to(np.asarray(prm.ambient_wind_m_s, dtype=np.float64), (n, 3)).copy()
        if not n or not self.vehicles:
            return u
        k = p.vehicle
        R = rot[k]
        body = np.einsum("nji,nj->ni", R, p.pos - org[k])  # world -> body: R^T (p - o)
        length = np.array([v.length_m for v in self.vehicles])[k]
        width = np.array([v.width_m for v in self.vehicles])[k]
        height = np.array([v.height_m for v in self.vehicles])[k]
        behind = -(body[:, 0] + 0.5 * length)  # m behind the rear bumper (negative alongside the car)
        wake = np.exp(-np.maximum(behind, 0.0) / prm.wake_length_m)
        wake *= np.exp(-np.maximum(np.abs(body[:, 1]) - 0.5 * width, 0.0) - np.maximum(body[:, 2] - height, 0.0))
        car_speed = np.linalg.norm(vel[k], axis=1)
        u += (wake * (1.0 - prm.wind_over_speed))[:, None] * vel[k]
        lo, hi = self.constants.particles.lateral_field_range_m
        lat = self.constants.lateral_wind
        in_field = (behind >= lo) & (behind <= hi)
        v_lat = prm.lateral_wind_scale * lateral_wind_speed(car_speed, lat.slope, lat.threshold_speed_m_s)
        lateral_body = np.zeros((n, 3))
        lateral_body[:, 1] = np.where(in_field, -p.side * v_lat, 0.0)  # left-wheel particles pushed right
        turb = self.noise.velocity(body, t) * (prm.turbulence_intensity * car_speed * wake)[:, None]
        u += np.einsum("nij,nj->ni", R, lateral_body + turb)
        return u

    # -- time --------------------------------------------------------------------------------
    def tick_at(self, time_s: float) -> int:
        """The last tick at or before ``time_s`` (s)."""
        return int(np.floor(time_s / self.params.tick_s + 1e-9))

    def advance_to(self, time_s: float) -> None:
        """Run every tick up to ``time_s`` (s); the first call starts the clock there (no particles yet)."""
        target = self.tick_at(time_s)
        if self.tick_index is None:
            self.tick_index = target
            return
        self._target_tick = target
        while self.tick_index < target:
            self._tick(self.tick_index)
            self.tick_index += 1
        for k in [k for k in self._pose_cache if k < self.tick_index]:
            del self._pose_cache[k]

    def state(self) -> SystemState:
        """A copy of what the system goes on from: its tick, particles and emission count."""
        return SystemState(self.tick_index, self.particles.copy(), self.emitted)

    def restore(self, state: SystemState) -> None:
        """Go on from ``state`` (:meth:`state` of a system of the same vehicles, poses and parameters started at the
        same tick): the particles are then those this system would have at that tick, bit for bit (every draw
        is keyed by its tick)."""
        self.tick_index, self.particles, self.emitted = state.tick_index, state.particles.copy(), state.emitted
        self._target_tick = state.tick_index
        self._state_cache = None
        self._pose_cache = {k: v for k, v in self._pose_cache.items() if k >= state.tick_index}

    def positions_at(self, time_s: float) -> np.ndarray:
        """Particle centres (n, 3) at ``time_s``, extrapolated from the last tick (ballistic)."""
        p = self.particles
        if self.tick_index is None or not len(p):
            return p.pos.copy()
        h = time_s - self.tick_index * self.params.tick_s
        out = p.pos + h * p.vel
        out[:, 2] -= 0.5 * self.constants.physics.gravity_m_s2 * h * h * (h > 0)
        return out

    def heights_above_ground(self, pos: np.ndarray) -> np.ndarray:
        """Height (m) of each particle's position ``pos`` (n, 3; world frame) above the ground plane of
        its vehicle at the newest tick (z of the vehicle's body frame; world z for a vehicle index the
        system does not know, as for particles placed by hand)."""
        v = self.particles.vehicle
        if not len(v):
            return np.zeros(0)
        k = self.tick_index or 0
        cached = self._state_cache
        rot, org = (cached[1] if cached is not None and cached[0] == k else self._vehicle_state(k))[:2]
        unknown = int(v.max()) + 1 - len(rot)
        if unknown > 0:
            rot = np.concatenate([rot, np.tile(np.eye(3), (unknown, 1, 1))])
            org = np.concatenate([org, np.zeros((unknown, 3))])
        return np.einsum("ni,ni->n", rot[v][:, :, 2], pos - org[v])

    def mist_radii(self, time_s: float) -> tuple[np.ndarray, np.ndarray]:
        """Horizontal and vertical semi-axes (m) at ``time_s`` of every particle seen as a drop packet
        (an ellipsoid, z up): horizontally sqrt(r0^2 + 2 K age), K its diffusivity (m^2/s; only packets,
        population 1, have one). Vertically the same in free flight; near the ground no more than the
        height K / w_s over which turbulence holds drops settling at w_s (their terminal speed), or the
        packet centre's height above the ground where that is more, but at least r0."""
        p = self.particles
        age = p.age + max(0.0, time_s - (self.time_s or 0.0))
        above = self.heights_above_ground(self.positions_at(time_s))
        return _packet_axes(self.constants.mist.initial_radius_m, p.diffusivity, age, p.kappa, p.lam, above,
                            self.constants.physics.gravity_m_s2)  # fmt: skip

    def _tick(self, k: int) -> None:
        prm, c = self.params, self.constants
        dt = prm.tick_s
        t = k * dt
        rng = self._generators.get([prm.seed & 0xFFFFFFFF, k & 0xFFFFFFFF, 0x5B2A])
        cached = self._state_cache
        s0 = cached[1] if cached is not None and cached[0] == k else self._vehicle_state(k)
        s1 = self._vehicle_state(k + 1)
        self._state_cache = (k + 1, s1)
        p = self.particles
        if len(p) and (len(p) >= PARALLEL_FROM or not self.vehicles):  # big sets: the parallel kernels
            air = self.air_velocity(p, t, *s0[:3])
            p.pos, p.vel = integrate_step(p.pos, p.vel, air, p.kappa, p.lam, c.physics.gravity_m_s2, dt)
            p.age = p.age + dt
            self._deposit_mist(p, s1[0], s1[1])
            self.particles = p.select(self._alive(p, s1[0], s1[1]))
            self._emit(rng, k, s1[3], s1[2], s1[0], s1[1])
        elif type(self)._emit is SpraySystem._emit:  # the emission drawn first, into the survivors' free rows
            blocks = self._emission(rng, k, s1[3], s1[2], s1[0], s1[1])
            extra = sum(n for n, _ in blocks)
            if len(p):
                self.particles = self._fused_step(p, t, s0, s1, extra)
                _fill(self.particles, len(self.particles) - extra, blocks)
            elif blocks:
                self.particles = _append(p, blocks)
        else:  # a subclass' own emission, after the update
            if len(p):
                self.particles = self._fused_step(p, t, s0, s1, 0)
            self._emit(rng, k, s1[3], s1[2], s1[0], s1[1])

    def _fused_step(self, p: "Particles", t: float, s0, s1, extra: int) -> "Particles":
        """The update of :meth:`_tick` (air at ``t`` with the vehicle state ``s0``, one step, ageing,
        deposition and death with the state ``s1`` of the next tick) in two numba calls
        (spray_particles.kernels.fused); the survivors come back with ``extra`` empty rows at the end."""
        prm, c = self.params, self.constants
        now, later = VehicleState(*s0[:3]), VehicleState(*s1[:3])
        tick = TickConstants(float(c.physics.gravity_m_s2), float(prm.tick_s), 0.5, float(c.mist.initial_radius_m))
        arrays = ParticleArrays(*(getattr(p, f) for f in Particles.__dataclass_fields__))
        pos, vel, age, above, vertical = _moved(arrays, (now, later, self._bodies, self._air_model(now.vel),
                                                         self._curl_modes(), float(t), tick))  # fmt: skip
        moved = arrays._replace(pos=pos, vel=vel, age=age)
        arrays = fused.survive(moved, above, vertical, vertical**3, later, self._bodies, MIN_MIST_SHARE, extra)
        return Particles(*arrays)

    def _deposit_mist(self, p: Particles, rot, org) -> None:
        """Ground deposition of mist packets: the drops of the part of a packet's ball that has reached
        the ground plane of its vehicle stay there (``airborne`` = share still airborne, never rising;
        the share of an ellipsoid above a plane is that of the ball of its vertical semi-axis)."""
        mist = np.flatnonzero(p.population == 1)
        if not len(mist):
            return
        k = p.vehicle[mist]
        height = np.einsum("ni,ni->n", rot[k][:, :, 2], p.pos[mist] - org[k])
        _, vertical = _packet_axes(self.constants.mist.initial_radius_m, p.diffusivity[mist], p.age[mist],
                                   p.kappa[mist], p.lam[mist], height, self.constants.physics.gravity_m_s2)  # fmt: skip
        p.airborne[mist] = np.minimum(p.airborne[mist], ball_share_above(height, vertical))

    def _alive(self, p: Particles, rot, org) -> np.ndarray:
        """Particles still alive: younger than their lifetime, above the ground under their vehicle,
        outside its body (lower body box minus the wheel arches)."""
        from spray_particles.kernels.stages import collisions

        dead = collisions(p.pos, p.vehicle, rot, org, self._bodies)
        deposited = (p.population == 1) & (p.airborne <= MIN_MIST_SHARE)
        return (p.age < p.lifetime) & ~dead & ~deposited

    def emission_mean_per_frame(self, speed_m_s: float, film_mm: float) -> float:
        """Mean inertial particles per wheel per sensor frame: eq. 2's linear dependence on film x speed
        above a threshold speed, calibrated to Table III (config/spray.yaml emission)."""
        e = self.constants.emission
        return self.params.emission_scale * self.params.inertial_scale * e.gain_per_mm_m_s * film_mm * \
            max(0.0, speed_m_s - e.threshold_speed_m_s)  # fmt: skip

    def _emit(self, rng, tick: int, present, vel, rot, org) -> None:
        """Append the tick's emission (:meth:`_emission`) to ``self.particles``."""
        blocks = self._emission(rng, tick, present, vel, rot, org)
        if blocks:
            self.particles = _append(self.particles, blocks)

    def _emission(self, rng, tick: int, present, vel, rot, org) -> list[tuple[int, dict]]:
        """The particles emitted at the end of tick ``tick``: per vehicle, Poisson counts per wheel of both
        populations from ``rng``, then each population's own generator for where and (packets) which
        drop size; blocks (row count, {field: values}) in the order vehicle, population."""
        prm, c = self.params, self.constants
        dt = prm.tick_s
        blocks = []
        for k, v in enumerate(self.vehicles):
            if not present[k]:
                continue
            speed = float(np.linalg.norm(vel[k]))
            film = drawn_film_mm(prm, rng)
            lam = self.emission_mean_per_frame(speed, film) * prm.tick_s / c.emission.frame_period_s
            # counts by inverse CDF of fixed uniforms and per-population generators: the same draws
            # whatever the film, so more water adds particles to the same ones (common random numbers,
            # which keeps a fit of the water film smooth)
            u = rng.random((2, v.emitter.n_wheels))
            water = prm.emission_scale * airborne_water_m3(c, film, speed, dt)
            n_packets = prm.mist_packets_per_wheel_per_tick if water > 0 else 0.0
            to_world = rot[k].T
            for pop, counts in ((0, _poisson_quantile(u[0], lam)), (1, _poisson_quantile(u[1], n_packets))):
                n = int(counts.sum())
                if not n:
                    continue
                draws = self._generators.get([prm.seed & 0xFFFFFFFF, tick & 0xFFFFFFFF, 0x5B2A, k, 1 + pop], 1)
                pos_b, vel_b, side, wheel = v.emitter.emit(draws, counts, speed, dt)
                block = {"pos": pos_b @ to_world + org[k], "vel": vel_b @ to_world + vel[k], "age": 0.0, "side": side,
                         "vehicle": k, "population": pop, "wheel": wheel, "airborne": 1.0}  # fmt: skip
                if pop == 0:
                    block.update(lifetime=prm.lifetime_s, diameter=c.particles.diameter_m, kappa=self._kappa_inertial,
                                 lam=self._lam_inertial, weight=1.0, diffusivity=0.0)  # fmt: skip
                else:  # drop packets: an equal share of the wheel's airborne water each, in drops of one size
                    d = volume_weighted_diameters(c, draws, n, speed)
                    kappa, lam_d = drag_rates(d, c.physics.drag_coefficient, c.physics.air_density_kg_m3,
                                              c.physics.water_density_kg_m3, c.physics.air_viscosity_pa_s)  # fmt: skip
                    block.update(lifetime=prm.mist_lifetime_s, diameter=d, kappa=kappa, lam=lam_d,
                                 weight=drops_per_volume(d, water / n_packets),
                                 diffusivity=c.mist.mixing_length_m * speed)  # fmt: skip
                blocks.append((n, block))
                self.emitted += n
        return blocks


def _moved(arrays: ParticleArrays, inputs: tuple) -> tuple[np.ndarray, ...]:
    """:func:`~spray_particles.kernels.fused.move` of the particles ``arrays`` with the tick's other ``inputs``, in
    chunks of rows the simulator's threads share (:mod:`lidar_weather_sim.core.workers`): each particle moves on its
    own, so the result is the one call's, bit for bit."""
    cuts = workers.bounds(len(arrays.age), MOVE_CHUNK_MIN, max_chunks=workers.THREADS)
    if len(cuts) == 2:
        return fused.move(arrays, *inputs)
    parts = workers.run_chunks(lambda c: fused.move(ParticleArrays(*(a[cuts[c] : cuts[c + 1]] for a in arrays)),
                                                    *inputs), len(cuts) - 1)  # fmt: skip
    return tuple(np.concatenate([part[i] for part in parts]) for i in range(len(parts[0])))


def _vehicle_bodies(vehicles: list[EmittingVehicle]) -> VehicleBodies:
    """The body boxes and wheel arches of ``vehicles`` as the kernels take them (body frame, m); a wheel
    arch is a cylinder 5 cm larger than the tyre, 5 cm wider on each side."""
    nv, wmax = len(vehicles), max([v.emitter.n_wheels for v in vehicles] or [1])
    wheel_xz, wheel_y = np.zeros((nv, wmax, 2)), np.zeros((nv, wmax))
    for k, v in enumerate(vehicles):
        wheel_xz[k, : v.emitter.n_wheels, 0] = v.emitter.wheel_xy[:, 0]
        wheel_xz[k, : v.emitter.n_wheels, 1] = v.emitter.radius_m
        wheel_y[k, : v.emitter.n_wheels] = v.emitter.wheel_xy[:, 1]
    return VehicleBodies(
        length=np.array([v.length_m for v in vehicles], dtype=np.float64),
        width=np.array([v.width_m for v in vehicles], dtype=np.float64),
        height=np.array([v.height_m for v in vehicles], dtype=np.float64),
        clearance=np.array([v.ground_clearance_m for v in vehicles], dtype=np.float64),
        wheel_xz=wheel_xz,
        wheel_y=wheel_y,
        n_wheels=np.array([v.emitter.n_wheels for v in vehicles], dtype=np.int64),
        arch_r=np.array([v.emitter.radius_m + 0.05 for v in vehicles], dtype=np.float64),
        arch_half_w=np.array([0.5 * v.emitter.width_m + 0.05 for v in vehicles], dtype=np.float64),
    )


def _append(p: Particles, blocks: list[tuple[int, dict]]) -> Particles:
    """``p`` followed by the ``blocks`` (row count, {field: array or one value for all rows})."""
    n0 = len(p)
    n = n0 + sum(m for m, _ in blocks)
    out = []
    for name in Particles.__dataclass_fields__:
        old = getattr(p, name)
        a = np.empty((n,) + old.shape[1:], old.dtype)
        a[:n0] = old
        out.append(a)
    out = Particles(*out)
    _fill(out, n0, blocks)
    return out


def _fill(p: Particles, start: int, blocks: list[tuple[int, dict]]) -> None:
    """Write the ``blocks`` into the rows of ``p`` from ``start`` on."""
    for name in Particles.__dataclass_fields__:
        a, j = getattr(p, name), start
        for m, block in blocks:
            a[j : j + m] = block[name]
            j += m


def _packet_axes(r0: float, diffusivity, age, kappa, lam, above, gravity: float) -> tuple[np.ndarray, np.ndarray]:
    """Semi-axes (m) of drop packets ``age`` s old whose centres lie ``above`` m over the ground (see
    :meth:`SpraySystem.mist_radii`). K / w_s is the thickness of the layer in which turbulence holds a
    suspension settling at w_s against the ground (concentration ~ exp(-w_s z / K)); a packet above that
    layer falls as a whole and spreads alike in every direction. The settling speed w_s solves
    g = kappa w^2 + lam w (quadratic and Stokes drag rates), so K / w_s = K (lam + sqrt(lam^2 + 4 kappa g)) / 2g."""
    horizontal = np.sqrt(r0 * r0 + 2.0 * diffusivity * age)
    held = diffusivity * (lam + np.sqrt(lam * lam + 4.0 * kappa * gravity)) / (2.0 * gravity)
    return horizontal, np.minimum(horizontal, np.maximum(np.maximum(held, r0), above))


def ball_share_above(height: np.ndarray, radius: np.ndarray) -> np.ndarray:
    """Share (0-1) of the volume of balls of ``radius`` (m) centred ``height`` (m) above a plane that lies
    above it (spherical cap below the plane: V = pi h^2 (3 r - h) / 3, h = r - height)."""
    h = np.clip(radius - height, 0.0, 2.0 * radius)
    return 1.0 - h * h * (3.0 * radius - h) / (4.0 * radius**3)


def _poisson_quantile(u: np.ndarray, lam: float) -> np.ndarray:
    """Poisson(lam) counts as the quantiles of the uniforms ``u`` (monotone in lam for fixed u):
    the smallest k whose CDF reaches u."""
    if lam <= 0:
        return np.zeros(len(u), np.int64)
    pmf = _POISSON_PMF.get(lam)
    if pmf is None:
        n = int(lam + 12.0 * np.sqrt(lam) + 12.0)
        pmf = np.exp(fused.poisson_log_pmf(n, np.log(lam), lam, _log_factorial(n)))
        if len(_POISSON_PMF) > 64:
            _POISSON_PMF.clear()
        _POISSON_PMF[lam] = pmf
    return fused.quantiles(pmf, u)


_POISSON_PMF: dict[float, np.ndarray] = {}  # probabilities by mean (the packets' mean is the same every tick)
_LOG_FACTORIAL: dict[int, np.ndarray] = {}


def _log_factorial(n: int) -> np.ndarray:
    """log(k!) for k = 0 .. n - 1 (cached by n)."""
    if n not in _LOG_FACTORIAL:
        k = np.arange(n)
        _LOG_FACTORIAL[n] = np.concatenate([[0.0], np.cumsum(np.log(k[1:]))])
    return _LOG_FACTORIAL[n]
