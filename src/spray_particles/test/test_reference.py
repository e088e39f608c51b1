"""Droplet reference: drop sizes (eq. 3), water volume (eq. 2), per-beam backscatter detection; metrics."""

import numpy as np
import pytest

from lidar_weather_sim.sensor.scan import ScanPattern
from lidar_weather_sim.testing.fixtures import simple_profile
from spray_particles.model.constants import load_constants
from spray_particles.model.emitter import vehicle_emitter
from spray_particles.validation.metrics import bev_histogram, compare_histograms, per_frame_overlap
from spray_particles.validation.reference import DropletReference, blob_share, detect_frame
from spray_particles.model.system import EmittingVehicle, Particles, SprayParams
from spray_particles.model.water import mean_drop_diameter_m, tread_pickup_m3_s, tyre_dimensions

C = load_constants()


def _reference(speed=15.0, **params):
    r, w = tyre_dimensions(C.tyre.size)
    vehicle = EmittingVehicle(100, 4.7, 1.85, 1.45, 0.15, vehicle_emitter(4.7, 1.85, 1.45, r, w))

    def poses(t):
        m = np.eye(4)
        m[0, 3] = speed * t
        return {100: m}

    return DropletReference([vehicle], poses, SprayParams(**{"water_film_mm": 0.5, **params}), C)


def test_drop_sizes_follow_eq3_and_carry_eq2_water():
    ref = _reference(15.0)
    ref.advance_to(0.0)
    ref.advance_to(0.01)  # one tick of emission, no flight yet
    p = ref.particles
    assert len(p) > 1000
    # number-weighted median of the real drops = eq. 3 mean diameter (clipping aside)
    order = np.argsort(p.diameter)
    cum = np.cumsum(p.weight[order]) / p.weight.sum()
    median = p.diameter[order][np.searchsorted(cum, 0.5)]
    d_eq3 = mean_drop_diameter_m(15.0, C.tyre.tread_height_m, C.water.drop_size_k)
    assert median == pytest.approx(d_eq3, rel=0.15)
    water = np.sum(p.weight * np.pi / 6 * p.diameter**3)
    expected = C.drops.airborne_fraction * 4 * tread_pickup_m3_s(0.5, 15.0, C.tyre.grooves, C.tyre.groove_width_m,
                                                                     C.tyre.tread_height_m) * 0.01  # fmt: skip
    assert water == pytest.approx(expected, rel=1e-6)
    # each drop has the drag of its own size: small drops have larger drag rates
    assert np.corrcoef(np.log(p.diameter), np.log(p.kappa))[0, 1] < -0.99


def _frame_with_drops(n_drops: int, weight: float, distance: float = 10.0, wall_m=None,
                      wall_amplitude: float | None = None, height_m: float = 0.0, subrays_v: int = 1):  # fmt: skip
    """Detections of a drop cloud on the x axis before a wall: ``wall_m`` a number (every beam) or a
    function of the pattern giving the wall's range per column, channel and sub-ray."""
    profile = simple_profile(optics__divergence_h_mrad=1.75, optics__divergence_v_mrad=2.0, optics__subrays_v=subrays_v)
    pattern = ScanPattern(profile)
    ref = _reference()
    rng = np.random.default_rng(0)
    pos = np.stack([distance + rng.uniform(-0.1, 0.1, n_drops), rng.uniform(-1e-4, 1e-4, n_drops),
                    height_m + rng.uniform(-1e-4, 1e-4, n_drops)], 1)  # fmt: skip
    n = n_drops
    ref.particles = Particles(pos, np.zeros((n, 3)), np.zeros(n), np.full(n, 9.0), np.zeros(n), np.zeros(n),
                              np.zeros(n, np.int64), np.ones(n), np.full(n, 2, np.uint8), np.zeros(n, np.int64),
                              np.full(n, 2e-4), np.full(n, weight), np.zeros(n), np.ones(n))  # fmt: skip
    ref.tick_index = 0

    def poses(times):
        return np.zeros((len(times), 3)), np.tile(np.eye(3), (len(times), 1, 1))

    shape = (len(pattern.column_azimuth), len(pattern.active_channels(0)))
    scene = wall_m(pattern) if callable(wall_m) else None if wall_m is None else np.full(shape, wall_m)
    amplitude = None if wall_amplitude is None else np.full(shape, wall_amplitude)
    return detect_frame(ref, pattern, 0, 0.0, poses, scene, threshold=4.0, scene_amplitude=amplitude)


def test_backscatter_summed_over_the_beam_volume_decides_detection():
    dense = _frame_with_drops(1000, 50.0)
    sparse = _frame_with_drops(1000, 0.01)
    assert len(sparse.range_m) == 0
    assert len(dense.range_m) >= 1 and dense.range_m == pytest.approx(np.full(len(dense.range_m), 10.0), abs=0.1)
    peak = np.argmax(dense.amplitude)
    assert dense.column[peak] == 40  # the 0 deg column of the test profile: the blob's centre
    assert set(np.abs(dense.column - 40)) <= set(range(4))  # the blob (0.1 m) reaches neighbouring beams


def test_drops_within_a_pulse_of_the_scene_hit_merge_into_its_echo():
    """A drop cloud 0.3 m before a wall forms one echo with it (labelled wall by the echo stage), 2 m before
    it a spray echo of its own; behind the wall nothing (pulse FWHM of the test profile: 0.6 m)."""
    assert len(_frame_with_drops(1000, 50.0, wall_m=12.0).range_m) >= 1
    assert len(_frame_with_drops(1000, 50.0, wall_m=10.3).range_m) == 0
    assert len(_frame_with_drops(1000, 50.0, wall_m=9.0).range_m) == 0


def test_a_bright_target_swallows_spray_its_pulse_overlaps():
    """With the wall's amplitude: 1 m before a wall 10^4 x the threshold the drops' pulse stays above the
    threshold into the wall's (one echo: the wall's); 1 m before a dim wall (1.5 x) it is an echo of its own."""
    assert len(_frame_with_drops(1000, 50.0, wall_m=11.0, wall_amplitude=4e4).range_m) == 0
    assert len(_frame_with_drops(1000, 50.0, wall_m=11.0, wall_amplitude=6.0).range_m) >= 1


def test_blob_share_conserves_the_blob():
    """Footprints that tile the plane share a blob out exactly; one much larger than the blob holds all of it,
    one much smaller its area times the peak density (the old rule gave peak density to a whole footprint
    next to the blob: ~1 + 0.056 R times the drops' cross-section in a beam at R m)."""
    sigma, w, h = 0.1, 0.03, 0.05
    dx, dy = np.meshgrid(np.arange(-40, 41) * w + 0.013, np.arange(-25, 26) * h - 0.007)
    assert blob_share(dx, dy, w, h, sigma).sum() == pytest.approx(1.0, abs=1e-9)
    assert blob_share(0.05, 0.0, 2.0, 2.0, sigma) == pytest.approx(1.0, abs=1e-9)
    tiny = blob_share(0.1, 0.0, 1e-3, 1e-3, sigma)
    assert tiny == pytest.approx(1e-6 / (2 * np.pi * sigma**2) * np.exp(-0.5), rel=1e-3)


def test_a_drop_is_seen_only_if_its_nearest_sub_ray_reaches_it():
    """Beams of three sub-rays (divergence 2 mrad: offsets -1.33, 0, +1.33 mrad): a wall at 5 m in front of the
    lower sub-ray only (a tyre below the bonnet's edge) hides drops at 10 m on that sub-ray's line, not drops
    on the central one; with the beam's central hit at 5 m neither is seen."""

    def lower_blocked(pattern):
        shape = (len(pattern.column_azimuth), len(pattern.active_channels(0)), pattern.n_subrays)
        scene = np.full(shape, np.inf)
        scene[:, :, np.argmin(pattern.subray_dv)] = 5.0
        return scene

    low = 10.0 * np.tan(-1.33e-3)
    assert len(_frame_with_drops(1000, 50.0, wall_m=lower_blocked, height_m=low, subrays_v=3).range_m) == 0
    assert len(_frame_with_drops(1000, 50.0, wall_m=lower_blocked, subrays_v=3).range_m) >= 1
    assert len(_frame_with_drops(1000, 50.0, wall_m=5.0, subrays_v=3).range_m) == 0


def _beam_amplitudes_by_quadrature(profile, pattern, drop, weight, diameter, sigma):
    """The reference's blob model from first principles, beam by beam: the Gaussian blob (std ``sigma`` m, cut
    at 3 sigma from the footprint) integrated over each beam's footprint on a 32 x 32 grid, its drops'
    cross-section share of the footprint, the peak amplitude of the LIDAR equation. {(column, channel): peak}."""
    r = float(np.linalg.norm(drop))
    az, el = np.arctan2(drop[1], drop[0]), np.arcsin(drop[2] / r)
    div_h, div_v = profile.optics.divergence_h_mrad * 1e-3, profile.optics.divergence_v_mrad * 1e-3
    w, h = div_h * r, div_v * r
    grid = (np.arange(32) + 0.5) / 32 - 0.5
    out = {}
    for col, beam_az in enumerate(pattern.column_azimuth):
        for ch in pattern.active_channels(0):
            d_az = (beam_az - az + np.pi) % (2 * np.pi) - np.pi
            cx, cy = d_az * np.cos(el) * r, (pattern.elevation[ch] - el) * r  # footprint centre (m)
            gap = np.hypot(max(abs(cx) - w / 2, 0.0), max(abs(cy) - h / 2, 0.0))
            if gap >= 3.0 * sigma:
                continue
            x, y = np.meshgrid(cx + grid * w, cy + grid * h)
            inside = np.exp(-0.5 * (x**2 + y**2) / sigma**2).mean() * w * h / (2 * np.pi * sigma**2)
            share = weight * np.pi / 4 * diameter**2 * inside / (w * h)
            reflectance = C.particles.single_scattering_albedo * C.particles.backscatter_phase * -np.expm1(-share)
            out[(col, int(ch))] = profile.detection.power_constant * reflectance / r**2
    return out


@pytest.mark.parametrize("drop, all_round", [((1.0, 0.02, 0.01), False), ((0.4, -0.03, 0.02), False),
                                             ((3.0, 0.1, -0.05), False), ((-1.0, 0.004, 0.01), True)])
def test_a_near_blob_feeds_every_beam_within_its_reach(drop, all_round):
    """A drop blob next to the sensor spans many beams (at 1 m its 3 sigma, 0.3 m, reach 17 deg): every beam
    whose footprint it reaches gets its share, as the blob integrated over each footprint gives it (the
    reference once took at most 8 columns and 1 channel either side: at 1 m 17 of the 139 columns its 3 sigma
    spans). ``all_round``: a sensor that looks all round, the drop behind it (its beams on both sides of
    +-180 deg)."""
    scan = {"scan__azimuth_min_deg": -180.0, "scan__azimuth_max_deg": 180.0, "scan__columns": 1440} if all_round else {}
    profile = simple_profile(beams=[{"elevation_deg": e} for e in (-3.0, -2.0, -1.0, 0.0, 1.0, 2.0, 3.0)],
                             optics__divergence_h_mrad=1.75, optics__divergence_v_mrad=2.0, **scan)  # fmt: skip
    pattern = ScanPattern(profile)
    ref = _reference()
    weight, diameter = 2e4, 2e-4
    pos = np.array([drop])
    ref.particles = Particles(pos, np.zeros((1, 3)), np.zeros(1), np.full(1, 9.0), np.zeros(1), np.zeros(1),
                              np.zeros(1, np.int64), np.ones(1), np.full(1, 2, np.uint8), np.zeros(1, np.int64),
                              np.full(1, diameter), np.full(1, weight), np.zeros(1), np.ones(1))  # fmt: skip
    ref.tick_index = 0

    def poses(times):
        return np.zeros((len(times), 3)), np.tile(np.eye(3), (len(times), 1, 1))

    got = detect_frame(ref, pattern, 0, 0.0, poses, None, threshold=4.0)
    found = {(int(c), int(ch)): a for c, ch, a in zip(got.column, got.channel, got.amplitude)}
    expected = _beam_amplitudes_by_quadrature(profile, pattern, pos[0], weight, diameter, C.reference.kernel_radius_m)
    clear = {k for k, a in expected.items() if abs(a / 4.0 - 1.0) > 0.02}  # away from the threshold (quadrature)
    assert {k for k in clear if expected[k] > 4.0} == {k for k in found if k in clear}
    assert len(found) > 30
    for k, a in found.items():
        assert a == pytest.approx(expected[k], rel=0.02)


def test_metrics():
    a = bev_histogram(np.array([[10.2, 0.1], [10.3, 0.2], [20.0, -3.0]]))
    assert a.sum() == 3 and a.shape == (80, 40)
    m = compare_histograms(a, a)
    assert m == {"pearson": pytest.approx(1.0), "jaccard_pct": 0.0, "hamming_pct": 0.0}
    b = bev_histogram(np.array([[10.2, 0.1], [30.0, 5.0]]))
    m = compare_histograms(a, b)
    assert m["jaccard_pct"] == pytest.approx(100 * 2 / 3) and m["hamming_pct"] == pytest.approx(100 * 2 / 3200)
    assert per_frame_overlap([1, 1, 2], [1, 2, 2]) == pytest.approx(2 / 3)
