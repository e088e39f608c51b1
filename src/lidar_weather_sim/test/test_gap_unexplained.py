"""The judgement after the gap search (lidar_weather_sim.gap.unexplained), on signatures built from arrays (no
simulation): which zones' residuals the counting noise cannot explain, their shapes, and the naming rule."""

import numpy as np
import pytest

from lidar_weather_sim.gap.search import Candidate, Diagnosis, rivals
from lidar_weather_sim.gap.signatures import RANGE_EDGES, Signature, gap_value
from lidar_weather_sim.gap.unexplained import (
    BANDS,
    MIN_RELATIVE,
    at_weak_end,
    judge_effects,
    removes_its_residual,
    zone_residuals,
)
from lidar_weather_sim.scenario.effects import parse_effect

FRAMES = 10
SUN, FOG, DIRT = (parse_effect(t) for t in ("sensor.sun:irradiance=400", "atmosphere.fog:visual_range=150",
                                            "cover.dirt:transmission=0.7"))  # fmt: skip


def signature(zones: dict[str, list[float]], frames: int = FRAMES) -> Signature:
    """A signature whose zones hold the given returns (sums over ``frames``) per band of :data:`BANDS`, each band's
    returns in the range bin at its middle (unit weights: squares = sums)."""
    sig = Signature(channels=1, frames=frames)
    for zone, counts in zones.items():
        edges = RANGE_EDGES[zone]
        hist = np.zeros(len(edges) - 1)
        for (lo, hi), count in zip(BANDS[zone], counts):
            hist[np.searchsorted(edges, 0.5 * (lo + hi)) - 1] += count
        sig.sums[f"{zone}/range"], sig.squares[f"{zone}/range"] = hist, hist.copy()
    return sig


SIMULATED = {"far": [1000.0] * 4, "road": [1000.0] * 4, "near": [0.0], "cover": [0.0]}
ONE_SIGMA = 1000.0 - (np.sqrt(8001.0) - 1.0) / 2.0  # a band 1 sigma low: (1000 - M) / sqrt(1000 + M) = 1
#: far field: the last band at exactly 10 sigma ((1000 - 600) / sqrt(1600)), the loss growing with range;
#: road: every band 1 sigma low; near field: 100 returns in 10 frames where the model has none (10 sigma)
MEASURED = {"far": [1000.0, 950.0, 800.0, 600.0], "road": [ONE_SIGMA] * 4, "near": [100.0], "cover": [0.0]}


def test_a_zone_at_10_sigma_is_unexplained_with_its_shape_and_one_at_1_sigma_is_not():
    residuals = zone_residuals(signature(MEASURED), signature(SIMULATED))
    far, near, road = residuals["far"], residuals["near"], residuals["road"]
    assert far.significant and far.sigma == pytest.approx(10.0)
    assert far.shape == "loss growing with range" and far.text() == "far field, loss growing with range"
    assert far.relative == pytest.approx(3350.0 / 4000.0 - 1.0)
    assert [b.significant for b in far.bands] == [False, False, True, True]  # 0, 1.1, 4.7 and 10 sigma
    assert near.significant and near.sigma == pytest.approx(10.0) and near.shape == "excess returns"
    assert not road.significant and max(b.sigma for b in road.bands) == pytest.approx(1.0)
    assert not residuals["cover"].significant and not residuals["wake"].significant  # empty on both sides


@pytest.mark.parametrize("measured, shape", [([800.0, 800.0, 800.0, 800.0], "uniform loss"),
                                             ([1000.0, 1000.0, 1300.0, 1800.0], "excess growing with range"),
                                             ([1800.0, 1300.0, 1000.0, 1000.0], "excess falling with range"),
                                             ([500.0, 800.0, 950.0, 1000.0], "loss falling with range")])  # fmt: skip
def test_the_shape_of_a_range_zone_is_the_sign_and_trend_of_measured_over_simulated(measured, shape):
    assert zone_residuals(signature({"far": measured}), signature({"far": [1000.0] * 4}))["far"].shape == shape


def test_a_significant_change_below_the_stated_share_of_a_bands_returns_is_not_unexplained():
    big = 1e6  # 0.5 % fewer returns: 3.5 sigma of the counting noise, but below MIN_RELATIVE
    assert MIN_RELATIVE > 0.005
    far = zone_residuals(signature({"far": [big * 0.995] * 4}), signature({"far": [big] * 4}))["far"]
    assert far.bands[0].sigma > 3.0 and not far.significant


def _simulate(table: dict[frozenset, dict[str, list[float]]]):
    return lambda effects: signature(table[frozenset(e.name for e in effects)])


def test_an_effect_that_shrinks_the_total_gap_but_leaves_its_own_zones_residual_is_not_named():
    measured = signature(MEASURED | {"road": [1000.0] * 4})
    # the sun's threshold loss takes 15 % of every band: the total gap shrinks, the far field's shape is left
    with_sun = SIMULATED | {"far": [850.0] * 4}
    table = {frozenset(): SIMULATED, frozenset({SUN.name}): with_sun}
    assert gap_value(measured, signature(with_sun)) < gap_value(measured, signature(SIMULATED))
    judgement = judge_effects([SUN], measured, _simulate(table))
    assert judgement.named == [] and [e for e, _ in judgement.refused] == [SUN]
    assert judgement.refused[0][1].startswith("leaves far field, ")
    unexplained = {r.zone: r.shape for r in judgement.unexplained}
    assert unexplained == {"far": "loss growing with range", "near": "excess returns"}  # without the sun


def test_an_effect_that_removes_its_zones_residual_is_named_and_leaves_only_the_others():
    measured = signature(MEASURED | {"road": [1000.0] * 4})
    with_fog = SIMULATED | {"far": [1000.0, 948.0, 805.0, 596.0], "near": [96.0]}
    table = {frozenset(): SIMULATED, frozenset({FOG.name}): with_fog}
    judgement = judge_effects([FOG], measured, _simulate(table))
    assert judgement.named == [FOG] and judgement.refused == [] and judgement.unexplained == []


def test_an_effect_that_does_not_beat_another_by_the_searchs_margin_is_not_named_and_what_it_took_is_reported():
    """The fog of the test above, but in the round it won a sun came within the margin a new effect must win (the
    fog's held-out gap not 10 % below the sun's): by the search's own standard the data did not tell them apart, so
    neither is a name. Candidates of the same effect (the fog at another backscatter gain) and a sun the fog beats
    by the margin do not count."""
    measured = signature(MEASURED | {"road": [1000.0] * 4})
    with_fog = SIMULATED | {"far": [1000.0, 948.0, 805.0, 596.0], "near": [96.0]}
    table = {frozenset(): SIMULATED, frozenset({FOG.name}): with_fog}
    fog, other_gain = Candidate(FOG, 0.011, 0.010, 9), Candidate(FOG.with_value(120.0), 0.012, 0.0101, 9)
    close_sun, far_sun = Candidate(SUN, 0.02, 0.0105, 9), Candidate(SUN, 0.03, 0.0115, 9)
    diag = Diagnosis(0.1, 0.010, accepted=[(fog, 0.1)], rounds=[[other_gain, fog, close_sun]])
    found = rivals(diag, lambda gap: 0.9 * gap)  # 0.010 > 0.9 x 0.0105: the fog does not beat this sun by 10 %
    assert found == [[close_sun]]
    judgement = judge_effects([FOG], measured, _simulate(table), rivals=found)
    assert judgement.named == [] and judgement.refused[0][1].startswith("not told apart from sensor.sun")
    assert {r.zone for r in judgement.unexplained} == {"far", "near"}
    diag.rounds = [[other_gain, fog, far_sun]]  # 0.010 <= 0.9 x 0.0115
    assert rivals(diag, lambda gap: 0.9 * gap) == [[]]
    assert judge_effects([FOG], measured, _simulate(table), rivals=rivals(diag, lambda gap: 0.9 * gap)).named == [FOG]


def test_a_candidate_that_cannot_go_with_the_effects_the_search_ended_with_is_no_rival():
    """Seeded draw case 6 (rain 20.9 mm/h behind a dirt of 0.726): the dirt won the first round by 8 % over a snow
    and a rain, then the rain was accepted beside it. Neither can stand in the dirt's place beside that rain (rain and
    snow do not go together, nor the rain twice), so neither is the dirt's rival; a sun as close in that round, which
    can go with the rain, is one."""
    dirt, rain, snow, sun = (parse_effect(t) for t in ("cover.dirt:transmission=0.72", "atmosphere.rain:intensity=20",
                                                       "atmosphere.snow:intensity=0.29", "sensor.sun:irradiance=300"))
    first = [Candidate(dirt, 0.19, 0.1905, 9), Candidate(snow, 0.2, 0.2062, 9), Candidate(rain.with_value(8.3), 0.2,
             0.2079, 9), Candidate(sun, 0.2, 0.2070, 9)]  # fmt: skip
    diag = Diagnosis(0.4, 0.002, accepted=[(first[0], 0.4), (Candidate(rain, 0.002, 0.002, 9), 0.1905)],
                     rounds=[first, [Candidate(rain, 0.002, 0.002, 9)]])  # fmt: skip
    assert rivals(diag, lambda gap: 0.9 * gap) == [[first[3]], []]


def test_a_weather_effect_at_the_weak_end_of_its_range_is_not_named_whatever_it_removes():
    """The fog of the test above fitted at 1000 m (its largest visual range: no fog the search can tell from none) is
    refused although it removes its zones' residual; at 900 m it is named. The weak end is each effect's own: the
    largest transmission of dirt, the smallest rate of rain; the sensor family has none."""
    measured = signature(MEASURED | {"road": [1000.0] * 4})
    with_fog = SIMULATED | {"far": [1000.0, 948.0, 805.0, 596.0], "near": [96.0]}
    table = {frozenset(): SIMULATED, frozenset({FOG.name}): with_fog}
    weak = FOG.with_value(1000.0)
    judgement = judge_effects([weak], measured, _simulate(table))
    assert judgement.named == [] and judgement.refused[0][1].startswith("at the weak end of its range (visual_range 1000 m)")
    assert {r.zone for r in judgement.unexplained} == {"far", "near"}  # what the fog took is reported
    assert judge_effects([FOG.with_value(900.0)], measured, _simulate(table)).named == [FOG.with_value(900.0)]
    assert at_weak_end(parse_effect("cover.dirt:transmission=0.995")) and not at_weak_end(DIRT)
    assert at_weak_end(parse_effect("atmosphere.rain:intensity=0.2")) and not at_weak_end(parse_effect("atmosphere.rain:intensity=100"))
    assert at_weak_end(parse_effect("sensor.range_noise:sigma=0.003")) is None


def test_an_effect_with_no_residual_in_its_zones_is_not_named_and_a_partial_removal_must_reach_the_stated_share():
    measured = signature({"far": [1000.0] * 4, "road": [1000.0] * 4, "cover": [0.0], "near": [1000.0]})
    clear = {"far": [1000.0] * 4, "road": [1000.0] * 4, "cover": [0.0], "near": [0.0]}
    without, with_dirt = zone_residuals(measured, signature(clear)), zone_residuals(measured, signature(clear))
    assert removes_its_residual(DIRT.name, without, with_dirt).startswith("no residual to remove in its zones")
    half = zone_residuals(measured, signature(clear | {"near": [500.0]}))  # rain removes half the near field's
    assert removes_its_residual("atmosphere.rain", without, half).startswith("leaves near field, excess returns")
    most = zone_residuals(measured, signature(clear | {"near": [850.0]}))  # 3.5 sigma left, < 20 % of the residual
    assert most["near"].significant and removes_its_residual("atmosphere.rain", without, most) is None
    assert removes_its_residual("sensor.intensity_gamma", without, without) is None  # no zones: the search decides


def test_the_report_and_the_cli_say_what_is_unexplained_and_which_fit_is_not_named(tmp_path, monkeypatch, capsys):
    import json

    import lidar_weather_sim.gap.command as command
    from lidar_weather_sim.cli import main as cli_main
    from lidar_weather_sim.gap.report import write_gap
    from lidar_weather_sim.gap.search import Candidate, Diagnosis
    from lidar_weather_sim.gap.signatures import ZONES

    measured, simulated = (signature({z: counts.get(z, [0.0] * len(BANDS[z])) for z in ZONES})
                           for counts in (MEASURED, SIMULATED))  # fmt: skip
    for sig in (measured, simulated):
        sig.sums["bev"] = np.zeros((400, 200))
    table = {frozenset(): SIMULATED, frozenset({SUN.name}): SIMULATED | {"far": [850.0] * 4}}
    judgement = judge_effects([SUN], measured, _simulate(table))
    diagnosis = Diagnosis(0.1, 0.08, accepted=[(Candidate(SUN, 0.08, 0.08, 1), 0.1)])
    result = write_gap(tmp_path / "gap", diagnosis, measured, simulated, simulated, "name: x\n", judgement=judgement)
    assert result["found"] == "no effect" and result["effects"][0]["named"] is False
    assert result["effects"][0]["refused"].startswith("leaves far field")
    on_disk = json.loads((tmp_path / "gap" / "gap.json").read_text())
    assert sorted((u["zone"], u["shape"], round(u["sigma"], 1)) for u in on_disk["unexplained"]) == [
        ("far", "loss growing with range", 10.0), ("near", "excess returns", 10.0)]
    assert [u["relative"] for u in on_disk["unexplained"] if u["zone"] == "near"] == [None]  # none simulated
    report = (tmp_path / "gap" / "report.md").read_text()
    assert "| far field | loss growing with range | 10.0 |" in report and "Fitted but not named: sensor.sun" in report

    monkeypatch.setattr(command, "run_gap", lambda *args, **kwargs: result)
    assert cli_main(["gap", "bag", "--scenario", "highway_clear", "--out", str(tmp_path / "gap")]) == 0
    lines = capsys.readouterr().out.splitlines()
    assert lines[0].startswith("gap 0.1000 -> 0.0800: no effect")
    assert lines[1].startswith("not named: sensor.sun (leaves far field")
    assert sorted(lines[2:]) == ["unexplained: far field, loss growing with range (10.0 sigma)",
                                 "unexplained: near field, excess returns (10.0 sigma)"]  # fmt: skip


def _with_epw(sig: Signature, zone: str, per_bin: list[float]) -> Signature:
    """``sig`` with the zone's EPW histogram (echo 1; unit weights) holding ``per_bin`` returns in its first bins."""
    from lidar_weather_sim.gap.signatures import EPW_EDGES

    hist = np.zeros(3 * (len(EPW_EDGES) - 1))
    hist[: len(per_bin)] = per_bin
    sig.sums[f"{zone}/epw"], sig.squares[f"{zone}/epw"] = hist, hist.copy()
    return sig


def test_pulses_wider_than_the_models_are_unexplained_and_fewer_pulses_of_the_same_widths_are_not():
    simulated = _with_epw(signature(SIMULATED), "far", [2000.0, 1500.0, 500.0])
    wider = _with_epw(signature(SIMULATED), "far", [1000.0, 1500.0, 1500.0])  # the same count, a third moved wider
    residual = zone_residuals(wider, simulated)["far/epw"]
    assert residual.significant and residual.shape == "wider pulses" and residual.text() == "far field, wider pulses"
    assert zone_residuals(wider, simulated)["far"].significant is False  # the counts agree
    import json

    assert json.loads(json.dumps(residual.to_dict()))["shape"] == "wider pulses"  # gap.json takes it
    fewer = _with_epw(signature(SIMULATED), "far", [1600.0, 1200.0, 400.0])  # 20 % fewer, same widths
    assert not zone_residuals(fewer, simulated)["far/epw"].significant
    # 3 % of 40000 returns moved wider: beyond the bins' thresholds, below MIN_SHAPE (what a fit's own error leaves)
    many = _with_epw(signature(SIMULATED), "far", [20000.0, 15000.0, 5000.0])
    slight = _with_epw(signature(SIMULATED), "far", [18800.0, 15000.0, 6200.0])
    bins = zone_residuals(slight, many)["far/epw"].bands
    assert bins[0].significant and bins[2].significant  # each bin alone: 6.1 and 11.3 sigma, beyond 5 %
    assert not zone_residuals(slight, many)["far/epw"].significant


def test_the_fog_is_named_on_the_range_law_of_its_loss_and_a_pulse_width_residual_it_leaves_is_reported():
    """The fog's naming judges its zones' range counts only (EFFECT_ASPECTS): a fog that gives the far field the
    measured loss growing with range is named though the far pulses stay wider than the model's (the unit's
    receiver); that residual is still reported unexplained. The sun is judged on every aspect: the same pulse
    widths left refuse it."""
    measured = _with_epw(signature(MEASURED | {"near": [0.0]}), "far", [1000.0, 1500.0, 850.0])
    clear = _with_epw(signature(SIMULATED), "far", [2000.0, 1500.0, 500.0])
    fitted = _with_epw(signature(MEASURED | {"near": [0.0]}), "far", [1675.0, 1256.0, 419.0])  # the loss, narrower
    table = {frozenset(): clear, frozenset({FOG.name}): fitted, frozenset({SUN.name}): fitted}
    judgement = judge_effects([FOG], measured, lambda effects: table[frozenset(e.name for e in effects)])
    assert judgement.named == [FOG] and judgement.refused == []
    assert [u.text() for u in judgement.unexplained] == ["far field, wider pulses"]
    judgement = judge_effects([SUN], measured, lambda effects: table[frozenset(e.name for e in effects)])
    assert judgement.named == [] and "far field, wider pulses" in judgement.refused[0][1]


RAIN = parse_effect("atmosphere.rain:intensity=5")


@pytest.mark.parametrize("shift_bins, named", [(0, True), (20, False)])
def test_a_rain_is_named_only_where_its_drops_echoes_have_the_near_field_s_shape(shift_bins, named):
    """100 drop echoes in 10 frames where the model without rain has none: a rain that puts them in the same 5 cm
    bins is named; one that matches their count 1 m further (fixed-generator case 1: a rain fitted for a fog's echoes)
    removes the zone's count residual but not the shape of its echoes, and is refused."""
    measured = {**SIMULATED, "near": [100.0]}
    with_rain = signature(measured)
    hist = with_rain.sums["near/range"]
    with_rain.sums["near/range"] = with_rain.squares["near/range"] = np.roll(hist, shift_bins)
    without = signature(SIMULATED)
    judgement = judge_effects([RAIN], signature(measured), lambda effects: with_rain if effects else without)
    assert (judgement.named == [RAIN]) == named
    if not named:
        ((effect, reason),) = judgement.refused
        assert effect == RAIN and reason.startswith("its drops' echoes are not the near field's (near/range 0.9")
