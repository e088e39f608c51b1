"""Physical atmosphere coefficients (lidar_weather_sim.physics): fog scaled to its visual range, rain against a
published near-IR extinction law, Mie efficiencies against their limits, the biaxial overlap function."""

from __future__ import annotations

import numpy as np
import pytest

from lidar_weather_sim.physics import dsd
from lidar_weather_sim.physics.coefficients import KOSCHMIEDER, medium
from lidar_weather_sim.physics.mie import efficiencies, geometric_backscatter, mie_direct, refractive_index
from lidar_weather_sim.physics.overlap import biaxial_overlap, circle_overlap_area
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
