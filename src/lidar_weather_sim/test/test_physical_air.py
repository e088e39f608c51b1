"""The physical atmosphere (regions.physical_air) on hand-made ray batches: seeded, in front of each hit,
the drop counts the beam volume predicts, the volume return as tables where the medium is dense enough and its
near field's realisations as the droplets fluctuate."""

from __future__ import annotations

import numpy as np
import pytest

from lidar_weather_sim.core.points import Label
from lidar_weather_sim.physics.coefficients import medium
from lidar_weather_sim.regions.air_volume import REALISATIONS
from lidar_weather_sim.regions.physical_air import NEAR_M, PhysicalAir
from lidar_weather_sim.sensor.volume_tables import REACH
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
    a, _ = air.scatterers(batch(hits), np.random.default_rng(3))
    b, _ = air.scatterers(batch(hits), np.random.default_rng(3))
    np.testing.assert_array_equal(a.range_m, b.range_m)
    drops = a.label == Label.RAIN
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
    hits = np.array([3.0, 40.0, np.inf])
    drops, terms = air.scatterers(batch(hits), np.random.default_rng(0))
    assert drops is None and len(terms) == 2  # the mean beyond the near field, and a realisation of it per beam
    far, near = terms
    assert far.hit_m is None and near.hit_m is None  # cut at each beam's scene hit by the echo stage
    assert len(near.tables) == REALISATIONS and near.choice.shape == (3,) and (far.scale == 1.0).all()
    for table in (far.table, *near.tables):
        assert set(np.unique(table.label)) == {Label.FOG}
    # the volume in front of a 3 m hit: the realisation's waveform there, nothing 6 sigma behind it
    table = near.tables[near.choice[0]]
    r, cut = table.range_m, table.truncated(3.0)
    assert (cut[r > 3.0 + 6.5 * air.volume.sigma_m] == 0.0).all() and cut[(r > 1.0) & (r < 2.5)].min() > 0.0
    front = r < 3.0 - 7 * air.volume.sigma_m
    np.testing.assert_allclose(cut[front], table.wave[front], rtol=1e-12)
    # haze: the same density beyond the near field, as strong as its backscatter (beta) is, its extinction apart
    thin = PhysicalAir(SCALA4_CONE_DC, 5000.0, None)
    r = far.table.range_m
    fog = (far.table.density > 0) & (r < 30.0)
    assert fog.sum() > 100 and thin.air_volume.boundary_m == air.air_volume.boundary_m
    ratio = thin.air_volume.far.density[fog] / far.table.density[fog] * np.exp(2.0 * (thin.alpha - air.alpha) * r[fog])
    np.testing.assert_allclose(ratio, medium("fog", 5000.0, 905.0).beta / medium("fog", 50.0, 905.0).beta, rtol=1e-5)


@pytest.mark.parametrize("profile, visual_range_m", [("scala4", 500.0), ("os1_128_2048", 100.0)])
def test_near_field_fog_slabs_fluctuate_as_the_droplets_in_them(profile, visual_range_m):
    """The near field's slabs from realisation to realisation, and from beam to beam, against droplets drawn one by
    one: a Poisson number in the slab's beam volume, sizes from the distribution, their cross-sections summed (a
    reflectance pi sum / S seen through O(r)). Each droplet takes the Mie cross-section of the nearest diameter of
    the medium's grid (the grid the model integrates on: between its nodes the resonances are not resolved, and
    interpolating there smooths them, lowering E[sigma^2] by ~20 %). Over the slabs from 2 to 4.5 m: mean within
    2 %, standard deviation within 10 %, over the realisations and over 2000 beams' choices; the realisations'
    tables hold their slabs' factors."""
    prof = receiver_variant(profile, ac_coupling_tau_m=0.0)  # the slabs before the receiver
    air = PhysicalAir(prof, visual_range_m, None)
    bank = air.air_volume
    n_beams = 2000
    _, (_, near) = air.scatterers(batch(np.full(n_beams, np.inf)), np.random.default_rng(5))
    edges, factors = bank.slab_edges, bank.factors
    assert factors.shape == (REALISATIONS, len(edges) - 1) and edges[-1] <= NEAR_M + air.volume.sigma_m
    fog, rng = medium("fog", visual_range_m, prof.optics.wavelength_nm or 905.0), np.random.default_rng(6)
    ratios = []
    for k in np.flatnonzero((edges[:-1] > 2.0) & (edges[1:] < 4.5)):
        centre, width = 0.5 * (edges[k] + edges[k + 1]), edges[k + 1] - edges[k]
        area, overlap = air.area(centre), air.volume.overlap(np.array([centre]))[0]
        counts = rng.poisson(fog.number * area * width, 4000)
        diameter, _ = fog.sample(int(counts.sum()), rng)
        node = np.clip(np.searchsorted(fog.diameters, diameter), 1, len(fog.diameters) - 1)
        node -= diameter - fog.diameters[node - 1] < fog.diameters[node] - diameter
        summed = np.bincount(np.repeat(np.arange(4000), counts), weights=fog.sigma_back[node], minlength=4000)
        drawn = np.pi * summed / area * overlap
        mean = np.pi * fog.beta * width * overlap  # the slab's mean reflectance
        banked, chosen = mean * factors[:, k], mean * factors[near.choice, k]
        ratios.append([banked.mean() / drawn.mean(), banked.std() / drawn.std(), chosen.std() / drawn.std()])
        assert drawn.std() > 0.01 * drawn.mean()
    ratios = np.mean(ratios, axis=0)
    assert len(ratios) and ratios[0] == pytest.approx(1.0, abs=0.02), ratios
    np.testing.assert_allclose(ratios[1:], 1.0, atol=0.10)
    # each realisation's cells are the mean's times its slab's factor (a cell inside slab k)
    k = int(np.searchsorted(edges, 3.0)) - 1
    cell = int(np.round(0.5 * (edges[k] + edges[k + 1]) / bank.far.dx_m)) + REACH
    a, b = bank.near[0].density[cell], bank.near[1].density[cell]
    assert a / b == pytest.approx(factors[0, k] / factors[1, k], rel=1e-9)


def test_the_grid_interpolation_is_numpys_bit_for_bit():
    from lidar_weather_sim.regions.physical_air import GRID_M, _interp_uniform

    rng = np.random.default_rng(7)
    grid = np.arange(0.05, 180.0 + GRID_M, GRID_M)
    table = np.cumsum(rng.random(len(grid)))
    x = np.concatenate([rng.uniform(-1.0, 185.0, 100_000), grid[::7], grid[-1:], grid[:1] - 1e-17, [np.nan, np.inf]])
    got = _interp_uniform(x, float(grid[0]), GRID_M, grid, table, np.empty(len(x)))
    want = np.interp(x, grid, table)
    assert got.tobytes() == want.tobytes()


def test_the_inverse_of_the_drops_cumulative_count_is_numpys_interpolation_bit_for_bit():
    """The drops' ranges: ``np.interp`` of uniform draws on the cumulative count (non-decreasing, flat where no drop
    can be seen), found by bisection inside a bucket of the count instead of numpy's search."""
    from lidar_weather_sim.regions.physical_air import _interp_sorted, bucket_index

    rng = np.random.default_rng(11)
    steps = rng.random(9000) * (rng.random(9000) < 0.7)  # 30 % flat steps: repeated values
    xp = np.concatenate([[0.0], np.cumsum(steps)])
    fp = np.arange(len(xp)) * 0.02 + 0.05
    x = np.concatenate([rng.uniform(-1.0, xp[-1] + 1.0, 200_000), xp[::5], xp[-1:], [np.nan, np.inf, -np.inf]])
    got = _interp_sorted(x, xp, fp, *bucket_index(xp), np.empty(len(x)))
    assert got.tobytes() == np.interp(x, xp, fp).tobytes()
    air = PhysicalAir(load_profile("os1_128_2048"), None, ("rain", 10.0))
    x = rng.random(200_000) * air._cum[-1]
    got = _interp_sorted(x, air._cum, air._grid, *air._cum_index, np.empty(len(x)))
    assert got.tobytes() == np.interp(x, air._cum, air._grid).tobytes()


@pytest.mark.parametrize("name", ["os1_128_2048", "vlp16", "hdl64e"])
def test_a_drop_is_in_the_receivers_view_exactly_where_a_draw_lies_below_the_overlap_function(name):
    """Cone overlap: the bounds on O(r) per range cell decide most drops; the decisions are u < O(r) itself."""
    air = PhysicalAir(load_profile(name), None, ("rain", 10.0))
    rng = np.random.default_rng(4)
    r = np.concatenate([rng.uniform(0.0, 8.0, 200_000), rng.uniform(0.0, air.r_max + 1.0, 100_000)])
    u = np.random.default_rng(9).random(len(r))
    seen = air._seen_share(r, np.random.default_rng(9))
    assert np.array_equal(seen, (u < air._overlap(r)).astype(np.float64))
    assert 0.0 < seen[:200_000].mean() < 1.0  # the near field holds drops on both sides of the receiver's view


@pytest.mark.parametrize("name", ["os1_128_2048", "vlp16", "hdl64e", "scala4"])
@pytest.mark.validation
def test_drops_see_the_overlap_function_itself_nearer_and_exactly_one_beyond_full_overlap(name):
    air = PhysicalAir(load_profile(name), None, ("rain", 10.0))
    r = np.random.default_rng(3).uniform(0.0, 60.0, 200_000)
    assert air._overlap(r).tobytes() == air.volume.overlap(r).tobytes()
    if name == "os1_128_2048":
        assert air._full_overlap_m < 10.0  # the fast path is taken for the dense sensor


def test_the_fog_backscatter_gain_scales_the_fogs_volume_at_every_range_and_leaves_the_drops():
    """``fog_backscatter_gain`` (a unit's pulse discrimination, near-range gain or blanking, fitted by the gap
    search): the fog's volume, near-field realisations and far layer alike, is the gain times the full one at
    every range (OS1's DC receiver: its fog echo is metres long), the extinction is untouched, the drops placed one by
    one are the same, gain 0 leaves no volume at all, and gain 1 is the profile's optics alone, bit for bit."""
    weather = (60.0, None)
    plain, one = PhysicalAir(SCALA4_CONE_DC, *weather), PhysicalAir(SCALA4_CONE_DC, *weather, fog_backscatter_gain=1.0)
    np.testing.assert_array_equal(one.air_volume.far.wave, plain.air_volume.far.wave)
    for a, b in zip(one.air_volume.near, plain.air_volume.near):
        np.testing.assert_array_equal(a.wave, b.wave)
    for gain in (0.0, 0.3):
        air = PhysicalAir(SCALA4_CONE_DC, *weather, fog_backscatter_gain=gain)
        assert air.alpha == plain.alpha
        tables = list(zip((air.air_volume.far, *air.air_volume.near), (plain.air_volume.far, *plain.air_volume.near)))
        assert len(tables) == (1 if gain == 0.0 else 1 + len(plain.air_volume.near))
        for scaled, full in tables:
            peak = np.abs(full.density).max()
            np.testing.assert_allclose(scaled.density, gain * full.density, rtol=1e-9, atol=1e-12 * peak)
            if full is plain.air_volume.far:
                assert np.abs(full.density[full.range_m > 2 * NEAR_M]).max() > 1e-3 * peak  # beyond the near field too
    # rain beside the fog: its drops are the same at every gain (same seed; the volume's terms draw from the batch's
    # generator too, so the drops are drawn alone)
    rainy, hits = (60.0, ("rain", 20.0)), np.full(4000, 40.0)
    w = np.asarray(batch(hits).weights, np.float64)
    full = PhysicalAir(SCALA4_CONE_DC, *rainy)._drops(hits, w, np.random.default_rng(5))
    assert np.sum(full.range_m < NEAR_M) > 100
    for gain in (0.0, 0.3):
        drops = PhysicalAir(SCALA4_CONE_DC, *rainy, fog_backscatter_gain=gain)._drops(hits, w, np.random.default_rng(5))
        np.testing.assert_array_equal(drops.range_m, full.range_m)
        np.testing.assert_array_equal(drops.reflectance, full.reflectance)
    with pytest.raises(ValueError, match="fog_backscatter_gain"):
        PhysicalAir(SCALA4_CONE_DC, *weather, fog_backscatter_gain=1.5)
