"""Time integration of particle trajectories: classical RK4 with the air velocity frozen over a step.

State: positions (n, 3) m and velocities (n, 3) m/s in one inertial frame (world or a
test frame), z up. The air velocity ``air`` (n, 3) m/s is evaluated once per step at
its start (it varies over metres and tenths of seconds, the step is 10 ms).
"""

from __future__ import annotations

import numpy as np

from spray_particles.model.forces import acceleration


def rk4_step(pos, vel, air, kappa, lam, gravity: float, dt: float):
    """One RK4 step of x' = v, v' = g - (kappa |v - u| + lambda)(v - u); returns new (pos, vel)."""
    k1v = acceleration(vel, air, kappa, lam, gravity)
    v2 = vel + 0.5 * dt * k1v
    k2v = acceleration(v2, air, kappa, lam, gravity)
    v3 = vel + 0.5 * dt * k2v
    k3v = acceleration(v3, air, kappa, lam, gravity)
    v4 = vel + dt * k3v
    k4v = acceleration(v4, air, kappa, lam, gravity)
    new_pos = pos + dt / 6.0 * (vel + 2.0 * v2 + 2.0 * v3 + v4)
    new_vel = vel + dt / 6.0 * (k1v + 2.0 * k2v + 2.0 * k3v + k4v)
    return new_pos, new_vel


def exponential_step(pos, vel, air, kappa, lam, gravity: float, dt: float):
    """One step for stiff particles (drag rate r = kappa |v - u| + lambda with r dt >~ 1): the linear
    relaxation v' = g - r (v - u) solved exactly with r frozen at a predicted mid-step velocity."""
    g = np.array([0.0, 0.0, -gravity])

    def rate(v):
        rel = v - air
        return kappa * np.sqrt(np.einsum("nk,nk->n", rel, rel)) + lam

    def advance(r, h):
        r = np.maximum(r, 1e-9)[:, None]  # noqa: B023 (pos, vel of the current sub-step)
        terminal = air + g / r  # the velocity it relaxes to
        decay = np.exp(-r * h)
        return pos + terminal * h + (vel - terminal) * (1.0 - decay) / r, terminal + (vel - terminal) * decay

    # sub-steps of at most 0.5 / r, the rate frozen at each sub-step's predicted midpoint
    n_sub = int(min(64, max(1, np.ceil(np.max(rate(vel)) * dt / 0.5))))
    h = dt / n_sub
    for _ in range(n_sub):
        _, v_half = advance(rate(vel), 0.5 * h)
        pos, vel = advance(rate(v_half), h)
    return pos, vel


def step(pos, vel, air, kappa, lam, gravity: float, dt: float, stiff_limit: float = 0.5):
    """One step of every particle: RK4 where the drag rate r = kappa |v - u| + lambda (1/s) has
    r dt <= ``stiff_limit``, :func:`exponential_step` elsewhere (numba kernel; returns new arrays)."""
    from spray_particles.kernels.stages import integrate_inplace

    pos = np.array(pos, dtype=np.float64, order="C")
    vel = np.array(vel, dtype=np.float64, order="C")
    integrate_inplace(pos, vel, np.ascontiguousarray(air, dtype=np.float64),
                       np.ascontiguousarray(kappa, dtype=np.float64), np.ascontiguousarray(lam, dtype=np.float64),
                       float(gravity), float(dt), float(stiff_limit))  # fmt: skip
    return pos, vel


def step_reference(pos, vel, air, kappa, lam, gravity: float, dt: float, stiff_limit: float = 0.5):
    """numpy reference of :func:`step`."""
    rel = vel - air
    stiff = (kappa * np.sqrt(np.einsum("nk,nk->n", rel, rel)) + lam) * dt > stiff_limit
    if not stiff.any():
        return rk4_step(pos, vel, air, kappa, lam, gravity, dt)
    new_pos, new_vel = np.empty_like(pos), np.empty_like(vel)
    e = ~stiff
    new_pos[e], new_vel[e] = rk4_step(pos[e], vel[e], air[e], kappa[e], lam[e], gravity, dt)
    new_pos[stiff], new_vel[stiff] = exponential_step(pos[stiff], vel[stiff], air[stiff], kappa[stiff], lam[stiff],
                                                      gravity, dt)  # fmt: skip
    return new_pos, new_vel


def integrate(pos, vel, kappa, lam, gravity: float, duration_s: float, dt: float, air=None, samples: int = 0):
    """Trajectories over ``duration_s`` with fixed steps ``dt`` in uniform air ``air`` (3,) m/s.

    Returns the final (pos, vel) and, if ``samples`` > 0, positions at every step (steps+1, n, 3).
    """
    pos = np.array(pos, dtype=np.float64, ndmin=2)
    vel = np.array(vel, dtype=np.float64, ndmin=2)
    n = len(pos)
    kappa = np.broadcast_to(np.asarray(kappa, dtype=np.float64), (n,))
    lam = np.broadcast_to(np.asarray(lam, dtype=np.float64), (n,))
    u = np.zeros((n, 3)) if air is None else np.broadcast_to(np.asarray(air, dtype=np.float64), (n, 3))
    steps = int(round(duration_s / dt))
    track = [pos] if samples else None
    for _ in range(steps):
        pos, vel = step(pos, vel, u, kappa, lam, gravity, dt)
        if samples:
            track.append(pos)
    return (pos, vel, np.stack(track)) if samples else (pos, vel)


def analytic_fall(height_m: float, kappa: float, gravity: float, times_s):
    """Height (m) of a particle released at rest in still air with quadratic drag only:
    z(t) = z0 - v_t^2 / g ln cosh(g t / v_t), v_t = sqrt(g / kappa)."""
    vt = np.sqrt(gravity / kappa)
    return height_m - vt * vt / gravity * np.log(np.cosh(gravity * np.asarray(times_s) / vt))
