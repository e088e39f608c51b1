"""Physical atmosphere coefficients (lidar_weather_sim.physics): fog scaled to its visual range, rain against a
published near-IR extinction law, Mie efficiencies against their limits, the biaxial overlap function with and
without the aperture's defocus."""

from __future__ import annotations

import numpy as np
import pytest

from lidar_weather_sim.physics import dsd
from lidar_weather_sim.physics.coefficients import KOSCHMIEDER, medium
from lidar_weather_sim.physics.mie import efficiencies, geometric_backscatter, mie_direct, refractive_index
from lidar_weather_sim.physics.overlap import biaxial_overlap, circle_overlap_area, defocused_overlap
from lidar_weather_sim.sensor.profile import load_profile


@pytest.mark.parametrize("visual_range", [30.0, 100.0, 500.0])
def test_fog_alpha_is_koschmieder_at_550nm_by_construction(visual_range):
    assert medium("fog", visual_range, 550.0).alpha == pytest.approx(KOSCHMIEDER / visual_range, rel=1e-9)


def test_fog_alpha_at_905nm_follows_the_droplets():
    """Advection fog (mode radius 10 um, x ~ 70 at 905 nm): Q_ext is near 2 at both wavelengths, so alpha at
    905 nm is within a few % of alpha at 550 nm and equals the DSD integral of the Mie cross-sections there."""
    m = medium("fog", 100.0, 905.0)
    ratio = m.alpha / (KOSCHMIEDER / 100.0)
    assert 0.95 < ratio < 1.1
    d = np.geomspace(m.dsd.d_min, m.dsd.d_max, 3000)
    qext, _ = mie_direct(refractive_index("water", 905.0), np.pi * d / 905e-9)
    f = m.dsd.density(d) * qext * np.pi * d**2 / 4
    assert m.alpha == pytest.approx(np.sum(0.5 * (f[1:] + f[:-1]) * np.diff(d)), rel=0.01)
    assert 10.0 < m.lidar_ratio_sr < 30.0  # fog lidar ratios of ~18 sr (e.g. Rasshofer et al. 2011)


def test_fog_number_density_matches_shettle_fenn():
    """Unscaled advection fog holds ~20 droplets per cm^3 (Shettle & Fenn 1979)."""
    assert dsd.shettle_fenn("advection").number() / 1e6 == pytest.approx(20.0, rel=0.05)


@pytest.mark.parametrize("rate", [1.0, 5.0, 10.0, 50.0])
def test_rain_alpha_matches_published_near_ir_law(rate):
    """alpha [1/km] = 0.365 R^0.63 (Kim et al. 2001 / Al Naboulsi et al. 2004, near IR): within 20 %."""
    alpha_km = medium("rain", rate, 905.0).alpha * 1e3
    assert alpha_km == pytest.approx(0.365 * rate**0.63, rel=0.2)


def test_rain_alpha_closed_form_marshall_palmer():
    """Q_ext 2 over 0.1-6 mm: alpha = pi N0 / Lambda^3 (untruncated) within the truncation's 3 %."""
    lam = 4.1 * 10.0**-0.21  # 1/mm
    closed = np.pi * 8000.0 / lam**3 * 1e-6  # mm^2/m^3 -> 1/m
    assert medium("rain", 10.0, 905.0).alpha == pytest.approx(closed, rel=0.03)


def test_snow_mean_flake_size_near_thesis(thesis_tables):
    """Gunn-Marshall at 1 mm/h with 100 kg/m^3 flakes: mean flake diameter near the thesis' 1 mm."""
    g = dsd.gunn_marshall(1.0)
    d = np.linspace(g.d_min, g.d_max, 5000)
    n = g.density(d)
    mean_mm = np.sum(n * g.optical(d)) / np.sum(n) * 1e3
    assert mean_mm == pytest.approx(thesis_tables["optics_and_materials"]["typical_sizes"]["snowflake_mm"], rel=0.35)


def test_heavier_weather_extinguishes_more():
    for kind, lo, hi in (("fog", 500.0, 30.0), ("rain", 1.0, 50.0), ("snow", 0.5, 5.0)):
        assert medium(kind, hi, 905.0).alpha > medium(kind, lo, 905.0).alpha
        assert medium(kind, hi, 905.0).beta > medium(kind, lo, 905.0).beta


def test_mie_limits():
    m = refractive_index("water", 905.0)
    qext, qback = mie_direct(m, np.array([0.01, 300.0]))
    k = (m**2 - 1) / (m**2 + 2)
    assert qback[0] == pytest.approx(4 * 0.01**4 * abs(k) ** 2, rel=1e-3)  # Rayleigh, radar convention
    assert qext[1] == pytest.approx(2.0, abs=0.05)  # extinction paradox
    assert geometric_backscatter(m) == pytest.approx(0.095, abs=0.003)
    qe, qb = efficiencies("water", 905.0, np.array([1e-3]), "geometric")
    assert qe[0] == 2.0 and qb[0] == pytest.approx(geometric_backscatter(m))
    with pytest.raises(ValueError, match="regime"):
        efficiencies("water", 905.0, np.array([1e-3]), "ray")


def test_poisson_draws_from_the_dsd_match_its_moments():
    rng = np.random.default_rng(3)
    m = medium("rain", 10.0, 905.0)
    d, sigma = m.sample(200_000, rng)
    assert d.min() >= m.dsd.d_min and d.max() <= m.dsd.d_max
    mean_d = np.sum(m.density * m.diameters) / np.sum(m.density)
    assert d.mean() == pytest.approx(mean_d, rel=0.01)
    assert sigma.mean() * m.number == pytest.approx(m.beta, rel=0.02)


def test_circle_overlap_area_limits():
    assert circle_overlap_area(1.0, 1.0, 3.0) == 0.0
    assert circle_overlap_area(1.0, 2.0, 0.5) == pytest.approx(np.pi)
    assert circle_overlap_area(1.0, 1.0, 0.0) == pytest.approx(np.pi)
    lens = circle_overlap_area(1.0, 1.0, 1.0)  # two unit circles one apart: 2 pi/3 - sqrt(3)/2
    assert lens == pytest.approx(2 * np.pi / 3 - np.sqrt(3) / 2)


@pytest.mark.parametrize("name", ["scala4", "vlp16", "os1_128_2048"])
def test_profile_overlap_zero_near_one_far(name):
    o = load_profile(name).optics
    assert o.wavelength_nm is not None and o.lens_separation_m is not None
    div = 1e-3 * np.sqrt(o.divergence_h_mrad * o.divergence_v_mrad)
    r = np.array([0.0, 0.05, 0.1, 1.0, 3.0, 20.0, 100.0])
    ov = biaxial_overlap(r, o.lens_separation_m, div, 1e-3 * o.receiver_fov_mrad, o.tx_aperture_radius_m,
                         o.rx_aperture_radius_m)  # fmt: skip
    assert ov[0] == 0.0 and ov[1] == 0.0 and ov[2] == 0.0
    assert ov[-1] == pytest.approx(1.0) and ov[-2] == pytest.approx(1.0)
    assert np.all(np.diff(ov) >= -1e-12)


def test_scala4_overlap_matches_the_thesis_ranges(thesis_tables):
    """Starts at the thesis' 0.5 m (line 498) and is full at the profile's 1.8 m."""
    p = load_profile("scala4")
    o = p.optics
    div = 1e-3 * np.sqrt(o.divergence_h_mrad * o.divergence_v_mrad)
    start = thesis_tables["optics_and_materials"]["sender_receiver_overlap_min_m"]
    ov = biaxial_overlap(np.array([start - 0.02, start + 0.05, o.overlap_full_m + 0.01]), o.lens_separation_m, div,
                         1e-3 * o.receiver_fov_mrad, o.tx_aperture_radius_m, o.rx_aperture_radius_m)  # fmt: skip
    assert ov[0] == 0.0 and 0.0 < ov[1] < 0.5 and ov[2] == pytest.approx(1.0)
    assert o.wavelength_nm == thesis_tables["sensor_scala"]["wavelength_nm"]


def _ray_traced_overlap(r: float, separation: float, divergence: float, fov: float, tx: float, rx: float,
                        rng: np.random.Generator, n: int = 400_000) -> float:
    """O(r) by tracing rays: a point drawn uniformly in the beam's disc, a point drawn uniformly in the receiver's
    aperture; behind a lens focused at infinity the ray lands at the angle of its direction, (p - a) / r, and
    the field stop takes it when that is within fov / 2."""

    def disc(radius):
        rho, phi = radius * np.sqrt(rng.random(n)), 2.0 * np.pi * rng.random(n)
        return rho * np.cos(phi), rho * np.sin(phi)

    bx, by = disc(tx + r * np.tan(0.5 * divergence))
    ax, ay = disc(rx)
    angle = np.hypot(separation + bx - ax, by - ay) / r
    return float(np.mean(angle <= np.tan(0.5 * fov)))


@pytest.mark.parametrize("name", ["scala4", "vlp16", "os1_128_2048"])
def test_defocused_overlap_agrees_with_traced_rays(name):
    """The quadrature of the defocused overlap against rays traced point by point, on each profile's optics,
    from where the overlap starts to where it is full; 0 before and 1 beyond, rising in between."""
    o = load_profile(name).optics
    args = (o.lens_separation_m, 1e-3 * np.sqrt(o.divergence_h_mrad * o.divergence_v_mrad), 1e-3 * o.receiver_fov_mrad,
            o.tx_aperture_radius_m, o.rx_aperture_radius_m)  # fmt: skip
    rng = np.random.default_rng(22)
    ranges = np.array([0.3, 0.7, 1.0, 1.5, 2.0, 3.0, 5.0, 8.0, 12.0, 30.0])
    quadrature = defocused_overlap(ranges, *args)
    traced = np.array([_ray_traced_overlap(r, *args, rng) for r in ranges])
    assert np.max(np.abs(quadrature - traced)) < 0.005
    assert quadrature[0] == 0.0 and quadrature[-1] == 1.0
    assert np.all(np.diff(quadrature) >= -1e-9)


def test_defocus_lowers_the_near_overlap_and_without_an_aperture_changes_nothing():
    """On scala4's optics the aperture's blur leaves ~2 % of the beam seen at 1 m, where the cone model counts
    half of it, and delays full overlap from 1.8 m to beyond 3.5 m; with a point aperture both models are one."""
    o = load_profile("scala4").optics
    div, fov = 1e-3 * np.sqrt(o.divergence_h_mrad * o.divergence_v_mrad), 1e-3 * o.receiver_fov_mrad
    r = np.array([1.0, 1.8, 3.5])
    cone = biaxial_overlap(r, o.lens_separation_m, div, fov, o.tx_aperture_radius_m, o.rx_aperture_radius_m)
    blur = defocused_overlap(r, o.lens_separation_m, div, fov, o.tx_aperture_radius_m, o.rx_aperture_radius_m)
    assert blur[0] < 0.05 < 0.4 < cone[0]
    assert cone[1] == pytest.approx(1.0, abs=1e-3) and blur[1] < 0.5 and blur[2] < 0.95
    ranges = np.geomspace(0.2, 20.0, 40)
    point = defocused_overlap(ranges, o.lens_separation_m, div, fov, o.tx_aperture_radius_m, 0.0)
    cone = biaxial_overlap(ranges, o.lens_separation_m, div, fov, o.tx_aperture_radius_m, 0.0)
    assert np.max(np.abs(point - cone)) < 0.01  # the quadrature's own error only
