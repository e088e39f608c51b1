"""High-fidelity droplet reference: real-size drops and a per-beam backscatter detection.

Drops
-----
The wheels emit drops with the same emitter (eq. 7-10) and forces as the particle
model, but many more, each with its own diameter (spray_particles.model.drops: lognormal
around eq. 3's D_mean(v_c)) and drag rates (eq. 19, Stokes term). Each computational
drop carries the same volume of water: the airborne share of eq. 2's tread pick-up
over the tick, divided by the drops of the tick; its ``weight`` is the number of real
drops it stands for. Drops die on the
ground, on the body or after ``lifetime_s``. No speed threshold: slow wheels make big
drops that fall at once (eq. 3).

Detection
---------
Per frame, every drop is seen from the sensor at its column's firing time (rolling
shutter). A computational drop stands for ``weight`` real drops spread as a Gaussian
blob of radius ``kernel_radius_m``: it feeds each beam (footprint ``divergence_h`` x
``divergence_v`` around the beam axis) with the share of the blob inside the footprint
(:func:`blob_share`), if the beam's sub-ray nearest to it reaches that far (scene hits per
sub-ray: a drop in a wheel arch is hidden by the tyre even where the beam's centre passes).
Its effective reflectance is the drops' cross-section share of the beam footprint at
that range times the albedo
and the disk-averaged phase factor; drops of one beam within one range cell (the pulse
FWHM) add up. Cells are taken in range order with Beer-Lambert-like shadowing (the
cross-section share of the nearer cells blocks the light, two ways), amplitudes from
the LIDAR equation of the simulator (``C rho / R^2 x T^2 x overlap``), and a cell is
detected when it exceeds the receiver threshold, up to ``max_echoes`` per beam, only
in front of the beam's scene hit and only if its pulse stays a separate echo: with the
scene hit's peak amplitude given, the waveform of the two (Gaussian, the profile's pulse
FWHM) must dip below the threshold between them, else they form one echo, which the
simulator's echo stage labels as the (brighter) target; without it, the cell must lie at
least one FWHM before the hit. Spray hugging the car's side on the proving ground merges.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.special import erf

from lidar_weather_sim.sensor.radiometry import FWHM_TO_SIGMA, overlap_factor
from spray_particles.model.drops import airborne_water_m3, drops_per_volume, volume_weighted_diameters
from spray_particles.model.forces import drag_rates
from spray_particles.model.system import Particles, SpraySystem, drawn_film_mm


class DropletReference(SpraySystem):
    """A :class:`SpraySystem` whose particles are real-size drops (see module docstring)."""

    def _emit(self, rng, tick: int, present, vel, rot, org) -> None:
        prm, c = self.params, self.constants
        ref = c.reference
        parts = [self.particles]
        for k, v in enumerate(self.vehicles):
            if not present[k]:
                continue
            speed = float(np.linalg.norm(vel[k]))
            film = drawn_film_mm(prm, rng)
            water = prm.emission_scale * airborne_water_m3(c, film, speed, prm.tick_s)
            if water <= 0:
                continue
            counts = rng.poisson(ref.drops_per_wheel_per_tick, v.emitter.n_wheels)
            n = int(counts.sum())
            if not n:
                continue
            pos_b, vel_b, side, wheel = v.emitter.emit(rng, counts, speed, prm.tick_s)
            d = volume_weighted_diameters(c, rng, n, speed)
            weight = drops_per_volume(d, water * counts.size / n)  # each drop carries the same water volume
            kappa, lam = drag_rates(d, c.physics.drag_coefficient, c.physics.air_density_kg_m3,
                                    c.physics.water_density_kg_m3, c.physics.air_viscosity_pa_s)  # fmt: skip
            parts.append(Particles(pos_b @ rot[k].T + org[k], vel_b @ rot[k].T + vel[k], np.zeros(n),
                                   np.full(n, ref.lifetime_s), kappa, lam, np.full(n, k, np.int64), side,
                                   np.full(n, 2, np.uint8), wheel, d, weight, np.zeros(n), np.ones(n)))  # fmt: skip
            self.emitted += n
        if len(parts) > 1:
            self.particles = Particles.concatenate(parts)


@dataclass
class ReferenceDetections:
    """Spray detections of one frame: beam (column, channel), range (m), sensor-frame x, y, z (m), amplitude."""

    column: np.ndarray
    channel: np.ndarray
    range_m: np.ndarray
    xyz: np.ndarray
    amplitude: np.ndarray


def detect_frame(reference: DropletReference, pattern, frame_index: int, frame_start_s: float, sensor_poses,
                 scene_distance=None, threshold: float = 4.0, max_echoes: int = 3,
                 scene_amplitude=None) -> ReferenceDetections:  # fmt: skip
    """Spray detections of the reference's drops for one frame of ``pattern`` (a ScanPattern).

    ``sensor_poses(times) -> (translations (N, 3), rotations (N, 3, 3))`` gives the sensor-to-world
    pose at each column time; ``scene_distance`` (columns, channels) m is the range of each beam's
    scene hit (inf: none), or (columns, channels, sub-rays) that of each sub-ray of the pattern: a
    drop then counts in a beam only in front of the hit of the sub-ray nearest to it, and the
    central sub-ray's hit stands for the beam's in the echo rule; the drops must have been advanced
    to the frame's middle.
    ``scene_amplitude`` (columns, channels): the peak amplitude of that hit (the threshold's units;
    None: the FWHM rule).
    """
    profile = pattern.profile
    p = reference.particles
    empty = ReferenceDetections(*(np.zeros(0, np.int64),) * 2, np.zeros(0), np.zeros((0, 3)), np.zeros(0))
    if not len(p):
        return empty
    ref = reference.constants.reference
    albedo = reference.constants.particles.single_scattering_albedo
    t_ref = reference.time_s
    col_t = frame_start_s + pattern.column_time_s
    trans, rots = sensor_poses(col_t)
    az_cols = pattern.column_azimuth
    mid = len(az_cols) // 2
    # column of each drop: azimuth at the frame's middle pose, then at its column's pose
    column = np.full(len(p), mid)
    for _ in range(2):
        dt = col_t[column] - t_ref
        world = p.pos + dt[:, None] * p.vel
        local = np.einsum("nji,nj->ni", rots[column], world - trans[column])
        az = np.arctan2(local[:, 1], local[:, 0])
        column = np.clip(np.searchsorted(-az_cols, -az), 0, len(az_cols) - 1)  # azimuths decrease (cw)
        prev = np.clip(column - 1, 0, len(az_cols) - 1)
        column = np.where(np.abs(az_cols[prev] - az) < np.abs(az_cols[column] - az), prev, column)
    rng_m = np.linalg.norm(local, axis=1)
    el = np.arcsin(np.clip(local[:, 2] / np.maximum(rng_m, 1e-9), -1, 1))
    div_h = max(profile.optics.divergence_h_mrad, 0.01) * 1e-3  # a pencil beam still has a footprint
    div_v = max(profile.optics.divergence_v_mrad, 0.01) * 1e-3
    channels = pattern.active_channels(frame_index)
    elev = pattern.elevation[channels]
    ok = rng_m > 0.05
    column, rng_m, local, az, el = column[ok], rng_m[ok], local[ok], az[ok], el[ok]
    d, w = p.diameter[ok], p.weight[ok]
    # Each computational drop stands for w real drops spread as a Gaussian blob of radius sigma_k:
    # it feeds every beam within 3 sigma (kernel) with the share of the blob inside that beam's
    # footprint (a point-like super-drop next to the sensor would fill a whole beam on its own).
    sigma = ref.kernel_radius_m
    # every beam within the blob's reach: 3 sigma around it, however many columns and channels that spans
    reach = 3.0 * sigma / np.maximum(rng_m, 1e-3)  # angular reach of the blob (rad)
    drop, cols, chs, da = _beams_in_reach(az, el, reach, az_cols, elev, div_h, div_v)
    de = el[drop] - elev[chs]
    r3 = rng_m[drop]
    dist = np.hypot(np.maximum(np.abs(da) - 0.5 * div_h, 0.0), np.maximum(np.abs(de) - 0.5 * div_v, 0.0)) * r3
    footprint = div_h * div_v * rng_m * rng_m
    frac = blob_share(da * r3, de * r3, div_h * r3, div_v * r3, sigma)
    valid = dist < 3.0 * sigma
    hit_distance = scene_distance
    if scene_distance is not None and np.ndim(scene_distance) == 3:
        # per sub-ray scene hits: the drop is seen by the sub-ray nearest to it in angle, so a drop behind
        # a tyre is not seen by a beam whose upper sub-rays pass over the bonnet
        sub = np.argmin((da[:, None] - pattern.subray_dh) ** 2 + (de[:, None] - pattern.subray_dv) ** 2, axis=-1)
        valid &= r3 < scene_distance[cols, chs, sub]
        hit_distance = scene_distance[:, :, pattern.n_subrays // 2]  # the central sub-ray's hit: echo merging
    elif scene_distance is not None:
        valid &= r3 < scene_distance[cols, chs]
    if not valid.any():
        return empty
    drop, column, ch_pos, frac = drop[valid], cols[valid], chs[valid], frac[valid]
    rng_m, local = rng_m[drop], local[drop]
    share = w[drop] * (np.pi / 4.0 * d[drop] ** 2) * frac / footprint[drop]  # cross-section share of the footprint
    cell = np.floor(rng_m / ref.range_cell_m).astype(np.int64)
    beam = column * len(channels) + ch_pos
    key = beam * 100000 + cell
    order = np.argsort(key, kind="stable")
    key, share_s, rng_s = key[order], share[order], rng_m[order]
    uniq, start = np.unique(key, return_index=True)
    cell_share = np.add.reduceat(share_s, start)
    cell_range = np.add.reduceat(share_s * rng_s, start) / cell_share
    cell_xyz = np.stack([np.add.reduceat(share_s * local[order][:, k], start) / cell_share for k in range(3)], 1)
    cell_beam = uniq // 100000
    # two-way shadowing by the nearer cells of the same beam
    first = np.ones(len(uniq), bool)
    first[1:] = cell_beam[1:] != cell_beam[:-1]
    tau = np.minimum(cell_share, 50.0)
    cum = np.cumsum(tau)
    base = np.maximum.accumulate(np.where(first, np.arange(len(uniq)), 0))
    before = cum - tau - (cum[base] - tau[base])
    reflect = albedo * reference.constants.particles.backscatter_phase * (1.0 - np.exp(-tau))  # saturates at a full footprint
    amp = profile.detection.power_constant * reflect / cell_range**2 * np.exp(-2.0 * before)
    amp *= overlap_factor(cell_range, profile.optics.overlap_start_m, profile.optics.overlap_full_m)
    det = amp > threshold
    if scene_distance is not None:  # a separate echo from the beam's scene hit?
        b = cell_beam[det]
        hit_range = hit_distance.reshape(-1)[b]
        hit_amp = None if scene_amplitude is None else scene_amplitude.reshape(-1)[b]
        det[det] = _separate(cell_range[det], amp[det], hit_range, hit_amp, threshold, profile.pulse.fwhm_m)
    # at most max_echoes per beam, nearest first
    rank = np.cumsum(det) - 1
    rank_base = np.maximum.accumulate(np.where(first, np.arange(len(uniq)), 0))
    rank = rank - np.where(rank_base > 0, np.cumsum(det)[rank_base - 1] * (rank_base > 0), 0)
    det &= rank < max_echoes
    b = cell_beam[det]
    return ReferenceDetections(b // len(channels), channels[b % len(channels)], cell_range[det], cell_xyz[det], amp[det])


def _beams_in_reach(az, el, reach, az_cols, elev, div_h: float, div_v: float):
    """Every (drop, beam) pair whose footprint may lie within ``reach`` (rad, per drop) of the drop at azimuth
    ``az`` and elevation ``el`` (rad): the columns of ``az_cols`` (monotone, rad) within reach + div_h / 2 of
    it in arc (azimuth difference times cos(el); across +-pi too), the channels of ``elev`` (rad) within reach +
    div_v / 2. Returns (drop index, column, channel position, azimuth offset times cos(el) (rad)) per pair."""
    arc = np.maximum(np.cos(el), 1e-6)
    w_az = (reach + 0.5 * div_h) / arc
    w_el = reach + 0.5 * div_v
    order = np.argsort(elev, kind="stable")
    e_lo = np.searchsorted(elev[order], el - w_el, side="left")
    e_hi = np.searchsorted(elev[order], el + w_el, side="right")
    ascending = len(az_cols) < 2 or az_cols[-1] > az_cols[0]
    key = az_cols if ascending else -az_cols
    parts = []
    for shift in (0.0, -2.0 * np.pi, 2.0 * np.pi):  # a window across +-pi on a sensor that looks all round
        a = az + shift
        lo, hi = (a - w_az, a + w_az) if ascending else (-(a + w_az), -(a - w_az))
        c_lo = np.searchsorted(key, lo, side="left")
        c_hi = np.searchsorted(key, hi, side="right")
        n_c, n_e = np.maximum(c_hi - c_lo, 0), np.maximum(e_hi - e_lo, 0)
        count = n_c * n_e
        drop = np.repeat(np.arange(len(az)), count)
        k = np.arange(len(drop)) - np.repeat(np.cumsum(count) - count, count)
        col = c_lo[drop] + k // n_e[drop]
        parts.append((drop, col, order[e_lo[drop] + k % n_e[drop]], (a[drop] - az_cols[col]) * arc[drop]))
    return tuple(np.concatenate(x) for x in zip(*parts))


def blob_share(dx, dy, width, height, sigma: float):
    """Share of a round Gaussian blob (std ``sigma`` m) inside a ``width`` x ``height`` m rectangle whose centre
    lies ``dx``, ``dy`` m from the blob's centre: the product of the Gaussian's integrals over the two sides
    (shares over rectangles that tile the plane sum to 1)."""
    s = np.sqrt(2.0) * sigma
    return 0.25 * (erf((dx + 0.5 * width) / s) - erf((dx - 0.5 * width) / s)) * \
        (erf((dy + 0.5 * height) / s) - erf((dy - 0.5 * height) / s))


def _separate(cell_range, cell_amp, hit_range, hit_amp, threshold: float, fwhm_m: float) -> np.ndarray:
    """Whether each spray cell's pulse (range m, peak amplitude) forms an echo of its own before the
    scene hit's pulse: the sum of the two Gaussian pulses dips below ``threshold`` between them (with
    ``hit_amp`` None: the cell lies at least one FWHM before the hit)."""
    gap = hit_range - cell_range
    if hit_amp is None:
        return gap >= fwhm_m
    out = ~np.isfinite(gap)  # no scene hit: nothing to merge with
    k = ~out
    sigma = fwhm_m * FWHM_TO_SIGMA
    x = np.linspace(0.0, 1.0, 33)[None, :] * gap[k, None]  # from the cell towards the hit (m)
    wave = cell_amp[k, None] * np.exp(-0.5 * (x / sigma) ** 2)
    wave += hit_amp[k, None] * np.exp(-0.5 * ((gap[k, None] - x) / sigma) ** 2)
    out[k] = wave.min(axis=1) < threshold
    return out
