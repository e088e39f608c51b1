"""numba kernels of one particle tick: air velocity, integration, collisions (fused, parallel).

They implement exactly the numpy reference of :mod:`spray_particles.model.forces`,
:mod:`spray_particles.model.integrator` and :class:`spray_particles.model.system.SpraySystem`
(tests compare them); units and frames as there (world frame, m, s).
"""

from __future__ import annotations

# Each kernel exists twice: serial (compiled once, cached on disk) and parallel (compiled on first
# use, for big particle sets: thread start-up costs ~0.5 ms a call, more than a few hundred particles).
import math

import numba
import numpy as np


@numba.njit(cache=True, inline="always")
def _accel(vx, vy, vz, ux, uy, uz, kappa, lam, g):
    rx, ry, rz = vx - ux, vy - uy, vz - uz
    c = kappa * math.sqrt(rx * rx + ry * ry + rz * rz) + lam
    return -c * rx, -c * ry, -c * rz - g


@numba.njit(cache=True, inline="always")
def _rate(vx, vy, vz, ux, uy, uz, kappa, lam):
    rx, ry, rz = vx - ux, vy - uy, vz - uz
    return kappa * math.sqrt(rx * rx + ry * ry + rz * rz) + lam


@numba.njit(cache=True, inline="always")
def _relax(p, v, u, g, r, h, out_p, out_v):
    """Exact solution of v' = g - r (v - u) over h (r frozen)."""
    r = max(r, 1e-9)
    decay = math.exp(-r * h)
    for k in range(3):
        term = u[k] - g / r if k == 2 else u[k]  # the velocity it relaxes to
        out_p[k] = p[k] + term * h + (v[k] - term) * (1.0 - decay) / r
        out_v[k] = term + (v[k] - term) * decay


def integrate_inplace(pos, vel, air, kappa, lam, g, dt, stiff_limit):
    """Advance every particle by ``dt``: RK4 if its drag rate r (1/s) has r dt <= stiff_limit, else
    exponential sub-steps of at most 0.5 / r with r frozen at each sub-step's predicted midpoint."""
    n = pos.shape[0]
    for i in numba.prange(n):
        ux, uy, uz = air[i, 0], air[i, 1], air[i, 2]
        vx, vy, vz = vel[i, 0], vel[i, 1], vel[i, 2]
        r0 = _rate(vx, vy, vz, ux, uy, uz, kappa[i], lam[i])
        if r0 * dt <= stiff_limit:
            a1 = _accel(vx, vy, vz, ux, uy, uz, kappa[i], lam[i], g)
            v2 = (vx + 0.5 * dt * a1[0], vy + 0.5 * dt * a1[1], vz + 0.5 * dt * a1[2])
            a2 = _accel(v2[0], v2[1], v2[2], ux, uy, uz, kappa[i], lam[i], g)
            v3 = (vx + 0.5 * dt * a2[0], vy + 0.5 * dt * a2[1], vz + 0.5 * dt * a2[2])
            a3 = _accel(v3[0], v3[1], v3[2], ux, uy, uz, kappa[i], lam[i], g)
            v4 = (vx + dt * a3[0], vy + dt * a3[1], vz + dt * a3[2])
            a4 = _accel(v4[0], v4[1], v4[2], ux, uy, uz, kappa[i], lam[i], g)
            pos[i, 0] += dt / 6.0 * (vx + 2.0 * v2[0] + 2.0 * v3[0] + v4[0])
            pos[i, 1] += dt / 6.0 * (vy + 2.0 * v2[1] + 2.0 * v3[1] + v4[1])
            pos[i, 2] += dt / 6.0 * (vz + 2.0 * v2[2] + 2.0 * v3[2] + v4[2])
            vel[i, 0] = vx + dt / 6.0 * (a1[0] + 2.0 * a2[0] + 2.0 * a3[0] + a4[0])
            vel[i, 1] = vy + dt / 6.0 * (a1[1] + 2.0 * a2[1] + 2.0 * a3[1] + a4[1])
            vel[i, 2] = vz + dt / 6.0 * (a1[2] + 2.0 * a2[2] + 2.0 * a3[2] + a4[2])
        else:
            n_sub = min(64, max(1, int(math.ceil(r0 * dt / 0.5))))
            h = dt / n_sub
            p = np.empty(3)
            v = np.empty(3)
            u = np.empty(3)
            tp = np.empty(3)
            tv = np.empty(3)
            for k in range(3):
                p[k], v[k], u[k] = pos[i, k], vel[i, k], air[i, k]
            for _ in range(n_sub):
                r = _rate(v[0], v[1], v[2], u[0], u[1], u[2], kappa[i], lam[i])
                _relax(p, v, u, g, r, 0.5 * h, tp, tv)
                r = _rate(tv[0], tv[1], tv[2], u[0], u[1], u[2], kappa[i], lam[i])
                _relax(p, v, u, g, r, h, tp, tv)
                for k in range(3):
                    p[k], v[k] = tp[k], tv[k]
            for k in range(3):
                pos[i, k], vel[i, k] = p[k], v[k]


def air_velocity(pos, vehicle, side, state, bodies, air, modes, t):
    """Air velocity (n, 3) m/s at the particles (see SpraySystem.air_velocity) at time ``t`` (s): vehicles
    in ``state`` (:class:`~.inputs.VehicleState`), their ``bodies`` (:class:`~.inputs.VehicleBodies`),
    ``air`` (:class:`~.inputs.AirModel`) and the curl noise's ``modes`` (:class:`~.inputs.CurlModes`)."""
    rot, org, vcar = state.rot, state.org, state.vel
    length, width, height = bodies.length, bodies.width, bodies.height
    v_lat, ambient, wind_over_speed, wake_length = air.v_lat, air.ambient, air.wind_over_speed, air.wake_length
    lat_lo, lat_hi, turb_intensity = air.lateral_lo, air.lateral_hi, air.turbulence
    nk, nomega, nphase, ncurl = modes.k, modes.omega, modes.phase, modes.curl
    n = pos.shape[0]
    m = nk.shape[0]
    out = np.empty((n, 3))
    for i in numba.prange(n):
        k = vehicle[i]
        d0, d1, d2 = pos[i, 0] - org[k, 0], pos[i, 1] - org[k, 1], pos[i, 2] - org[k, 2]
        bx = rot[k, 0, 0] * d0 + rot[k, 1, 0] * d1 + rot[k, 2, 0] * d2
        by = rot[k, 0, 1] * d0 + rot[k, 1, 1] * d1 + rot[k, 2, 1] * d2
        bz = rot[k, 0, 2] * d0 + rot[k, 1, 2] * d1 + rot[k, 2, 2] * d2
        behind = -(bx + 0.5 * length[k])
        wake = math.exp(-max(behind, 0.0) / wake_length)
        wake *= math.exp(-max(abs(by) - 0.5 * width[k], 0.0) - max(bz - height[k], 0.0))
        speed = math.sqrt(vcar[k, 0] ** 2 + vcar[k, 1] ** 2 + vcar[k, 2] ** 2)
        lx, ly, lz = 0.0, 0.0, 0.0
        if behind >= lat_lo and behind <= lat_hi:
            ly = -side[i] * v_lat[k]
        amp = turb_intensity * speed * wake
        if amp != 0.0:
            for j in range(m):
                c = math.cos(bx * nk[j, 0] + by * nk[j, 1] + bz * nk[j, 2] - nomega[j] * t + nphase[j]) * amp
                lx += c * ncurl[j, 0]
                ly += c * ncurl[j, 1]
                lz += c * ncurl[j, 2]
        s = wake * (1.0 - wind_over_speed)
        for q in range(3):
            out[i, q] = ambient[q] + s * vcar[k, q] + rot[k, q, 0] * lx + rot[k, q, 1] * ly + rot[k, q, 2] * lz
    return out


def collisions(pos, vehicle, rot, org, bodies):
    """True where a particle is below the ground of its vehicle's footprint plane or inside its body
    box (ground clearance to height) but not in a wheel arch (body frame; vehicles at ``rot``, ``org``,
    their ``bodies`` a :class:`~.inputs.VehicleBodies`)."""
    length, width, height, clearance = bodies.length, bodies.width, bodies.height, bodies.clearance
    wheel_xz, wheel_y, n_wheels, arch_r, arch_half_w = (bodies.wheel_xz, bodies.wheel_y, bodies.n_wheels,
                                                        bodies.arch_r, bodies.arch_half_w)  # fmt: skip
    n = pos.shape[0]
    dead = np.zeros(n, np.bool_)
    for i in numba.prange(n):
        k = vehicle[i]
        d0, d1, d2 = pos[i, 0] - org[k, 0], pos[i, 1] - org[k, 1], pos[i, 2] - org[k, 2]
        bx = rot[k, 0, 0] * d0 + rot[k, 1, 0] * d1 + rot[k, 2, 0] * d2
        by = rot[k, 0, 1] * d0 + rot[k, 1, 1] * d1 + rot[k, 2, 1] * d2
        bz = rot[k, 0, 2] * d0 + rot[k, 1, 2] * d1 + rot[k, 2, 2] * d2
        if bz <= 0.0:
            dead[i] = True
            continue
        if abs(bx) < 0.5 * length[k] and abs(by) < 0.5 * width[k] and bz > clearance[k] and bz < height[k]:
            in_arch = False
            for w in range(n_wheels[k]):
                ddx, ddz = bx - wheel_xz[k, w, 0], bz - wheel_xz[k, w, 1]
                if ddx * ddx + ddz * ddz < arch_r[k] ** 2 and abs(by - wheel_y[k, w]) < arch_half_w[k]:
                    in_arch = True
                    break
            dead[i] = not in_arch
    return dead


PARALLEL_FROM = 50_000  # particles


def _variants(fn):
    serial = numba.njit(cache=True, nogil=True)(fn)
    holder = {}

    def call(*args):
        if args[0].shape[0] >= PARALLEL_FROM:
            if "p" not in holder:
                holder["p"] = numba.njit(parallel=True)(fn)
            return holder["p"](*args)
        return serial(*args)

    call.__doc__ = fn.__doc__
    call.serial = serial
    return call


integrate_inplace = _variants(integrate_inplace)
air_velocity = _variants(air_velocity)
collisions = _variants(collisions)
