"""Cover region: texture sampling, two-way loss, Table I random fields, range noise, cover returns, blending."""

import numpy as np
import pytest

from lidar_weather_sim.core.config import ConfigError
from lidar_weather_sim.core.points import Label
from lidar_weather_sim.regions.base import REGISTRY, RegionContext
from lidar_weather_sim.regions.cover import _forward_scatter_factors
from lidar_weather_sim.regions.cover_textures import blend, image_texture, load_samples, make_texture
from lidar_weather_sim.sensor.radiometry import FWHM_TO_SIGMA
from lidar_weather_sim.sim.simulator import LidarSimulator
from lidar_weather_sim.testing.fixtures import one_frame, scene_of, simple_profile, wall


def _sim(profile, seed=0, **params):
    regions = [("cover", REGISTRY.create("cover", params, RegionContext(profile)))] if params else []
    return LidarSimulator(profile, scene_of(wall(20.0, "concrete", 1)), regions=regions, seed=seed)


def _amplitude(epw, fwhm=0.6, threshold=4.0):
    return threshold * np.exp((epw / (2 * fwhm * FWHM_TO_SIGMA)) ** 2 / 2)


def test_texture_is_sampled_per_ray_and_applied_out_and_back(tmp_path):
    grid = np.tile(np.linspace(0.5, 1.0, 9), (3, 1))  # transmission 0.5 at the right edge, 1.0 at the left
    np.save(tmp_path / "ramp.npy", grid)
    profile = simple_profile()
    clean = one_frame(_sim(profile)).points
    dirty_sim = _sim(profile, texture=f"image:{tmp_path / 'ramp.npy'}")
    dirty = one_frame(dirty_sim).points
    assert len(clean) == len(dirty) == 81
    region = dirty_sim.regions[0][1]
    direction = np.stack([np.cos(dirty["azimuth"]), np.sin(dirty["azimuth"]), np.zeros(len(dirty))], -1)
    u, v = region.uv(direction.astype(np.float64))
    t = region.textures[0].sample(u, v)
    assert t.min() == pytest.approx(0.5, abs=0.01) and t.max() == pytest.approx(1.0, abs=0.01)
    ratio = _amplitude(dirty["epw"].astype(np.float64)) / _amplitude(clean["epw"].astype(np.float64))
    np.testing.assert_allclose(ratio, t**2, rtol=2e-3)  # two-way loss T^2 where the dirt sits


def test_random_fields_reproduce_each_table_1_mean_within_1_percent(thesis_tables):
    db = load_samples()
    rng = np.random.default_rng(7)
    for name, row in thesis_tables["cover_dirt_samples"].items():
        if not (isinstance(row, dict) and "T" in row):
            continue
        means = [make_texture(name, rng, 0.03, db).mean for _ in range(40)]
        assert np.mean(means) == pytest.approx(row["T"] / 100.0, rel=0.01), name
        one = make_texture(name, rng, 0.03, db)
        assert one.grid.shape == (4, 18) and 0.0 <= one.grid.min() and one.grid.max() <= 1.0
    heavy = make_texture("5u", np.random.default_rng(1), 0.03, db).grid
    assert 0.03 < heavy.max() - heavy.min() < 0.3  # within-cover spread like Fig. 7 (64-77.5 %)
    a = make_texture("3l", np.random.default_rng(3), 0.03, db).grid
    assert np.array_equal(a, make_texture("3l", np.random.default_rng(3), 0.03, db).grid)  # seeded


def test_range_noise_grows_as_in_table_2(thesis_tables):
    profile = simple_profile(range__noise_sigma_m=0.03, scan__columns=801)
    clean = one_frame(_sim(profile, seed=1, texture="clean")).points
    dirty = one_frame(_sim(profile, seed=1, texture="3l")).points
    wall_only = lambda p: p[p["label"] == Label.STATIC]  # noqa: E731  (without the near-field cover returns)
    residual = lambda p: wall_only(p)["distance"] - 20.0 / np.cos(wall_only(p)["azimuth"].astype(np.float64))  # noqa: E731
    increase = residual(dirty).std() / residual(clean).std() - 1.0
    expected = thesis_tables["cover_dirt_samples"]["3l"]["sigma_increase"] / 100.0
    assert increase == pytest.approx(expected, abs=0.15)


def test_near_field_cover_returns_grow_with_dirt_and_water():
    profile = simple_profile(scan__columns=801)

    def cover_returns(texture):
        pts = one_frame(_sim(profile, seed=2, texture=texture)).points
        near = pts[pts["label"] == Label.COVER]
        assert np.all(near["distance"] < 0.6)
        return len(near)

    assert cover_returns("clean") == 0
    light, heavy, water = cover_returns("1u"), cover_returns("3l"), cover_returns("water_film")
    assert light < heavy and water > 100  # detected although the biaxial overlap is 0 there


def test_the_texture_return_gain_scales_the_dirts_cover_returns_and_leaves_its_loss_and_the_ghosts():
    """``texture_return_gain`` (effect key ``cover.dirt:...,gain=``; a unit that blanks its cover zone): the dirt's
    cover returns come at the gain times their rate (none at 0), the wall's returns through the dirt are the same at
    every gain, their mean intensity within 1 % (the loss is the texture's alone; a cover return shadows a little of
    its sub-ray, and the draws after the cover returns differ), and the clean window's ghosts stay."""
    profile = simple_profile(scan__columns=4001)

    def frame(**params):
        pts = one_frame(_sim(profile, seed=2, texture="3l", **params)).points
        return pts[pts["label"] == Label.COVER], pts[pts["label"] == Label.STATIC]

    (full, wall_full), (half, wall_half), (none, wall_none) = frame(), frame(texture_return_gain=0.5), \
        frame(texture_return_gain=0.0)  # fmt: skip
    assert len(full) > 300 and len(none) == 0
    assert len(half) / len(full) == pytest.approx(0.5, abs=4.0 * np.sqrt(0.25 / len(full)) + 0.03)
    for wall_returns in (wall_half, wall_none):
        assert len(wall_returns) == len(wall_full)
        assert wall_returns["intensity"].mean() == pytest.approx(wall_full["intensity"].mean(), rel=0.01)
    ghosts, _ = frame(texture_return_gain=0.0, near_field_ghost_per_beam=0.2)
    assert len(ghosts) > 200


def test_textures_blend_over_time():
    profile = simple_profile()
    region = REGISTRY.create("cover", {"texture": "clean", "target_texture": "3l", "blend_start_s": 1.0,
                                       "blend_duration_s": 2.0}, RegionContext(profile))  # fmt: skip
    np.testing.assert_allclose(region.blend_weight(np.array([0.0, 1.0, 2.0, 3.0, 9.0])), [0, 0, 0.5, 1, 1])
    mid = blend(region.textures[0], region.textures[1], 0.5)
    assert mid.mean == pytest.approx(0.5 * (1.0 + region.textures[1].mean), rel=1e-3)


@pytest.mark.parametrize("profile_name", ["scala4", "vlp16"])
def test_the_pattern_table_gives_the_texture_of_each_direction(profile_name):
    """The transmission read from the scan-pattern table by column and channel is the texture sampled
    at the batch's own directions, bit for bit, for every layer of a layered pattern (scala4) and both
    textures of a blend."""
    from lidar_weather_sim.regions.base import RayBatch
    from lidar_weather_sim.sensor.profile import load_profile
    from lidar_weather_sim.sensor.scan import ScanPattern

    profile = load_profile(profile_name)
    region = REGISTRY.create("cover", {"texture": "3l", "target_texture": "5u", "texture_seed": 4},
                             RegionContext(profile))  # fmt: skip
    pattern = ScanPattern(profile)
    rng = np.random.default_rng(2)
    for frame in (0, 1):
        columns = np.sort(rng.choice(pattern.n_columns, 40, replace=False))
        channels = pattern.active_channels(frame)
        dirs = pattern.direction_table(frame)[columns].reshape(-1, pattern.n_subrays, 3)
        n = len(dirs)
        batch = RayBatch(frame, np.zeros((n, 3)), dirs, dirs, np.tile(channels, len(columns)), np.zeros(n),
                         pattern.subray_weight, np.full(dirs.shape[:2], 10.0), np.zeros(dirs.shape),
                         np.zeros(dirs.shape[:2], np.int64), np.zeros(dirs.shape[:2], np.uint32),
                         np.zeros(dirs.shape[:2], np.uint8))  # fmt: skip
        direct = region.texture_samples(batch)
        batch.column = np.repeat(columns, len(channels))
        tabled = region.texture_samples(batch)
        assert len(direct) == 2 and direct[0].std() > 0
        for a, b in zip(direct, tabled):
            assert a.tobytes() == b.tobytes()


def test_forward_scattering_widens_the_beam_and_keeps_its_energy():
    w = np.array([0.25, 0.5, 0.25])
    f = _forward_scatter_factors(w, 0.3)
    assert f[1] == pytest.approx(0.7) and f[0] > 1 and np.sum(w * f) == pytest.approx(1.0)


def test_forward_scattering_acts_once_so_a_wall_behind_a_uniform_dirt_returns_t_squared(tmp_path):
    """The cover's forward scattering moves light off the core sub-ray on the way out; the return crosses the
    cover at its transmission alone. A wall at 20 m that fills a 3 x 3 sub-ray beam, behind a uniform film of
    T = 0.6 with a forward share of 0.35, returns T^2 of the clean wall's peak (thesis line 1333), as without
    the share; squaring the factors with the transmission returned 1.5x that on scala4's sub-rays."""
    from dataclasses import replace

    np.save(tmp_path / "film.npy", np.full((4, 18), 0.6))
    profile = simple_profile(optics={"divergence_h_mrad": 3.0, "divergence_v_mrad": 3.0, "subrays_h": 3,
                                     "subrays_v": 3})  # fmt: skip
    clean = one_frame(_sim(profile)).points
    ratios = {}
    for share in (0.0, 0.35):
        sim = _sim(profile, texture=f"image:{tmp_path / 'film.npy'}")
        region = sim.regions[0][1]
        region.textures = [replace(region.textures[0], forward_share=share)]
        dirty = one_frame(sim).points
        assert len(dirty) == len(clean) == 81
        ratios[share] = _amplitude(dirty["epw"].astype(np.float64)) / _amplitude(clean["epw"].astype(np.float64))
    np.testing.assert_allclose(ratios[0.35], 0.36, rtol=5e-3)
    np.testing.assert_allclose(ratios[0.35], ratios[0.0], rtol=5e-3)


def test_bad_texture_names_the_file_or_key(tmp_path):
    with pytest.raises(ConfigError, match="unknown cover texture '7x'"):
        make_texture("7x", np.random.default_rng(0), 0.03)
    with pytest.raises(ConfigError, match="missing.png: cannot read"):
        image_texture(tmp_path / "missing.png")


@pytest.mark.parametrize("min_range_m", [0.0, 0.3])
def test_the_clean_covers_near_field_ghosts_come_at_their_rate_beyond_the_minimum_range(min_range_m):
    """``near_field_ghost_per_beam`` (effect ``sensor.near_field_ghost``) adds the clean window's cover returns:
    exponential in range (scale ``near_field_scale_m``) over 0-0.5 m, of which those beyond the profile's
    minimum range are reported, each detected when its log-normal peak clears the threshold; the wall keeps
    every return. Measured: 2695 for 2929 expected at 0 m, 114 for 127 at 0.3 m."""
    from scipy.stats import norm

    columns, rate, scale = 16001, 0.2, 0.1
    profile = simple_profile(scan__columns=columns, range__min_m=min_range_m)
    points = one_frame(_sim(profile, seed=5, texture="clean", near_field_ghost_per_beam=rate)).points
    ghosts = points[points["label"] == Label.COVER]
    beyond = (np.exp(-min_range_m / scale) - np.exp(-0.5 / scale)) / (1.0 - np.exp(-0.5 / scale))
    detected = norm.sf(-np.log(3.0) / 0.8)  # median peak 3x the dark threshold, log-sd 0.8 (the region's defaults)
    expected = columns * rate * beyond * detected
    # 4 sigma of Poisson, and 10 % for ghosts that merge into one echo within a pulse width (-8 % at 0 m)
    assert len(ghosts) == pytest.approx(expected, rel=4.0 / np.sqrt(expected) + 0.1)
    assert ghosts["distance"].min() >= min_range_m and ghosts["distance"].max() <= 0.5
    assert np.sum(points["label"] == Label.STATIC) == columns
    assert len(one_frame(_sim(profile, seed=5, texture="clean")).points) == columns  # rate 0: no ghost


def test_window_ghosts_come_at_each_channels_weight():
    """``near_field_ghost_channel_weights`` scales the ghost rate per channel (channel 0 = lowest): weights 0, 1, 3 on
    three layers give no ghost on the first and ~3x as many on the third as on the second; a list of the wrong
    length is refused, naming the parameter."""
    profile = simple_profile(scan__columns=6001, beams=[{"elevation_deg": e} for e in (-1.0, 0.0, 1.0)])
    points = one_frame(_sim(profile, seed=4, texture="clean", near_field_ghost_per_beam=0.1,
                            near_field_ghost_channel_weights=[0.0, 1.0, 3.0])).points  # fmt: skip
    per_channel = np.bincount(points["channel"][points["label"] == Label.COVER], minlength=3)
    assert per_channel[0] == 0 and per_channel[1] > 100
    assert per_channel[2] / per_channel[1] == pytest.approx(3.0, rel=0.15), per_channel
    with pytest.raises(ConfigError, match="near_field_ghost_channel_weights"):
        _sim(profile, texture="clean", near_field_ghost_per_beam=0.1, near_field_ghost_channel_weights=[1.0, 2.0])


def test_a_weather_behind_the_cover_returns_through_its_transmission_twice_with_the_forward_scatter_once():
    """What a fog or rain spread along a beam returns through the cover (the reference's cover term):
    1 for a clean cover; for a dirt with a forward share > 0 each beam's mean over its sub-rays of T^2 times
    the forward-scatter factor: the scattered light still lights the weather, on the outer sub-rays, so a dirt
    of mean T 0.66 returns ~T^2 = 0.44 (0.19 when the scattered light was counted lost both ways)."""
    from lidar_weather_sim.sensor.profile import load_profile
    from lidar_weather_sim.sensor.scan import ScanPattern

    profile = load_profile("scala4")
    clean = REGISTRY.create("cover", {"texture": "clean"}, RegionContext(profile)).beam_two_way()
    pattern = ScanPattern(profile)
    assert clean.shape == (pattern.n_columns, pattern.n_channels)
    np.testing.assert_allclose(clean, 1.0, rtol=1e-12)
    region = REGISTRY.create("cover", {"texture": "dirt:0.66"}, RegionContext(profile))
    assert region.textures[0].forward_share > 0.1
    two_way = region.beam_two_way()
    assert two_way.mean() == pytest.approx(0.66**2, rel=0.05)
    assert two_way.std() > 0.01  # the texture's spots: beams differ


def test_a_dirt_at_contrast_0_is_a_uniform_film_that_darkens_every_direction_alike():
    """``texture_contrast`` scales the dirt's patches around its mean transmission: at 1 (the default) a generic
    dirt of 0.7 darkens the wall at 20 m by T^2 of the patch each direction looks through (one-way, 5.9 % apart
    between the darkest and the clearest of the 81 directions over 20 deg); at 0 it is a uniform film of the same
    mean, every return at 0.7^2 of the clean wall's peak, as the fixed generators' cover (T^2 on every return)
    makes it; at 0.5 the spread is halved."""
    profile = simple_profile()
    clean = _amplitude(one_frame(_sim(profile)).points["epw"].astype(np.float64))
    ratios, means = {}, {}
    for contrast in (1.0, 0.5, 0.0):
        sim = _sim(profile, texture="dirt:0.7", forward_share=0.0, texture_return_gain=0.0, texture_contrast=contrast)
        dirty = one_frame(sim).points
        assert len(dirty) == len(clean) == 81
        ratios[contrast] = _amplitude(dirty["epw"].astype(np.float64)) / clean
        means[contrast] = sim.regions[0][1].textures[0].mean
    assert means[1.0] == pytest.approx(0.7, abs=1e-9) and means[0.0] == pytest.approx(0.7, abs=1e-9)
    np.testing.assert_allclose(ratios[0.0], 0.49, rtol=5e-3)
    spread = {c: np.sqrt(r).max() / np.sqrt(r).min() - 1.0 for c, r in ratios.items()}
    assert spread[1.0] > 0.03 and spread[0.0] < 1e-4, spread
    assert spread[0.5] == pytest.approx(0.5 * spread[1.0], rel=0.15), spread


def test_the_dirt_effects_contrast_goes_to_the_cover_and_is_refused_outside_0_to_1():
    from lidar_weather_sim.scenario.effects import apply_effects, parse_effect
    from lidar_weather_sim.scenario.schema import load_scenario

    film = parse_effect("cover.dirt:transmission=0.7,forward=0,contrast=0")
    params = apply_effects(load_scenario("highway_clear"), [film.with_value(0.65)]).region_params["cover"]
    assert params["texture"] == "dirt:0.65" and params["texture_contrast"] == 0.0 and params["forward_share"] == 0.0
    with pytest.raises(ValueError, match="'contrast' scales the dirt's patches around its mean .* got 1.5"):
        parse_effect("cover.dirt:transmission=0.7,contrast=1.5")
