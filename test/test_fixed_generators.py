"""The weather generators fixed before use (references/generators): each against its own first-principles
specification on synthetic points: Beer-Lambert loss and the threshold, the soft echoes' range laws and shares,
the drop counts and diameter laws, seeds, parameter checks."""

from __future__ import annotations

import numpy as np
import pytest
from scipy import stats

from lidar_weather_sim.core.points import Label, empty_points
from lidar_weather_sim.io.cloud_codec import encode
from lidar_weather_sim.references.generators.cover import DirtyCover
from lidar_weather_sim.references.generators.echoes import Receiver
from lidar_weather_sim.references.generators.fog_loss import FogLoss
from lidar_weather_sim.references.generators.fog_shell import FogShell
from lidar_weather_sim.references.generators.fog_spread import FogSpread
from lidar_weather_sim.references.generators.precip_dsd import PrecipDSD, size_law
from lidar_weather_sim.sensor.profile import load_profile

LN_DR = float(np.log(1e4))


@pytest.fixture(scope="module")
def rx():
    return Receiver.of(load_profile("scala4"))


def _beams(n: int, ranges_m, intensity, seed: int = 0) -> np.ndarray:
    """One return on each of ``n`` beams (channel, time stamp distinct) at ``ranges_m`` with ``intensity``."""
    rng = np.random.default_rng(seed)
    pts = empty_points(n)
    r = np.broadcast_to(np.asarray(ranges_m, np.float64), (n,))
    az = rng.uniform(-1.0, 1.0, n)
    pts["x"], pts["y"], pts["z"] = r * np.cos(az), r * np.sin(az), 0.0
    pts["distance"], pts["azimuth"] = r, az
    pts["channel"] = np.arange(n) % 4
    pts["time_stamp"] = np.arange(n) // 4
    pts["intensity"] = np.broadcast_to(np.asarray(intensity), (n,))
    pts["epw"] = 0.5
    pts["label"] = Label.STATIC
    return pts


def test_fog_loss_keeps_exactly_the_returns_above_the_threshold_and_scales_them_by_beer_lambert(rx):
    rng = np.random.default_rng(1)
    n = 2000
    ranges, intensity = rng.uniform(1.0, 150.0, n), rng.integers(0, 255, n)
    pts = _beams(n, ranges, intensity)
    alpha = 3.912 / 80.0
    out = FogLoss(rx, 80.0).apply(pts, rng)
    ratio = pts["intensity"] / 255.0 * LN_DR - 2 * alpha * pts["distance"].astype(np.float64)
    kept = ratio >= 0
    assert len(out) == kept.sum() and 0 < kept.sum() < n
    assert np.array_equal(out["distance"], pts["distance"][kept])
    assert np.array_equal(out["intensity"], np.rint(255 * ratio[kept] / LN_DR).astype(np.uint8))
    # received power A / T = DR^(I/255): the kept returns' power ratio is exp(-2 alpha R) within the byte's step
    power = np.exp((out["intensity"].astype(float) - pts["intensity"][kept]) / 255 * LN_DR)
    assert np.allclose(power, np.exp(-2 * alpha * out["distance"]), rtol=LN_DR / 255)
    assert np.allclose(out["epw"], 0.5 * np.sqrt(ratio[kept] / (pts["intensity"][kept] / 255.0 * LN_DR)), atol=1e-6)


def test_fog_spread_echoes_follow_the_range_law_in_0_6_to_5_m_and_grow_with_density(rx):
    n = 20000
    pts = _beams(n, 60.0, 250)
    counts = {}
    for v in (400.0, 100.0, 40.0):
        gen = FogSpread(rx, v)
        out = gen.apply(pts, np.random.default_rng(3))
        fog = out[out["label"] == Label.FOG]
        counts[v] = len(fog)
        assert len(fog) == pytest.approx(n * (1 - np.exp(-gen.alpha * 15.0)), abs=4 * np.sqrt(n * 0.25))
        r = fog["distance"].astype(np.float64)
        assert r.min() >= 0.6 and r.max() <= 5.0
        assert stats.kstest(r, gen.cdf).pvalue > 1e-3
        # the law itself: w(r) exp(-2 alpha r) / r^2, w a 0.6-1.5 m ramp
        x = np.array([1.0, 2.0, 4.0])
        want = np.clip((x - 0.6) / 0.9, 0, 1) * np.exp(-2 * gen.alpha * x) / x**2
        assert np.allclose(gen.density(x) / gen.density(2.0), want / want[1])
    assert counts[400.0] < counts[100.0] < counts[40.0]
    # a wrong law is rejected: echoes uniform over 0.6-5 m fail the same test
    uniform = np.random.default_rng(4).uniform(0.6, 5.0, 3000)
    assert stats.kstest(uniform, FogSpread(rx, 100.0).cdf).pvalue < 1e-6


def test_fog_shell_echoes_lie_in_a_0_3_m_shell_that_moves_in_with_density(rx):
    n = 20000
    pts = _beams(n, 60.0, 250)
    shells = []
    for v in (400.0, 40.0):
        gen = FogShell(rx, v)
        fog = gen.apply(pts, np.random.default_rng(5))
        fog = fog[fog["label"] == Label.FOG]
        r = fog["distance"].astype(np.float64)
        assert gen.shell_m == pytest.approx(1.0 + 3.0 * np.exp(-gen.alpha * 25.0))
        assert r.min() >= gen.shell_m - 1e-5 and r.max() <= gen.shell_m + 0.3 + 1e-5
        assert len(fog) == pytest.approx(n * min(0.9, gen.alpha * 8.0), abs=4 * np.sqrt(n * 0.25))
        shells.append(gen.shell_m)
    assert shells[1] < shells[0]


def test_soft_echoes_only_before_the_beams_nearest_return(rx):
    pts = _beams(4000, 1.0, 250)
    out = FogSpread(rx, 40.0).apply(pts, np.random.default_rng(6))
    assert (out["distance"][out["label"] == Label.FOG] < 1.0).all()


@pytest.mark.parametrize("kind, rate", [("rain", 2.0), ("rain", 30.0), ("snow", 0.5), ("snow", 4.0)])
def test_precip_drop_counts_are_the_laws_integral_times_the_volume_and_diameters_follow_the_law(rx, kind, rate):
    gen = PrecipDSD(rx, kind, rate)
    far = np.random.default_rng(7).uniform(2.0, 30.0, 20000)
    beam, r, d = gen.drops(far, np.random.default_rng(8))
    reach = np.minimum(far, gen.reach_m)
    # n = int N(D) dD by an independent quadrature; V the cone (a + theta r) between near and reach
    grid = np.linspace(*{"rain": (0.1, 6.0), "snow": (0.1, 5.0)}[kind], 200001)
    n = np.trapezoid(size_law(kind, rate, grid), grid)
    th, a = rx.divergence_rad, rx.aperture_m
    volume = np.pi / (12 * th) * ((a + th * reach) ** 3 - (a + th * gen.near_m) ** 3)
    expected = n * volume.sum()
    assert len(beam) == pytest.approx(expected, abs=5 * np.sqrt(expected))
    assert (r >= gen.near_m).all() and (r <= reach[beam] + 1e-9).all()
    assert stats.kstest(d, gen.cdf).pvalue > 1e-3
    # the law's shape: exponential (Sekhon-Srivastava) for snow, D^2 exp(-Lambda D) for rain
    if kind == "snow":
        assert size_law(kind, rate, 1.0) == pytest.approx(2.5e3 * rate**-0.94 * np.exp(-2.29 * rate**-0.45))
    else:
        lam = 5.67 / (0.9 * rate**0.21)
        assert size_law(kind, rate, 2.0) / size_law(kind, rate, 1.0) == pytest.approx(4 * np.exp(-lam))
        v = np.maximum(9.65 - 10.3 * np.exp(-0.6 * grid), 0)
        assert 6e-4 * np.pi * np.trapezoid(grid**3 * v * size_law(kind, rate, grid), grid) == pytest.approx(rate, 1e-3)


def test_precip_echoes_are_the_drops_above_the_threshold_and_their_loss_is_small(rx):
    gen = PrecipDSD(rx, "rain", 20.0)
    pts = _beams(5000, 40.0, 200)
    out = gen.apply(pts, np.random.default_rng(9))
    rain = out[out["label"] == Label.RAIN]
    assert len(rain) > 0 and (rain["distance"] < gen.reach_m).all()
    assert gen.alpha < 0.01  # 1/m: the rain's extinction is small
    hard = out[out["label"] == Label.STATIC]
    assert len(hard) >= 0.99 * len(pts)  # 2 alpha R < 0.15: bright returns stay unless three drops come first
    # a drop's peak: C pi sigma_b / (pi (a + theta r)^2 / 4) w(r) exp(-2 alpha r) / r^2, sigma_b = F D^2 / 16
    beam, r, d = gen.drops(np.full(5000, 40.0), np.random.default_rng(10))
    sigma = (0.328 / 2.328) ** 2 * (d * 1e-3) ** 2 / 16
    peak = rx.power_constant * np.pi * sigma / (np.pi / 4 * (rx.aperture_m + rx.divergence_rad * r) ** 2)
    peak *= np.clip((r - 0.5) / 1.3, 0, 1) * np.exp(-2 * gen.alpha * r) / r**2
    assert np.allclose(gen.peak(r, d), peak)
    assert len(rain) <= (peak >= rx.threshold).sum() * 1.1 and len(rain) >= (peak >= rx.threshold).sum() * 0.9


def test_dirty_cover_lowers_every_return_by_the_two_way_transmission(rx):
    pts = _beams(1000, np.linspace(1, 100, 1000), np.arange(1000) % 256)
    out = DirtyCover(rx, 0.8).apply(pts, np.random.default_rng(0))
    ratio = pts["intensity"] / 255.0 * LN_DR + 2 * np.log(0.8)
    assert len(out) == (ratio >= 0).sum()
    assert np.array_equal(out["intensity"], np.rint(255 * ratio[ratio >= 0] / LN_DR).astype(np.uint8))


@pytest.mark.parametrize("make", [lambda rx: FogSpread(rx, 60.0), lambda rx: FogShell(rx, 60.0),
                                  lambda rx: PrecipDSD(rx, "snow", 2.0), lambda rx: FogLoss(rx, 60.0)])
def test_same_seed_same_output(rx, make):
    pts = _beams(3000, np.linspace(2, 80, 3000), 180)
    gen = make(rx)
    a, b = (gen.apply(pts, np.random.default_rng(42)) for _ in range(2))
    c = gen.apply(pts, np.random.default_rng(43))
    same = [np.array_equal(a[f], b[f]) for f in a.dtype.names]
    assert len(a) == len(b) and all(same)
    assert encode(a).data == encode(b).data  # as written to a bag: byte for byte
    assert isinstance(gen, FogLoss) or len(a) != len(c) or not all(np.array_equal(a[f], c[f]) for f in a.dtype.names)


@pytest.mark.parametrize("make, name", [(lambda rx: FogLoss(rx, -5.0), "visual_range_m"),
                                        (lambda rx: FogSpread(rx, 5000.0), "visual_range_m"),
                                        (lambda rx: FogShell(rx, 0.0), "visual_range_m"),
                                        (lambda rx: PrecipDSD(rx, "rain", 80.0), "rate_mm_h"),
                                        (lambda rx: PrecipDSD(rx, "snow", 0.01), "rate_mm_h"),
                                        (lambda rx: PrecipDSD(rx, "hail", 1.0), "kind"),
                                        (lambda rx: DirtyCover(rx, 1.5), "transmission")])
def test_bad_parameters_name_themselves(rx, make, name):
    with pytest.raises(ValueError, match=f"^{name}: ") as info:
        make(rx)
    assert "\n" not in str(info.value)


def test_single_return_mode_reports_one_echo_per_beam():
    rx = Receiver.of(load_profile("scala4").with_return_mode("first"))
    pts = _beams(4000, 30.0, 250)
    out = FogSpread(rx, 40.0).apply(pts, np.random.default_rng(2))
    assert len(out) == len(pts)
    assert ((out["label"] == Label.FOG).mean()) == pytest.approx(1 - np.exp(-3.912 / 40 * 15), abs=0.05)


def test_the_committed_draw_is_the_seeded_one_and_covers_every_generator_and_both_profiles():
    import yaml

    from lidar_weather_sim.core.paths import config_dir
    from lidar_weather_sim.references.generators.draw import SEED, draw_cases

    committed = yaml.safe_load((config_dir() / "generator_draw.yaml").read_text())
    assert committed["seed"] == SEED and committed["cases"] == draw_cases(SEED)
    cases = committed["cases"]
    assert len(cases) >= 40
    assert {c["generator"] for c in cases} == {"fog_loss", "fog_spread", "fog_shell", "precip_dsd"}
    assert {c["profile"] for c in cases} == {"scala4", "os1_128_1024"}
    bounds = {"atmosphere.fog": (40, 400), "atmosphere.rain": (2, 40), "atmosphere.snow": (0.5, 5)}
    for c in cases:
        lo, hi = bounds[c["effect"]]
        assert lo <= c["value"] <= hi
        assert c["cover"] is None or 0.6 <= c["cover"] <= 0.9
    for effect in bounds:  # each effect alone and behind a dirty cover, on both profiles
        for profile in ("scala4", "os1_128_1024"):
            covers = {c["cover"] is None for c in cases if c["effect"] == effect and c["profile"] == profile}
            assert covers == {True, False}


@pytest.mark.parametrize("hide, words", [(["atmosphere.rain:intensity=80"], "rate_mm_h: rain rate"),
                                         (["atmosphere.fog:visual_range=20", "sensor.sun:irradiance=300"], "makes one of"),
                                         (["atmosphere.rain:intensity=5", "atmosphere.snow:intensity=1"], "makes one of")])
def test_make_measured_refuses_bad_parameters_in_one_line_with_exit_2(capsys, hide, words):
    from lidar_weather_sim.cli import main

    argv = ["make-measured", "highway_clear", "--generator", "precip_dsd", "--out", "/nonexistent"]
    for h in hide:
        argv += ["--hide", h]
    assert main(argv) == 2
    err = capsys.readouterr().err.strip()
    assert words in err and "\n" not in err


def test_fixed_transform_puts_the_weather_then_the_cover_on_each_frame(rx):
    from types import SimpleNamespace

    from lidar_weather_sim.references.measured import fixed_transform
    from lidar_weather_sim.scenario.effects import parse_effect

    pts = _beams(4000, np.linspace(2, 80, 4000), 200)
    effects = [parse_effect("atmosphere.fog:visual_range=60"), parse_effect("cover.dirt:transmission=0.7")]
    transform = fixed_transform(effects, "fog_shell", load_profile("scala4"), np.random.default_rng(1))
    out = transform(SimpleNamespace(points=pts))
    want = DirtyCover(rx, 0.7).apply(FogShell(rx, 60.0).apply(pts, np.random.default_rng(1)), None)
    assert all(np.array_equal(out[f], want[f]) for f in pts.dtype.names)
    assert fixed_transform([], "fog_loss", load_profile("scala4"), np.random.default_rng(1)) is None
