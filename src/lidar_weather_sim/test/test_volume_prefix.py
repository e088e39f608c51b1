"""The volume's echoes shared by the beams of a group (lidar_weather_sim.sensor.volume_prefix) against the echo
stage sampling every beam on its own (``shared_prefix=False``): the same echoes bit for bit, on seeded draws of
beams (tables, scales, hard targets, pulses near the boundary of the shared part) and on simulated frames."""

from __future__ import annotations

import numpy as np
import pytest

from lidar_weather_sim.scenario.schema import load_scenario
from lidar_weather_sim.scenario.world import World
from lidar_weather_sim.sensor import echo
from lidar_weather_sim.sensor.echo import detect_echoes
from lidar_weather_sim.sensor.profile import load_profile
from lidar_weather_sim.sensor.radiometry import FWHM_TO_SIGMA, MIN_RANGE_M, Threshold
from lidar_weather_sim.sensor import volume_prefix
from lidar_weather_sim.sensor.volume_prefix import build_prefix
from lidar_weather_sim.sensor.volume_tables import build_table, stack_volume
from lidar_weather_sim.sim.simulator import LidarSimulator
from lidar_weather_sim.testing.lidar_integral import medium_return

FIELDS = ("beam", "echo", "range_m", "amplitude", "epw_m", "label", "object_id")


def written(echoes) -> dict[str, np.ndarray]:
    take = np.concatenate([np.arange(a, a + c) for a, c in zip(*echoes.runs)] + [np.zeros(0, np.int64)])
    return {name: getattr(echoes, name)[take] for name in FIELDS}


def assert_same_echoes(candidates, **kwargs) -> dict[str, np.ndarray]:
    shared = written(detect_echoes(*candidates, shared_prefix=True, **kwargs))
    alone = written(detect_echoes(*candidates, shared_prefix=False, **kwargs))
    for name in FIELDS:
        np.testing.assert_array_equal(shared[name], alone[name], err_msg=name)
    return shared


def table(profile, kind: str, value: float):
    v = medium_return(profile, kind, value)
    dark = Threshold.under_sun(profile.detection)
    return build_table(v.density, sigma_m=v.sigma_m, r_max_m=float(profile.range.max_m),
                       label=3 if kind == "fog" else 4, start_m=max(v.overlap_start_m, MIN_RANGE_M),
                       tau_m=float(profile.detection.ac_coupling_tau_m), floor=0.02 * dark.level)  # fmt: skip


@pytest.mark.parametrize("profile_name, seed", [("os1_128_2048", 1), ("os1_128_2048", 2), ("scala4", 3)])
def test_shared_echoes_are_every_beams_own_on_seeded_draws(profile_name, seed):
    """400 beams of two layers (three fog tables of 40-60 m, a rain table of 10 mm/h), scales from a few values
    (groups) or drawn per beam (none), hard targets anywhere or none, and pulses: the target's, drops in the near
    field, and faint ones placed where they just reach the shared part. Every echo equal, and the near-field fog
    echo of most beams found in the groups."""
    profile = load_profile(profile_name)
    rng = np.random.default_rng(seed)
    tables = [table(profile, "fog", vr) for vr in (40.0, 50.0, 60.0)] + [table(profile, "rain", 10.0)]
    threshold = Threshold.under_sun(profile.detection)
    thr = threshold.level
    n = 400
    layers = np.stack([rng.integers(0, 3, n), np.where(rng.random(n) < 0.5, 3, -1)], axis=1)
    scale = np.where(rng.random((n, 1)) < 0.8, rng.choice([1.0, 0.7], (n, 1)), rng.uniform(0.3, 1.0, (n, 1)))
    scale = np.repeat(scale, 2, axis=1)
    hit = np.where(rng.random(n) < 0.7, rng.uniform(0.5, 60.0, n), np.inf)
    volume = stack_volume(tables, layers, scale, np.repeat(hit[:, None], 2, axis=1))
    beams, ranges, amps = [], [], []
    s = float(profile.pulse.fwhm_m) / 2.3548
    for b in range(n):
        if np.isfinite(hit[b]):
            beams.append(b), ranges.append(hit[b]), amps.append(thr * 10 ** rng.uniform(-1, 3))
        for _ in range(rng.integers(0, 3)):  # drops
            beams.append(b), ranges.append(rng.uniform(0.3, 15.0)), amps.append(thr * rng.uniform(0.05, 3.0))
        if rng.random() < 0.3:  # faint, its reach to 1e-20 of the threshold ending a few samples from anywhere
            a = thr * 10 ** rng.uniform(-25, -5)
            reach = s * np.sqrt(2 * np.log(a / (thr * 1e-20))) if a > thr * 1e-20 else 0.0
            beams.append(b), ranges.append(rng.uniform(1.0, 20.0) + reach), amps.append(a)
    k = len(beams)
    candidates = (np.array(beams, np.int64), np.array(ranges), np.array(amps), np.ones(k, np.uint8),
                  np.arange(k, dtype=np.uint32))  # fmt: skip
    got = assert_same_echoes(candidates, threshold=threshold, fwhm_m=profile.pulse.fwhm_m, resolution_m=0.0,
                             max_echoes=profile.detection.max_echoes, volume=volume)  # fmt: skip
    detector = echo.Detector(thr, s, 0.0, profile.detection.max_echoes)
    prefix = build_prefix(volume, detector, lambda v: echo._group_echoes(v, detector))
    assert (prefix.group >= 0).mean() > 0.6  # the groups are used: the test compares the shared path
    assert len(prefix.over_first) >= 3  # ... with their near-field echoes
    fog_echoes = np.unique(got["beam"][(got["label"] == 3) & (got["range_m"] < 10.0)])
    assert len(fog_echoes) > 0.5 * n


def fog_batch(tables, rng, n: int, scales) -> tuple[tuple, object]:
    """Candidates and volume of ``n`` beams on ``tables`` (one fog layer, table 0-2, scale drawn from
    ``scales``), a hard target on 70 % of them (amplitude 0.1-1000 thresholds at 0.5-60 m)."""
    layers = rng.integers(0, len(tables), (n, 1))
    scale = rng.choice(scales, (n, 1))
    hit = np.where(rng.random(n) < 0.7, rng.uniform(0.5, 60.0, n), np.inf)
    volume = stack_volume(tables, layers, scale, hit[:, None])
    beams = np.flatnonzero(np.isfinite(hit))
    candidates = (beams.astype(np.int64), hit[beams], 10 ** rng.uniform(-1, 3, len(beams)),
                  np.ones(len(beams), np.uint8), np.arange(len(beams), dtype=np.uint32))  # fmt: skip
    return candidates, volume


def test_a_later_batch_of_the_same_tables_reads_the_groups_kept_and_finds_every_beams_own_echoes(monkeypatch):
    """The groups' echoes are kept per stack of tables and receiver: a second batch of the same tables (a later
    batch of the same weather) computes no group it met before, uses them even for a beam alone in its group,
    and its echoes equal those of every beam sampled alone; when more groups come than are kept
    (``GROUPS``), a batch's new ones serve that batch alone, the echoes still the same."""
    profile = load_profile("os1_128_2048")
    tables = [table(profile, "fog", vr) for vr in (40.0, 50.0, 60.0)]
    threshold = Threshold.under_sun(profile.detection)
    sigma = float(profile.pulse.fwhm_m) * FWHM_TO_SIGMA  # the receiver as detect_echoes keys its groups
    detector = echo.Detector(float(threshold.level), sigma, 0.0, int(profile.detection.max_echoes))
    kwargs = dict(threshold=threshold, fwhm_m=profile.pulse.fwhm_m, resolution_m=0.0,
                  max_echoes=profile.detection.max_echoes)  # fmt: skip
    made = []
    group_prefixes = volume_prefix._group_prefixes
    monkeypatch.setattr(volume_prefix, "_group_prefixes",
                        lambda v, t, *a: made.append(len(t)) or group_prefixes(v, t, *a))  # fmt: skip
    rng = np.random.default_rng(7)
    candidates, volume = fog_batch(tables, rng, 300, [1.0, 0.8, 0.6])
    assert_same_echoes(candidates, volume=volume, **kwargs)
    assert sum(made) == 9  # three tables at three scales, each group found once for the batch
    made.clear()
    candidates, volume = fog_batch(tables, rng, 300, [1.0, 0.8, 0.6])
    _, one_each = np.unique(np.concatenate([volume.table, volume.scale], axis=1), axis=0, return_index=True)
    later = volume._replace(table=volume.table[one_each], scale=volume.scale[one_each], hit_m=volume.hit_m[one_each])
    alone = build_prefix(later, detector, lambda v: echo._group_echoes(v, detector))  # each beam its own group
    assert len(one_each) == 9 and (alone.group >= 0).all()
    assert_same_echoes(candidates, volume=volume, **kwargs)
    assert made == []  # nothing new: every group was kept
    monkeypatch.setattr(volume_prefix._StackGroups, "GROUPS", 20)
    for _ in range(3):  # 30 scales a batch, 3 tables: more groups than kept
        candidates, volume = fog_batch(tables, rng, 400, rng.uniform(0.3, 1.0, 30))
        assert_same_echoes(candidates, volume=volume, **kwargs)
        assert (build_prefix(volume, detector, lambda v: echo._group_echoes(v, detector)).group >= 0).mean() > 0.5
        kept = volume_prefix._StackGroups.of(volume, tuple(detector))
        assert 9 <= len(kept.index) <= 20 and len(kept.usable) == len(kept.index)


FOG_50 = {"fog": {"visual_range_m": 50.0}}
SNOW_5 = {"precipitation": {"type": "snow", "intensity_mm_h": 5.0}}  # scala4's optics see no volume in snow
FOG_150_RAIN_10 = {"fog": {"visual_range_m": 150.0}, "precipitation": {"type": "rain", "intensity_mm_h": 10.0}}


@pytest.mark.parametrize("profile_name, weather", [("os1_128_1024", FOG_50), ("scala4", FOG_50),
                                                   ("os1_128_1024", SNOW_5), ("os1_128_1024", FOG_150_RAIN_10),
                                                   ("scala4", FOG_150_RAIN_10)],
                         ids=["os1 fog 50m", "scala4 fog 50m", "os1 snow 5", "os1 fog 150m + rain 10",
                              "scala4 fog 150m + rain 10"])  # fmt: skip
def test_a_simulated_frame_has_the_same_echoes_with_shared_prefixes(profile_name, weather, monkeypatch):
    """One frame of highway_clear in the weather, a dirty cover on: each batch's echoes with and without the
    groups' echoes equal."""
    base = load_scenario("highway_clear").model_dump()
    base["weather"]["fog"] = {**base["weather"].get("fog", {}), "visual_range_m": 100000.0}
    for key, value in weather.items():
        base["weather"][key] = {**base["weather"].get(key, {}), **value}
    base["regions"] = ["cover", "atmosphere"]
    base["region_params"] = {"cover": {"texture": "3l"}}
    scenario = type(load_scenario("highway_clear")).model_validate(base)
    world = World.build(scenario, profile_name)
    sim = LidarSimulator.of_world(world)
    batches = []

    def both(candidates, segments, volume=None):
        profile = sim.profile
        kwargs = dict(threshold=sim.threshold(), fwhm_m=profile.pulse.fwhm_m, resolution_m=profile.range.resolution_m,
                      max_echoes=profile.detection.max_echoes, segments=segments, volume=volume)  # fmt: skip
        if volume is not None:
            batches.append(len(assert_same_echoes(candidates, **kwargs)["beam"]))
        return detect_echoes(*candidates, scratch=sim._scratch, **kwargs)

    monkeypatch.setattr(sim, "_echoes", both)
    t, done = 0.0, []
    while not done:
        t = round(t + 0.01, 9)
        done = sim.advance(t, world.player)
    assert batches and sum(batches) > 0  # batches with volumes were compared
