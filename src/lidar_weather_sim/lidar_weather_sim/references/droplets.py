"""An independent atmosphere reference: fog, rain and snow simulated drop by drop, apart from the
fast atmosphere region (it imports nothing of ``regions.atmosphere`` or ``regions.near_field``).

Slow and simple on purpose. A clear frame of the simulator gives the scene: for every beam its returns'
range R, peak amplitude A (from the intensity byte, on the profile's log scale) and pulse width: the Gaussian
whose EPW at the clear run's threshold T is the one the clear frame reports (:func:`scene_pulses`).
Then, for each weather (:mod:`lidar_weather_sim.physics`: DSD, Mie, biaxial overlap):

- **Sampled beams** (all of a small profile, else ``beams_per_frame`` drawn at random) get a new waveform
  on a range grid of s/8 (s the pulse's Gaussian sigma), summed from
    * the scene returns, each attenuated by ``exp(-2 alpha R)`` (each Gaussian pulse summed exactly);
    * rain drops / snow flakes placed one by one (Poisson in each grid cell of the beam volume, diameters
      from the DSD) in 0-5 m, and beyond 5 m every drop large enough to reach 5 % of the threshold on its
      own (smaller ones join the volume term);
    * fog droplets placed one by one in 0-5 m where a grid cell holds fewer than 50 of them, else their
      summed cross-section drawn from the compound-Poisson normal limit of the cell (fog in 0-5 m holds
      1e4-1e6 droplets per beam);
    * beyond 5 m the fog (and the small drops) by single-scattering quadrature of
      ``C pi beta(r) O(r) exp(-2 alpha r) / r^2`` per grid cell, convolved with the pulse.
  The drops' peaks are shared between their two nearest grid cells and convolved with the pulse together
  with the volume term (one FFT per block of beams; thin fog puts ~1e3 droplets one by one in a beam).
  A drop of differential backscatter cross-section sigma (m^2/sr) in a beam of cross-section S(r) acts
  as a surface of reflectance ``pi sigma / S(r)``: its peak is ``C pi sigma / (S(r) r^2) exp(-2 alpha r)``
  (C the profile's power constant). Each drop is placed across the beam (a uniform disc, the beam's
  geometric-mean divergence) and counts with the share of its light the receiver takes there
  (:func:`lidar_weather_sim.physics.overlap.point_share` of the profile's ``optics.overlap_model``: ``cone``,
  wholly inside the receiver's field of view, a disc ``lens_separation_m`` off axis, or not at all; ``defocus``,
  the share of the aperture's blur on the field stop): the overlap O(r) comes out drop by drop; the volume
  terms use the model's O(r) (:data:`lidar_weather_sim.physics.overlap.OVERLAP_MODELS`) with the same discs.
  Echoes: runs of the waveform above the threshold ``mu + x sigma`` (under the scenario's sun); range at
  the run's highest sample (parabolic refinement), EPW the length of the run (crossings interpolated
  linearly), at most ``max_echoes`` nearest, none below ``range.min_m``; intensity on the profile's log
  scale. Label: the scene return's (label, object id) when it dominates the waveform at the peak, else
  FOG / RAIN / SNOW. Weather echoes get the profile's range noise.
  Weather behind a beam's nearest scene return is hidden: its drops and volume cells there are left out
  (the return is taken to block the whole beam, as the fast model takes its core sub-ray's hit). Not behind
  a return of the sensor cover (label COVER, 0-0.5 m): the light goes on through the window. Taking those
  as blocking hid the fog from every beam with a dirt return (gap draw case 7: 101 cover returns a frame
  kept apart where the fog's waveform, 2x the threshold already at 0.1 m, merges them into its echo).
- **Other beams** keep their clear returns attenuated by ``exp(-2 alpha R)`` (EPW and intensity lowered,
  returns below the threshold removed), and get no near-field weather.

With a sensor cover (``cover_two_way``: each beam's two-way transmission through it, from the cover region
that made the clear frame) the weather's own returns are lowered by that factor too: the light scattered
back by fog or rain crosses the cover twice, as the scene's light did. Without it a dirty cover in a
pair dimmed only the scene: fog 107 m behind dirt 0.66 then kept its full near-field echo (EPW 14 m, and
behind it 242 far returns a frame where the simulator, which dims it, gives 920), and the gap search
could not name the dirt (gap draw case 7).

With an AC-coupled receiver (``detection.ac_coupling_tau_m`` > 0, :mod:`lidar_weather_sim.sensor.ac_coupling`)
the volume terms (fog with its droplets placed one by one, the small drops) pass its high-pass before the pulse
convolution, undershoot included; the scene's returns and the drops seen one by one keep the profile's pulse,
which is fitted to measured echoes and so is the filtered pulse already.

Limits (documented, not modelled): no multiple scattering, one return mode (``all``), a top-hat beam.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.signal import fftconvolve, lfilter

from lidar_weather_sim.core.points import Label, ReturnType, empty_points
from lidar_weather_sim.scenario.effects import Effect
from lidar_weather_sim.physics.coefficients import Medium, medium
from lidar_weather_sim.physics.overlap import OVERLAP_MODELS, point_share
from lidar_weather_sim.sensor.profile import SensorProfile
from lidar_weather_sim.sensor.radiometry import FWHM_TO_SIGMA, Threshold, dark_level
from lidar_weather_sim.sensor.scan import ScanPattern

NEAR_M = 5.0  # drops of every size one by one out to here (m)
INDIVIDUAL_FRACTION = 0.05  # beyond NEAR_M: drops reaching this share of the threshold on their own
SMALL_PROFILE_BEAMS = 4096  # profiles with at most this many beams per frame: every beam is sampled
DEFAULT_BEAMS_PER_FRAME = 1024  # sampled beams per frame of larger profiles (>= 200)
DIRECT_PER_CELL = 50.0  # fog droplets per grid cell below which they are placed one by one
PULSE_REACH = 5.0  # a pulse is summed out to this many sigmas
CHUNK_BEAMS = 256  # sampled beams per waveform block (memory: 256 x cells x 8 B per array)
_WEATHER_LABEL = {"fog": Label.FOG, "rain": Label.RAIN, "snow": Label.SNOW}
ATMOSPHERE_EFFECTS = ("atmosphere.fog", "atmosphere.rain", "atmosphere.snow")


@dataclass(frozen=True)
class Atmosphere:
    """The weather the reference simulates: fog visual range (m) and/or one precipitation (kind, mm/h)."""

    fog_m: float | None = None
    precipitation: tuple[str, float] | None = None

    @classmethod
    def split(cls, effects: list[Effect]) -> tuple["Atmosphere", list[Effect]]:
        """The atmosphere of ``effects`` (fog, rain, snow) and the other effects (left to the simulator)."""
        fog = next((e.value for e in effects if e.name == "atmosphere.fog"), None)
        precip = next(((e.name.split(".")[1], e.value) for e in effects if e.name in ATMOSPHERE_EFFECTS[1:]), None)
        return cls(fog, precip), [e for e in effects if e.name not in ATMOSPHERE_EFFECTS]

    @property
    def empty(self) -> bool:
        return self.fog_m is None and self.precipitation is None


#: below this ln(A / T) a return's EPW says little of its width (the intensity byte's 1.8 % step in A moves
#: the width by more than 10 %): the profile's pulse is taken
MIN_WIDTH_LOG_RATIO = 0.1


def scene_pulses(points: np.ndarray, threshold: float, sigma_m: float, dark: float,
                 log_span: float) -> tuple[np.ndarray, np.ndarray]:  # fmt: skip
    """(peak amplitude in noise units, Gaussian sigma in m) of the pulse each point's echo is taken to be.

    The peak from the intensity byte (log scale over the dark threshold, :func:`intensity_bytes` inverted), or
    from the EPW as an isolated pulse's (``T exp((EPW / 2s)^2 / 2)``) where the byte is saturated. The sigma
    gives the point's EPW at the threshold ``T``: the profile's ``sigma_m`` for an isolated echo, wider for
    one the simulator summed from sub-rays at slightly different ranges (a vehicle's side). Taking the peak
    from the EPW alone would make such echoes brighter whenever the reference re-drew them: a
    vehicle's returns at intensity 90 would come out at 132 in fog, the largest term of every reference case's gap."""
    amplitude = dark * np.exp(points["intensity"].astype(np.float64) / 255.0 * log_span)
    width = np.full(len(points), sigma_m)
    if "epw" not in (points.dtype.names or ()):
        return amplitude, width
    epw = points["epw"].astype(np.float64)
    isolated = threshold * np.exp(0.5 * (epw / (2.0 * sigma_m)) ** 2)
    amplitude = np.where(points["intensity"] >= 255, np.maximum(amplitude, isolated), amplitude)
    log_ratio = np.log(np.maximum(amplitude / threshold, 1.0))
    wide = log_ratio > MIN_WIDTH_LOG_RATIO
    width[wide] = np.maximum(epw[wide] / (2.0 * np.sqrt(2.0 * log_ratio[wide])), sigma_m)
    return amplitude, width


def intensity_bytes(amplitude: np.ndarray, dark: float, log_span: float) -> np.ndarray:
    """Intensity 0-255: 255 ln(A / dark) / ln(dynamic range), rounded and clipped (the profile's scale)."""
    return np.clip(np.rint(255.0 * np.log(np.maximum(amplitude, 1e-300) / dark) / log_span), 0, 255).astype(np.uint8)


def epw_of(amplitude: np.ndarray, threshold: float, sigma_m: float | np.ndarray) -> np.ndarray:
    """EPW (m) of an isolated Gaussian pulse of peak ``amplitude`` and sigma ``sigma_m`` over ``threshold``."""
    return 2.0 * sigma_m * np.sqrt(2.0 * np.log(np.maximum(amplitude / threshold, 1.0)))


class ReferenceAtmosphere:
    """The reference for one profile, weather and receiver threshold; :meth:`apply` turns a clear frame's
    points (with ground truth) into the frame in that weather."""

    def __init__(self, profile: SensorProfile, atmosphere: Atmosphere, *, sun_irradiance_w_m2: float = 0.0,
                 beams_per_frame: int | None = None, cover_two_way: np.ndarray | None = None) -> None:  # fmt: skip
        """``cover_two_way``: (columns, channels) two-way transmission of each beam through the sensor cover
        (:meth:`lidar_weather_sim.regions.cover.CoverRegion.beam_two_way`); None: no cover."""
        o = profile.optics
        if o.wavelength_nm is None or o.lens_separation_m is None or o.receiver_fov_mrad is None:
            raise ValueError(f"profile {profile.name!r} has no optics.wavelength_nm / lens_separation_m / "
                             "receiver_fov_mrad: the atmosphere reference needs them (see config/sensors/scala4.yaml)")  # fmt: skip
        self.profile = profile
        self.atmosphere = atmosphere
        self.scan = ScanPattern(profile)
        if cover_two_way is not None and cover_two_way.shape != (self.scan.n_columns, self.scan.n_channels):
            raise ValueError(f"cover_two_way has shape {cover_two_way.shape}, the scan pattern "
                             f"({self.scan.n_columns}, {self.scan.n_channels})")  # fmt: skip
        self.cover = cover_two_way
        self.threshold = Threshold.under_sun(profile.detection, sun_irradiance_w_m2).level
        self.dark = dark_level(profile.detection)
        self.log_span = float(np.log(profile.detection.intensity_dynamic_range))
        self.power = profile.detection.power_constant
        self.sigma = profile.pulse.fwhm_m * FWHM_TO_SIGMA
        self.dx = self.sigma / 8.0
        self.n_cells = int(np.ceil(profile.range.max_m / self.dx)) + 1
        self.r = (np.arange(self.n_cells) + 0.5) * self.dx  # cell centres (m)
        self.divergence = 1e-3 * float(np.sqrt(o.divergence_h_mrad * o.divergence_v_mrad))
        self.fov = 1e-3 * o.receiver_fov_mrad
        self.separation = o.lens_separation_m
        self.tx_radius, self.rx_radius = o.tx_aperture_radius_m, o.rx_aperture_radius_m
        self.beam_radius = self.tx_radius + self.r * np.tan(0.5 * self.divergence)  # (K,) m
        self.overlap_model = o.overlap_model
        self.overlap = OVERLAP_MODELS[o.overlap_model](self.r, self.separation, self.divergence, self.fov,
                                                       self.tx_radius, self.rx_radius)  # fmt: skip
        self.media: list[Medium] = []
        if atmosphere.fog_m is not None:
            self.media.append(medium("fog", float(atmosphere.fog_m), float(o.wavelength_nm)))
        if atmosphere.precipitation is not None:
            kind, rate = atmosphere.precipitation
            self.media.append(medium(kind, float(rate), float(o.wavelength_nm)))
        self.alpha = float(sum(m.alpha for m in self.media))
        self.transmission = np.exp(-2.0 * self.alpha * self.r)  # two-way, (K,)
        self.n_beams_all = self.scan.n_columns * max(len(c) for c in self.scan._channels)
        self.beams_per_frame = beams_per_frame or (self.n_beams_all if self.n_beams_all <= SMALL_PROFILE_BEAMS
                                                   else DEFAULT_BEAMS_PER_FRAME)  # fmt: skip
        k = np.arange(-int(PULSE_REACH * 8), int(PULSE_REACH * 8) + 1)
        self.kernel = np.exp(-0.5 * (k * self.dx / self.sigma) ** 2)  # the pulse on the grid, peak 1

    # --- geometry ---------------------------------------------------------------------------------
    def column_of(self, points: np.ndarray) -> np.ndarray:
        """Firing column of each point (from its azimuth less its channel's azimuth offset)."""
        scan = self.profile.scan
        lo = np.deg2rad(scan.azimuth_min_deg)
        step = (np.deg2rad(scan.azimuth_max_deg) - lo) / scan.columns
        az = points["azimuth"].astype(np.float64) - self.scan.azimuth_offset[points["channel"].astype(np.int64)]
        az = lo + np.mod(az - lo + 0.5 * step, 2.0 * np.pi) - 0.5 * step
        k = np.clip(np.floor((az - lo) / step).astype(np.int64), 0, scan.columns - 1)
        return scan.columns - 1 - k if scan.direction == "cw" else k

    def drop_amplitude(self, sigma_back: np.ndarray, r: np.ndarray) -> np.ndarray:
        """Peak (noise units) of a drop of differential backscatter ``sigma_back`` (m^2/sr) at ``r`` (m) in full
        view, without extinction: C pi sigma / (S(r) r^2), S the beam's cross-section."""
        radius = self.tx_radius + r * np.tan(0.5 * self.divergence)
        return self.power * np.pi * sigma_back / (np.pi * radius**2) / np.maximum(r, 0.05) ** 2

    # --- the frame --------------------------------------------------------------------------------
    def apply(self, points: np.ndarray, frame_index: int, rng: np.random.Generator) -> np.ndarray:
        """The clear frame ``points`` (project layout with ground truth) in the reference's weather."""
        if self.atmosphere.empty:
            return points.copy()
        channels = self.scan.active_channels(frame_index)
        n_col = self.scan.n_columns
        n_beams = len(channels) * n_col
        chan_pos = np.full(self.scan.n_channels, -1, np.int64)
        chan_pos[channels] = np.arange(len(channels))
        beam_of_point = chan_pos[points["channel"].astype(np.int64)] * n_col + self.column_of(points)
        if len(points) and beam_of_point.min() < 0:
            raise ValueError("a point's channel is not active in this frame: frame index and points disagree")
        sampled = (np.arange(n_beams) if self.beams_per_frame >= n_beams
                   else np.sort(rng.choice(n_beams, self.beams_per_frame, replace=False)))  # fmt: skip
        in_sample = np.isin(beam_of_point, sampled)
        out = [self._attenuate(points[~in_sample])]
        out.append(self._waveform_beams(points[in_sample], beam_of_point[in_sample], sampled, channels, rng))
        return np.concatenate(out)

    def _attenuate(self, pts: np.ndarray) -> np.ndarray:
        """Clear returns of unsampled beams with exp(-2 alpha R): lower peak, EPW and intensity; lost below T."""
        a, width = scene_pulses(pts, self.threshold, self.sigma, self.dark, self.log_span)
        a = a * np.exp(-2.0 * self.alpha * pts["distance"].astype(np.float64))
        keep = a > self.threshold
        out = pts[keep].copy()
        if "epw" in (out.dtype.names or ()):
            out["epw"] = epw_of(a[keep], self.threshold, width[keep])
        out["intensity"] = intensity_bytes(a[keep], self.dark, self.log_span)
        return out

    def _particles(self, n_beams: int, rng: np.random.Generator):
        """Scatterers of ``n_beams`` beams, per weather label: {label: (beam, range m, peak, volume)}, with the
        drops one by one (beam index, range, peak amplitude with extinction) and the volume term per cell
        (n_beams, K), peak-amplitude units before the pulse convolution, extinction and overlap included."""
        K = self.n_cells
        near = int(np.ceil(NEAR_M / self.dx))
        cell_volume = np.pi * self.beam_radius**2 * self.dx  # m^3 (K,)
        scale = self.power * np.pi / np.maximum(self.r, 0.05) ** 2 * self.transmission
        out = {}
        for m in self.media:
            label = int(_WEATHER_LABEL[m.kind])
            volume = np.zeros((n_beams, K))
            drops: list[tuple[np.ndarray, np.ndarray, np.ndarray]] = []
            lam = m.number * cell_volume[:near]  # particles per cell in 0-5 m (near,)
            if m.kind == "fog":
                # 0-5 m: droplets one by one where few, else the cell's summed cross-section (compound Poisson,
                # normal limit: mean lam E[sigma], variance lam E[sigma^2])
                f2 = m.density * m.sigma_back**2
                mean_s = m.beta / m.number
                mean_s2 = float(np.sum(0.5 * (f2[1:] + f2[:-1]) * np.diff(m.diameters))) / m.number
                direct = lam < DIRECT_PER_CELL
                if direct.any():
                    drops.append(self._place(rng.poisson(np.broadcast_to(lam * direct, (n_beams, near))), m, rng))
                bulk = np.nonzero(~direct)[0]
                z = rng.standard_normal((n_beams, len(bulk)))
                summed = np.maximum(lam[bulk] * mean_s + np.sqrt(lam[bulk] * mean_s2) * z, 0.0)  # m^2/sr per cell
                # the receiver views the share O(r) of the cell's droplets
                volume[:, bulk] = summed / cell_volume[bulk] * self.dx * self.overlap[bulk]
                volume[:, near:] = m.beta * self.dx * self.overlap[near:]  # single-scattering quadrature
            else:
                drops.append(self._place(rng.poisson(np.broadcast_to(lam, (n_beams, near))), m, rng))
                # beyond 5 m: drops reaching INDIVIDUAL_FRACTION of the threshold one by one, the rest as volume
                r = self.r[near:]
                per_sigma = self.drop_amplitude(np.ones_like(r), r) * self.transmission[near:]
                sigma_min = INDIVIDUAL_FRACTION * self.threshold / np.maximum(per_sigma, 1e-300)
                per_d2 = float(np.median(m.sigma_back / np.maximum(m.diameters, 1e-12) ** 2))  # geometric: constant
                d_min = np.sqrt(sigma_min / per_d2)  # distribution diameter
                lam_far = m.number_above(d_min) * cell_volume[near:]
                drops.append(self._place(rng.poisson(np.broadcast_to(lam_far, (n_beams, K - near))), m, rng,
                                         first=near, d_lo=d_min))  # fmt: skip
                volume[:, near:] = m.beta_below(d_min) * self.dx * self.overlap[near:]
            if drops:
                beam, r_d, a_d = (np.concatenate(x) for x in zip(*drops))
            else:  # dense fog on a wide beam: every near-field cell holds enough droplets to be bulk
                beam, r_d, a_d = np.zeros(0, np.int64), np.zeros(0), np.zeros(0)
            out[label] = (beam, r_d, a_d, volume * scale)
        return out

    def _place(self, counts, m: Medium, rng, first: int = 0, d_lo=None):
        """Drops of ``counts`` (beams, cells from ``first``): range uniform in the cell, position uniform on the
        beam's disc, kept if inside the receiver's disc; diameters from the DSD (above ``d_lo`` per cell).
        Returns (beam, range m, peak amplitude with extinction)."""
        b, c = np.nonzero(counts)
        n = counts[b, c]
        b, c = np.repeat(b, n), np.repeat(c, n) + first
        r = (c + rng.random(len(c))) * self.dx
        radius = self.tx_radius + r * np.tan(0.5 * self.divergence)
        rho = radius * np.sqrt(rng.random(len(r)))
        phi = 2.0 * np.pi * rng.random(len(r))
        share = point_share(self.overlap_model, np.hypot(rho * np.cos(phi) - self.separation, rho * np.sin(phi)), r,
                            self.fov, self.rx_radius)  # fmt: skip
        seen = share > 0
        lo = None if d_lo is None else d_lo[c[seen] - first]
        _, sigma = m.sample(int(seen.sum()), rng, lo)
        r = r[seen]
        return b[seen], r, self.drop_amplitude(sigma, r) * share[seen] * np.exp(-2.0 * self.alpha * r)

    def _waveform_beams(self, pts, beam_of_point, sampled, channels, rng) -> np.ndarray:
        """Echoes of the sampled beams (chunks of CHUNK_BEAMS, to bound memory)."""
        pos = np.searchsorted(sampled, beam_of_point)
        out = [empty_points(0, ground_truth=True)]
        for c0 in range(0, len(sampled), CHUNK_BEAMS):
            c1 = min(c0 + CHUNK_BEAMS, len(sampled))
            inside = (pos >= c0) & (pos < c1)
            out.append(self._chunk(pts[inside], pos[inside] - c0, sampled[c0:c1], channels, rng))
        return np.concatenate(out)

    def _chunk(self, pts, pos, sampled, channels, rng) -> np.ndarray:
        n, K = len(sampled), self.n_cells
        scene_r = pts["distance"].astype(np.float64)
        scene_a, scene_w = scene_pulses(pts, self.threshold, self.sigma, self.dark, self.log_span)
        scene_a = scene_a * np.exp(-2.0 * self.alpha * scene_r)
        scene = self._pulses(pos, scene_r, scene_a, scene_w, n)
        hit = np.full(n, np.inf)  # the beam's nearest scene return: the weather behind it is hidden
        blocks = pts["label"] != Label.COVER  # the cover's own returns: the beam goes on through the window
        np.minimum.at(hit, pos[blocks], scene_r[blocks])
        in_front = self.r[None, :] < hit[:, None]
        cover = 1.0
        if self.cover is not None:  # the weather's light crosses the cover twice, as the scene's did
            cover = self.cover[sampled % self.scan.n_columns, channels[sampled // self.scan.n_columns]][:, None]
        parts = {}
        for lab, (b, r, a, vol) in self._particles(n, rng).items():
            seen = r < hit[b]
            volume, drops = np.where(in_front, vol, 0.0), self._deposit(b[seen], r[seen], a[seen], n)
            if lab == Label.FOG:  # fog's droplets are a volume, one by one or not
                volume, drops = volume + drops, 0.0
            parts[lab] = cover * fftconvolve(self._ac_coupled(volume) + drops, self.kernel[None, :], mode="same",
                                             axes=1)  # fmt: skip
        wave = scene + sum(parts.values())
        # echoes: runs above the threshold, nearest max_echoes per beam
        above = wave > self.threshold
        edges = np.diff(np.pad(above.astype(np.int8), ((0, 0), (1, 1))), axis=1)
        sb, sk = np.nonzero(edges == 1)  # row-major: by beam, then by range
        _, ek = np.nonzero(edges == -1)  # exclusive ends, same order
        rank = np.arange(len(sb)) - np.searchsorted(sb, sb, side="left")
        keep = rank < self.profile.detection.max_echoes
        sb, sk, ek = sb[keep], sk[keep], ek[keep]
        if not len(sb):
            return empty_points(0, ground_truth=True)
        peak_k = np.array([sk[i] + int(np.argmax(wave[sb[i], sk[i]:ek[i]])) for i in range(len(sb))], np.int64)
        amp = wave[sb, peak_k]
        w_lo = np.where(peak_k > 0, wave[sb, np.maximum(peak_k - 1, 0)], amp)
        w_hi = np.where(peak_k < K - 1, wave[sb, np.minimum(peak_k + 1, K - 1)], amp)
        den = w_lo - 2.0 * amp + w_hi
        shift = np.where(den < 0, 0.5 * (w_lo - w_hi) / np.where(den < 0, den, -1.0), 0.0)
        r_peak = self.r[peak_k] + np.clip(shift, -0.5, 0.5) * self.dx

        def crossing(k_in, k_out):  # range where the waveform crosses the threshold between two cells
            w_in, w_out = wave[sb, k_in], wave[sb, k_out]
            frac = (w_in - self.threshold) / np.where(w_in != w_out, w_in - w_out, 1.0)
            return self.r[k_in] + (self.r[k_out] - self.r[k_in]) * frac

        start = np.where(sk > 0, crossing(sk, np.maximum(sk - 1, 0)), 0.0)
        end = np.where(ek < K, crossing(ek - 1, np.minimum(ek, K - 1)), self.r[-1])
        epw = end - start
        # who dominates the waveform at the peak: a scene return or one weather
        labels = np.array(list(parts), np.uint8)
        weather_val = np.stack([parts[lab][sb, peak_k] for lab in parts], axis=0)
        weather_label = labels[np.argmax(weather_val, axis=0)]
        is_scene = scene[sb, peak_k] >= weather_val.max(axis=0)
        src = np.full(len(sb), -1, np.int64)  # the clear return behind a scene echo: the beam's nearest in range
        if len(pts):
            order = np.lexsort((scene_r, pos))
            pos_sorted = pos[order]
            for i in np.nonzero(is_scene)[0]:
                cand = order[np.searchsorted(pos_sorted, sb[i]):np.searchsorted(pos_sorted, sb[i], side="right")]
                if len(cand):
                    src[i] = cand[np.argmin(np.abs(scene_r[cand] - r_peak[i]))]
        is_scene &= src >= 0
        valid = r_peak >= self.profile.range.min_m
        sel = np.nonzero(valid)[0]
        sb, r_out, is_scene, src = sb[sel], r_peak[sel].copy(), is_scene[sel], src[sel]
        out = empty_points(len(sel), ground_truth=True)
        b_glob = sampled[sb]
        ch = channels[b_glob // self.scan.n_columns]
        col = b_glob % self.scan.n_columns
        weather = ~is_scene
        noise = self.profile.range.noise_sigma_m
        if noise > 0:
            r_out[weather] = np.maximum(r_out[weather] + rng.normal(0.0, noise, int(weather.sum())), 1e-3)
        az = self.scan.column_azimuth[col] + self.scan.azimuth_offset[ch]
        el = self.scan.elevation[ch]
        direction = np.stack([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)], axis=1)
        time_ns = np.rint(self.scan.column_time_s[col] * 1e9).astype(np.uint32)
        label = weather_label[sel].copy()
        obj = np.zeros(len(sel), np.uint32)
        rows = np.nonzero(is_scene)[0]
        if len(rows):  # a scene echo keeps its clear return's direction, time, label and object
            p = pts[src[rows]]
            d = np.maximum(p["distance"].astype(np.float64), 1e-9)
            direction[rows] = np.stack([p["x"] / d, p["y"] / d, p["z"] / d], axis=1)
            time_ns[rows] = p["time_stamp"]
            label[rows] = p["label"]
            obj[rows] = p["object_id"]
        xyz = direction * r_out[:, None]
        out["x"], out["y"], out["z"] = xyz[:, 0], xyz[:, 1], xyz[:, 2]
        out["distance"] = r_out
        out["azimuth"] = np.arctan2(xyz[:, 1], xyz[:, 0])
        out["elevation"] = np.arctan2(xyz[:, 2], np.hypot(xyz[:, 0], xyz[:, 1]))
        out["channel"] = ch
        out["time_stamp"] = time_ns
        out["intensity"] = intensity_bytes(amp[sel], self.dark, self.log_span)
        out["epw"] = epw[sel]
        out["label"] = label
        out["object_id"] = obj
        first = np.searchsorted(sb, sb, side="left")  # echo rank among the beam's kept echoes
        last = np.searchsorted(sb, sb, side="right") - 1
        idx = np.arange(len(sb))
        out["echo"] = (idx - first + 1).astype(np.uint8)
        rt = np.where(first == last, ReturnType.IDENTICAL, np.where(
            idx == first, ReturnType.FIRST, np.where(idx == last, ReturnType.LAST, ReturnType.SECOND)))  # fmt: skip
        out["return_type"] = rt.astype(np.uint8)
        return out

    def _ac_coupled(self, density: np.ndarray) -> np.ndarray:
        """(n, K) peaks per cell after the receiver's AC coupling (``detection.ac_coupling_tau_m``; 0: unchanged):
        each cell's amount spread evenly over it, less what the high-pass's exponential tails of it and of the
        cells before it put inside it. The undershoot stays in (negative cells)."""
        tau = self.profile.detection.ac_coupling_tau_m
        if tau <= 0:
            return density
        decay = np.exp(-self.dx / tau)
        own = tau / self.dx * (1.0 - decay)  # share of a cell's amount that leaves it as tail
        tail = lfilter([own], [1.0, -decay], density, axis=1)  # tail mass at each cell's far edge
        before = np.pad(tail[:, :-1], ((0, 0), (1, 0)))
        return density - (1.0 - decay) * before - (1.0 - own) * density

    def _deposit(self, beam: np.ndarray, r: np.ndarray, a: np.ndarray, n: int) -> np.ndarray:
        """(n, K) peaks of drops (beam index, range m, peak) shared linearly between the two nearest cell centres
        (keeps each drop's amplitude and mean range; convolved with the pulse afterwards, this is its Gaussian
        pulse to within dx / sigma = 1/8 of a cell's shift, at a fraction of the cost of summing each pulse)."""
        out = np.zeros(n * self.n_cells)
        if len(beam):
            u = r / self.dx - 0.5
            k0 = np.clip(np.floor(u).astype(np.int64), 0, self.n_cells - 2)
            w1 = np.clip(u - k0, 0.0, 1.0)
            flat = beam * self.n_cells + k0
            out += np.bincount(flat, weights=a * (1.0 - w1), minlength=n * self.n_cells)
            out += np.bincount(flat + 1, weights=a * w1, minlength=n * self.n_cells)
        return out.reshape(n, self.n_cells)

    def _pulses(self, beam: np.ndarray, r: np.ndarray, a: np.ndarray, width: np.ndarray, n: int) -> np.ndarray:
        """(n, K) waveform of Gaussian pulses (beam index, range m, peak, sigma m) summed exactly on the grid."""
        wave = np.zeros(n * self.n_cells)
        if not len(beam):
            return wave.reshape(n, self.n_cells)
        half = int(np.ceil(PULSE_REACH * float(width.max()) / self.dx))
        centre = np.floor(r / self.dx).astype(np.int64)
        offs = np.arange(-half, half + 1)
        k = centre[:, None] + offs[None, :]
        val = a[:, None] * np.exp(-0.5 * ((self.r[np.clip(k, 0, self.n_cells - 1)] - r[:, None]) / width[:, None]) ** 2)
        ok = (k >= 0) & (k < self.n_cells)
        flat = (beam[:, None] * self.n_cells + k)[ok]
        wave += np.bincount(flat, weights=val[ok], minlength=n * self.n_cells)
        return wave.reshape(n, self.n_cells)
