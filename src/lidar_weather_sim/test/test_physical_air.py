"""The physical atmosphere (regions.physical_air) on hand-made ray batches: seeded, in front of each hit,
the drop counts the beam volume predicts, the volume return where the medium is dense enough."""

from __future__ import annotations

import numpy as np
import pytest

from lidar_weather_sim.core.points import Label
from lidar_weather_sim.physics.coefficients import medium
from lidar_weather_sim.regions.physical_air import NEAR_M, PhysicalAir
from lidar_weather_sim.sensor.profile import load_profile
from lidar_weather_sim.testing.fixtures import beams_along_x as batch
from lidar_weather_sim.testing.fixtures import receiver_variant

#: scala4's optics before its receiver: the cone overlap (a drop seen wholly or not) and a DC-coupled volume
SCALA4_CONE_DC = receiver_variant("scala4", "cone", 0.0)


def test_extinction_is_the_media_at_the_profiles_wavelength():
    os1 = load_profile("os1_128_2048")  # 865 nm
    air = PhysicalAir(os1, 80.0, ("rain", 5.0))
    assert air.alpha == pytest.approx(medium("fog", 80.0, 865.0).alpha + medium("rain", 5.0, 865.0).alpha)


def test_rain_drops_are_seeded_in_front_of_the_hit_and_as_many_as_the_beam_volume_holds():
    air = PhysicalAir(SCALA4_CONE_DC, None, ("rain", 10.0))
    hits = np.where(np.arange(4000) % 2 == 0, 8.0, np.inf)
    a = air.scatterers(batch(hits), np.random.default_rng(3))
    b = air.scatterers(batch(hits), np.random.default_rng(3))
    np.testing.assert_array_equal(a.range_m, b.range_m)
    drops = (a.label == Label.RAIN) & (a.occlusion > 0)  # the volume pulses of the small drops block nothing
    assert (a.range_m[drops] < hits[a.beam[drops]]).all()
    # the drops placed one by one in front of an 8 m hit: the table's expectation, thinned by the overlap
    r = np.linspace(0.05, 8.0, 4000)
    per_m = np.gradient(np.interp(r, air._grid, air._cum), r)
    expected = np.sum(per_m * air.volume.overlap(r)) * (r[1] - r[0])
    placed = np.sum(drops & (hits[a.beam] == 8.0) & (a.range_m < 8.0)) / 2000
    assert placed == pytest.approx(expected, rel=0.05)
    assert a.reflectance[drops].min() > 0 and np.median(a.occlusion[drops]) < 0.01  # a drop blocks little light


def test_fog_gives_every_beam_its_volume_return_up_to_the_hit():
    air = PhysicalAir(SCALA4_CONE_DC, 50.0, None)
    out = air.scatterers(batch(np.array([3.0, 40.0, np.inf])), np.random.default_rng(0))
    assert set(out.label) == {Label.FOG} and out.bypass_overlap.all() and not out.occlusion.any()
    per_beam = np.bincount(out.beam, minlength=3)
    assert 0 < per_beam[0] < per_beam[1] <= per_beam[2]
    assert out.range_m[out.beam == 0].max() < 3.0
    # haze: the same slabs, each as strong as its backscatter (beta) is (beyond the near field, where the slabs
    # do not fluctuate from beam to beam)
    haze = PhysicalAir(SCALA4_CONE_DC, 5000.0, None).scatterers(batch(np.array([40.0])), np.random.default_rng(0))
    fog = (out.beam == 1) & (out.range_m > NEAR_M)
    common = np.isin(out.range_m[fog], haze.range_m)
    ratio = haze.reflectance[np.isin(haze.range_m, out.range_m[fog])] / out.reflectance[fog][common]
    assert len(ratio) > 10
    np.testing.assert_allclose(ratio, medium("fog", 5000.0, 905.0).beta / medium("fog", 50.0, 905.0).beta, rtol=1e-9)


@pytest.mark.parametrize("profile, visual_range_m", [("scala4", 500.0), ("os1_128_2048", 100.0)])
def test_near_field_fog_slabs_fluctuate_as_the_droplets_in_them(profile, visual_range_m):
    """A near-field fog slab's pulse from beam to beam against droplets drawn one by one: a Poisson number in the
    slab's beam volume, sizes from the distribution, their cross-sections summed (a reflectance pi sum / S seen
    through O(r)). Each droplet takes the Mie cross-section of the nearest diameter of the medium's grid (the
    grid the model integrates on: between its nodes the resonances are not resolved, and interpolating there
    smooths them, lowering E[sigma^2] by ~20 %). Mean within 2 %, standard deviation within 10 %."""
    prof = receiver_variant(profile, ac_coupling_tau_m=0.0)  # the slabs before the receiver
    air = PhysicalAir(prof, visual_range_m, None)
    n_beams = 4000
    out = air.scatterers(batch(np.full(n_beams, np.inf)), np.random.default_rng(5))
    centres, widths = air.volume.slabs(np.inf, spacing_m=air.volume.sigma_m, r_max_m=air.r_max)
    k = int(np.argmin(np.abs(centres - 3.0)))
    weight = 1.0 / 3.0
    simulated = out.reflectance[out.range_m == centres[k]] * weight
    assert len(simulated) == n_beams
    fog, rng = medium("fog", visual_range_m, prof.optics.wavelength_nm or 905.0), np.random.default_rng(6)
    area = air.area(centres[k])
    counts = rng.poisson(fog.number * area * widths[k], n_beams)
    diameter, _ = fog.sample(int(counts.sum()), rng)
    node = np.clip(np.searchsorted(fog.diameters, diameter), 1, len(fog.diameters) - 1)
    node -= diameter - fog.diameters[node - 1] < fog.diameters[node] - diameter
    sigma = fog.sigma_back[node]
    summed = np.bincount(np.repeat(np.arange(n_beams), counts), weights=sigma, minlength=n_beams)
    drawn = np.pi * summed / area * air.volume.overlap(np.array([centres[k]]))[0]
    assert simulated.mean() == pytest.approx(drawn.mean(), rel=0.02)
    assert simulated.std() == pytest.approx(drawn.std(), rel=0.10) and drawn.std() > 0.01 * drawn.mean()
    far = out.range_m > NEAR_M  # beyond the near field: the expectation, the same in every beam
    assert len(np.unique(out.reflectance[far & (out.range_m == out.range_m[far][0])])) == 1


def test_the_grid_interpolation_is_numpys_bit_for_bit():
    from lidar_weather_sim.regions.physical_air import GRID_M, _interp_uniform

    rng = np.random.default_rng(7)
    grid = np.arange(0.05, 180.0 + GRID_M, GRID_M)
    table = np.cumsum(rng.random(len(grid)))
    x = np.concatenate([rng.uniform(-1.0, 185.0, 100_000), grid[::7], grid[-1:], grid[:1] - 1e-17, [np.nan, np.inf]])
    got = _interp_uniform(x, float(grid[0]), GRID_M, grid, table, np.empty(len(x)))
    want = np.interp(x, grid, table)
    assert got.tobytes() == want.tobytes()


@pytest.mark.parametrize("name", ["os1_128_2048", "vlp16", "hdl64e", "scala4"])
@pytest.mark.validation
def test_drops_see_the_overlap_function_itself_nearer_and_exactly_one_beyond_full_overlap(name):
    air = PhysicalAir(load_profile(name), None, ("rain", 10.0))
    r = np.random.default_rng(3).uniform(0.0, 60.0, 200_000)
    assert air._overlap(r).tobytes() == air.volume.overlap(r).tobytes()
    if name == "os1_128_2048":
        assert air._full_overlap_m < 10.0  # the fast path is taken for the dense sensor
