"""One particle tick in two numba calls, and the wheel emission geometry (serial, cached on disk).

They do what :class:`spray_particles.model.system.SpraySystem` did stage by stage with numpy
(air velocity, integration, ageing, drop-packet deposition, collisions, death and the
compaction of the survivors) in the same floating-point operations, so the particles
are bit for bit the same: only IEEE-exact operations (+ - * / sqrt min max) and libm's
sin / cos (which numpy's float64 loops also use) run here; what numpy computes with its
own SIMD code (exp, pow) stays in numpy between the two calls. World frame, m, s.
"""

from __future__ import annotations

import math

import numba
import numpy as np

from spray_particles.kernels.stages import air_velocity, collisions, integrate_inplace

_air = air_velocity.serial
_integrate = integrate_inplace.serial
_collisions = collisions.serial


@numba.njit(cache=True, nogil=True)
def move(p, now, later, bodies, air, modes, t, tick):
    """Air at tick time ``t`` (s; vehicles ``now``, a :class:`~.inputs.VehicleState`), one step of
    ``tick.dt`` and ageing of the particles ``p`` (:class:`~.inputs.ParticleArrays`); returns new
    (pos, vel, age), each particle's height (m) above its vehicle's ground plane at the next tick
    (vehicles ``later``) and its vertical packet semi-axis (m, see ``model.system._packet_axes``) at its
    new age and height. ``bodies``, ``air``, ``modes``: see :func:`.stages.air_velocity`; ``tick``: a
    :class:`~.inputs.TickConstants`. The inputs are not modified."""
    pos, vel, age, kappa, lam, diffusivity, vehicle = p.pos, p.vel, p.age, p.kappa, p.lam, p.diffusivity, p.vehicle
    gravity, dt, r0 = tick.gravity, tick.dt, tick.r0
    rot1, org1 = later.rot, later.org
    air_u = _air(pos, vehicle, p.side, now, bodies, air, modes, t)
    new_pos, new_vel = pos.copy(), vel.copy()
    _integrate(new_pos, new_vel, air_u, kappa, lam, gravity, dt, tick.stiff_limit)
    n = pos.shape[0]
    new_age = np.empty(n)
    above, vertical = np.empty(n), np.empty(n)
    for i in range(n):
        new_age[i] = age[i] + dt
        k = vehicle[i]
        d0, d1, d2 = new_pos[i, 0] - org1[k, 0], new_pos[i, 1] - org1[k, 1], new_pos[i, 2] - org1[k, 2]
        above[i] = rot1[k, 0, 2] * d0 + rot1[k, 1, 2] * d1 + rot1[k, 2, 2] * d2
        horizontal = math.sqrt(r0 * r0 + 2.0 * diffusivity[i] * new_age[i])
        held = diffusivity[i] * (lam[i] + math.sqrt(lam[i] * lam[i] + 4.0 * kappa[i] * gravity)) / (2.0 * gravity)
        vertical[i] = min(horizontal, max(held, r0, above[i]))
    return new_pos, new_vel, new_age, above, vertical


@numba.njit(cache=True, nogil=True)
def survive(p, above, vertical, vertical_cubed, later, bodies, min_share, extra):
    """Deposition of drop packets (population 1: ``airborne`` = min(airborne, share of the ball of
    radius ``vertical`` centred ``above`` m above the vehicle's ground plane)), then the survivors of ``p``
    (:class:`~.inputs.ParticleArrays`, moved: younger than their lifetime, outside body and ground of the
    vehicles ``later`` with their ``bodies``, packets above ``min_share``) compacted into new arrays with
    ``extra`` free rows at the end (for the particles emitted this tick), in the field order of
    ``model.system.Particles``."""
    (pos, vel, age, lifetime, kappa, lam, vehicle, side, population, wheel, diameter, weight, diffusivity,
     airborne) = p  # fmt: skip
    n = pos.shape[0]
    dead = _collisions(pos, vehicle, later.rot, later.org, bodies)
    share = airborne.copy()
    keep = np.empty(n, np.bool_)
    m = 0
    for i in range(n):
        if population[i] == 1:
            r = vertical[i]
            h = min(max(r - above[i], 0.0), 2.0 * r)
            share[i] = min(airborne[i], 1.0 - h * h * (3.0 * r - h) / (4.0 * vertical_cubed[i]))
        keep[i] = age[i] < lifetime[i] and not dead[i] and not (population[i] == 1 and share[i] <= min_share)
        m += keep[i]
    size = m + extra
    out = (np.empty((size, 3)), np.empty((size, 3)), np.empty(size), np.empty(size), np.empty(size), np.empty(size),
           np.empty(size, np.int64), np.empty(size), np.empty(size, np.uint8), np.empty(size, np.int64),
           np.empty(size), np.empty(size), np.empty(size), np.empty(size))  # fmt: skip
    j = 0
    for i in range(n):
        if not keep[i]:
            continue
        for q in range(3):
            out[0][j, q] = pos[i, q]
            out[1][j, q] = vel[i, q]
        out[2][j], out[3][j], out[4][j], out[5][j] = age[i], lifetime[i], kappa[i], lam[i]
        out[6][j], out[7][j], out[8][j], out[9][j] = vehicle[i], side[i], population[i], wheel[i]
        out[10][j], out[11][j], out[12][j], out[13][j] = diameter[i], weight[i], diffusivity[i], share[i]
        j += 1
    return out


@numba.njit(cache=True, nogil=True)
def ring_body(draws, counts, wheel_xy, tread_offsets, n_vertices, treads, speed, radius, dt):
    """Body-frame positions (n, 3) m, velocities (n, 3) m/s, side (n,) and wheel (n,) of ``counts[w]``
    particles per wheel w from the uniforms ``draws`` (max count, W, 2): vertex and tread of eq. 7-10
    (see ``model.emitter.ring_emission``, thesis x mapped to body -x), particle-major like ``WheelEmitter.emit``."""
    n = 0
    for w in range(counts.shape[0]):
        n += counts[w]
    pos = np.empty((n, 3))
    vel = np.empty((n, 3))
    side = np.empty(n)
    wheel = np.empty(n, np.int64)
    nv = float(n_vertices)
    j = 0
    for w in range(counts.shape[0]):
        for c in range(counts[w]):
            vertex = float(min(int(draws[c, w, 0] * n_vertices), n_vertices - 1))
            tread = min(int(draws[c, w, 1] * treads), treads - 1)
            angle = 2.0 * np.pi * vertex / nv - 0.5 * np.pi + speed * dt * vertex / (nv * radius)
            mag = speed * vertex / nv
            ca, sa = math.cos(angle), math.sin(angle)
            pos[j, 0] = wheel_xy[w, 0] - radius * ca
            pos[j, 1] = wheel_xy[w, 1] + tread_offsets[tread]
            pos[j, 2] = radius * sa + radius
            vel[j, 0] = -(-mag * sa)
            vel[j, 1] = 0.0
            vel[j, 2] = mag * ca
            side[j] = 1.0 if wheel_xy[w, 1] >= 0 else -1.0
            wheel[j] = w
            j += 1
    return pos, vel, side, wheel


@numba.njit(cache=True, nogil=True)
def poisson_log_pmf(n, log_lam, lam, log_factorial):
    """log P(k) = k log(lam) - lam - log(k!) of a Poisson(lam) for k < n (numpy's exp follows)."""
    out = np.empty(n)
    for k in range(n):
        out[k] = k * log_lam - lam - log_factorial[k]
    return out


@numba.njit(cache=True, nogil=True)
def quantiles(pmf, u):
    """The smallest k whose CDF (the running sum of ``pmf``) reaches each uniform of ``u``, at most
    len(pmf) - 1."""
    cdf = np.cumsum(pmf)
    out = np.empty(u.shape[0], np.int64)
    for i in range(u.shape[0]):
        out[i] = min(np.searchsorted(cdf, u[i]), cdf.shape[0] - 1)
    return out


@numba.njit(cache=True, nogil=True)
def packet_radii(age, later, diffusivity, kappa, lam, population, above, r0, gravity, sphere_radius):
    """Horizontal and vertical semi-axes (m) of every particle ``later`` s after its ``age``, ``above`` m
    above its vehicle's ground plane: those of ``model.system._packet_axes`` for drop packets (population 1),
    ``sphere_radius`` for the others."""
    n = age.shape[0]
    horizontal, vertical = np.empty(n), np.empty(n)
    for i in range(n):
        if population[i] != 1:
            horizontal[i] = vertical[i] = sphere_radius
            continue
        h = math.sqrt(r0 * r0 + 2.0 * diffusivity[i] * (age[i] + later))
        held = diffusivity[i] * (lam[i] + math.sqrt(lam[i] * lam[i] + 4.0 * kappa[i] * gravity)) / (2.0 * gravity)
        horizontal[i], vertical[i] = h, min(h, max(held, r0, above[i]))
    return horizontal, vertical
